"""hgjax: point-cloud resampling with hypergraph signal processing, in JAX.

Implements HKC, HKF and LHF from Deng, Zhang, Ding, "An Efficient Hypergraph Approach to
Robust Point Cloud Resampling", IEEE TIP 31 (2022), with baselines, evaluation and
differentiable soft resampling. On one tile, ``resample`` is a composition of public pieces,
``keep(score(neighbourhoods(points, method), method), ratio)``; :mod:`hgjax.tiles` runs it tile
by tile (here or on Dask workers) and :mod:`hgjax.survey` on files as one cloud.
"""

import importlib
import importlib.util

# The public names and the modules that define them. ``import hgjax`` loads none of them (nor JAX):
# each is imported on first use (PEP 562, as SciPy and scikit-image load theirs), so that the
# command line installs its signal handlers before JAX starts (``hgjax.cli.main``).
_EXPORTS = {
    "hgjax._method": ("Method", "Sampler"),
    "hgjax.neighbours.container": ("Neighbourhoods", "stack_neighbourhoods"),
    "hgjax.neighbours.precision": ("PrecisionWarning", "local_frame", "working_dtype"),
    "hgjax.engine": ("METHODS", "capacity", "keep", "neighbourhoods", "resample", "score", "soft_resample",
                     "soft_score", "soft_weights"),
    "hgjax.samplers": ("farthest_point_sample", "fps_backend", "uniform_sample", "voxel_sample"),
    "hgjax.engine.select": ("soft_select", "top_k", "weighted_sample"),
    "hgjax.neighbours.balls": ("cube",),
    "hgjax.neighbours.nearest": ("knn",),
    "hgjax.neighbours.spatial": ("intrinsic_resolution", "spatial_order"),
}
_SOURCE = {name: module for module, names in _EXPORTS.items() for name in names}


def __getattr__(name: str):
    if name in _SOURCE:
        value = getattr(importlib.import_module(_SOURCE[name]), name)
    elif name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("hgjax")
        except PackageNotFoundError:  # running from a source tree without installation
            value = "0.0.0+local"
    elif not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f"{__name__}.{name}")  # any submodule: hgjax.tiles, hgjax.survey
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "METHODS",
    "Method",
    "Neighbourhoods",
    "PrecisionWarning",
    "Sampler",
    "capacity",
    "cube",
    "eval",
    "farthest_point_sample",
    "fps_backend",
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
    "uniform_sample",
    "voxel_sample",
    "weighted_sample",
    "working_dtype",
]
