"""Per-point resampling scores, one module per method of the paper and its baselines.

Each module holds, side by side, the hard kernel for ONE neighbourhood, its smooth twin,
the neighbourhoods it needs (built by :mod:`hgjax.neighbours`), and ``score`` / ``soft_score`` over a whole
:class:`hgjax.Neighbourhoods`: :mod:`~hgjax.scores.hkc` (Eq. 11), :mod:`~hgjax.scores.hkf`
(Eq. 12), :mod:`~hgjax.scores.lhf` (Eqs. 14-16), :mod:`~hgjax.scores.gfr`,
:mod:`~hgjax.scores.ea`, :mod:`~hgjax.scores.pca_ac`, and beyond the paper
:mod:`~hgjax.scores.mss` (multi-scale sharpness); :mod:`~hgjax.scores.cubic_kernel` is the cubic
kernel shared by HKC and HKF.
"""

from hgjax.scores import cubic_kernel, ea, gfr, hkc, hkf, lhf, mss, pca_ac

__all__ = ["cubic_kernel", "ea", "gfr", "hkc", "hkf", "lhf", "mss", "pca_ac"]
