"""Per-point resampling scores, one module per method of the paper and its baselines.

Each module has a kernel for ONE neighbourhood (``*_neighbourhood``) and a host entry point
that builds neighbourhoods with SciPy and streams the vmapped, jitted kernel over the cloud.
"""

from hgjax.scores.hkc import hkc, hkc_neighbourhood
from hgjax.scores.hkf import hkf, hkf_neighbourhood
from hgjax.scores.lhf import combine as lhf_combine, lhf, lhf_neighbourhood, lhf_single

__all__ = [
    "hkc",
    "hkc_neighbourhood",
    "hkf",
    "hkf_neighbourhood",
    "lhf",
    "lhf_combine",
    "lhf_neighbourhood",
    "lhf_single",
]
