"""Per-point resampling scores, one module per method of the paper and its baselines.

Each module has a kernel for ONE neighbourhood (``*_neighbourhood``) and a host entry point
that builds neighbourhoods with SciPy and streams the vmapped, jitted kernel over the cloud.
"""

from hgjax.scores.ea import ea, ea_neighbourhood
from hgjax.scores.gfr import gfr, gfr_neighbourhood
from hgjax.scores.hkc import hkc, hkc_neighbourhood
from hgjax.scores.hkf import hkf, hkf_neighbourhood
from hgjax.scores.pca_ac import pca_ac, ward_1d
from hgjax.scores.lhf import combine as lhf_combine, lhf, lhf_neighbourhood, lhf_single

__all__ = [
    "ea",
    "ea_neighbourhood",
    "gfr",
    "gfr_neighbourhood",
    "hkc",
    "hkc_neighbourhood",
    "hkf",
    "hkf_neighbourhood",
    "lhf",
    "lhf_combine",
    "lhf_neighbourhood",
    "lhf_single",
    "pca_ac",
    "ward_1d",
]
