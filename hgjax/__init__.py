"""hgjax: point-cloud resampling with hypergraph signal processing, in JAX.

Implements HKC, HKF and LHF from Deng, Zhang, Ding, "An Efficient Hypergraph Approach to
Robust Point Cloud Resampling", IEEE TIP 31 (2022), with baselines, evaluation and
differentiable soft resampling.
"""

from importlib.metadata import PackageNotFoundError, version as _version

from hgjax import eval, io, scores, spectrum  # noqa: A004 (hgjax.eval is the evaluation package)
from hgjax.neighbourhoods import Neighbourhoods, cube, intrinsic_resolution, knn, spatial_order
from hgjax.resample import METHODS, Method, resample
from hgjax.select import top_k, weighted_sample
from hgjax.samplers import *  # noqa: F401,F403  (issue 3: uniform, voxel, fps)
from hgjax.soft import *  # noqa: F401,F403  (issue 7)
from hgjax import samplers as _samplers, soft as _soft

try:
    __version__ = _version("hgjax")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+local"

__all__ = [
    "METHODS",
    "Method",
    "Neighbourhoods",
    "cube",
    "eval",
    "io",
    "intrinsic_resolution",
    "knn",
    "resample",
    "scores",
    "spatial_order",
    "spectrum",
    "top_k",
    "weighted_sample",
]
__all__ += _samplers.__all__ + _soft.__all__
