"""Per-point resampling scores, one module per method of the paper and its baselines.

Each module holds, side by side, the hard kernel for ONE neighbourhood, its smooth twin,
the host builder of the neighbourhoods it needs, and ``score`` / ``soft_score`` over a whole
:class:`hgjax.Neighbourhoods`: :mod:`~hgjax.scores.hkc` (Eq. 11), :mod:`~hgjax.scores.hkf`
(Eq. 12), :mod:`~hgjax.scores.lhf` (Eqs. 14-16), :mod:`~hgjax.scores.gfr`,
:mod:`~hgjax.scores.ea`, :mod:`~hgjax.scores.pca_ac`, and beyond the paper
:mod:`~hgjax.scores.mss` (multi-scale sharpness); :mod:`~hgjax.scores.voxel` is the cubic
kernel shared by HKC and HKF.
"""

from hgjax.scores import ea, gfr, hkc, hkf, lhf, mss, pca_ac, voxel

__all__ = ["ea", "gfr", "hkc", "hkf", "lhf", "mss", "pca_ac", "voxel"]
