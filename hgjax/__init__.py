"""hgjax: point-cloud resampling with hypergraph signal processing, in JAX.

Implements HKC, HKF and LHF from Deng, Zhang, Ding, "An Efficient Hypergraph Approach to
Robust Point Cloud Resampling", IEEE TIP 31 (2022), with baselines, evaluation and
differentiable soft resampling. On one tile, ``resample`` is a composition of public pieces,
``keep(score(neighbourhoods(points, method), method), ratio)``; :mod:`hgjax.tiles` runs it tile
by tile (here or on Dask workers) and :mod:`hgjax.survey` on files as one cloud.
"""

from importlib.metadata import PackageNotFoundError, version as _version

from hgjax import eval, io, scores, spectrum  # noqa: A004 (hgjax.eval is the evaluation package)
from hgjax import samplers as _samplers
from hgjax import survey, tiles  # noqa: F401  (the tiled path and surveys of files)
from hgjax._method import Method, Sampler
from hgjax._registry import METHODS
from hgjax.engine import resample
from hgjax.pipeline import keep, neighbourhoods, score, soft_resample, soft_score, soft_weights
from hgjax.samplers import farthest_point_sample, fps_backend, uniform_sample, voxel_sample
from hgjax.select import soft_select, top_k, weighted_sample
from hgjax.spatial import (
    Neighbourhoods,
    PrecisionWarning,
    cube,
    intrinsic_resolution,
    knn,
    local_frame,
    spatial_order,
    stack_neighbourhoods,
    working_dtype,
)

try:
    __version__ = _version("hgjax")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+local"

__all__ = [
    "METHODS",
    "Method",
    "Neighbourhoods",
    "Sampler",
    "PrecisionWarning",
    "cube",
    "eval",
    "intrinsic_resolution",
    "io",
    "keep",
    "knn",
    "local_frame",
    "neighbourhoods",
    "resample",
    "score",
    "scores",
    "soft_resample",
    "soft_score",
    "soft_select",
    "soft_weights",
    "spatial_order",
    "spectrum",
    "stack_neighbourhoods",
    "top_k",
    "weighted_sample",
    "working_dtype",
]
__all__ += _samplers.__all__
