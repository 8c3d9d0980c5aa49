"""hgjax: point-cloud resampling with hypergraph signal processing, in JAX.

Implements HKC, HKF and LHF from Deng, Zhang, Ding, "An Efficient Hypergraph Approach to
Robust Point Cloud Resampling", IEEE TIP 31 (2022), with baselines, evaluation and
differentiable soft resampling.
"""

import os as _os
from importlib.metadata import PackageNotFoundError, version as _version

# jaxlib 0.10's CPU runtime can deadlock when batched LAPACK eigh calls (LHF reference,
# EA) run inside XLA's concurrency-optimised scheduler; turning it off avoids the hang. It
# takes effect only if JAX's CPU backend has not been initialised before hgjax is imported.
_FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler=false"
if _FLAG.split("=")[0] not in _os.environ.get("XLA_FLAGS", ""):
    _os.environ["XLA_FLAGS"] = (_os.environ.get("XLA_FLAGS", "") + " " + _FLAG).strip()

from hgjax import eval, io, scores, spectrum  # noqa: A004 (hgjax.eval is the evaluation package)
from hgjax.neighbourhoods import Neighbourhoods, cube, intrinsic_resolution, knn, spatial_order
from hgjax.resample import METHODS, Method, resample
from hgjax.select import top_k, weighted_sample
from hgjax.samplers import farthest_point_sample, uniform_sample, voxel_sample
from hgjax import samplers as _samplers, soft as _soft
from hgjax.soft import (
    SOFT_METHODS,
    soft_gfr,
    soft_hkc_neighbourhood,
    soft_lhf_neighbourhood,
    soft_local_signal,
    soft_neighbourhoods,
    soft_resample,
    soft_scores,
    soft_select,
    soft_weights,
)

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
    "intrinsic_resolution",
    "io",
    "knn",
    "resample",
    "scores",
    "spatial_order",
    "spectrum",
    "top_k",
    "weighted_sample",
]
__all__ += _samplers.__all__ + _soft.__all__  # each module's own list, imported by name above
