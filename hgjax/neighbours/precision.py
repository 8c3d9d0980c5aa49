"""The float64 local frame, and when computing in float32 loses what a cloud holds.

Every builder moves a cloud to its local frame (:func:`local_frame`: the float64 centre of its
bounding box subtracted, :func:`frame_origin`) before any cast to the working dtype, after
checking that the dtype represents the cloud's geometry at all
(:func:`hgjax._validate.check_extent`: its extent neither overflows nor underflows when
squared). Without JAX's x64 mode float64 input is computed in float32
(:func:`working_dtype`), and a :class:`PrecisionWarning` says so where the cast's half-ulp
rounding at the frame's extent (:func:`float32_rounding`, :func:`frame_extent`) exceeds 2^-10
of the cloud's finest spacing (:func:`finest_spacing`, measured by
:func:`hgjax.neighbours.spatial.index_spacing` or :func:`hgjax.neighbours.spatial.pair_spacing`). This module sits
beside :mod:`hgjax._validate`: it builds on nothing else of hgjax, and
:mod:`hgjax.neighbours.spatial` re-exports its public names.
"""

from __future__ import annotations

import warnings

import jax
import numpy as np

from hgjax import _validate

__all__ = ["PRECISION_SHARE", "PrecisionWarning", "axis_bounds", "finest_spacing", "float32_rounding", "frame_extent",
           "frame_origin", "local_frame", "split_frame", "working_dtype"]


PRECISION_SHARE = 2.0 ** -10  # float32's rounding may reach this share of the finest spacing before a warning


class PrecisionWarning(UserWarning):
    """float64 input computed in float32 (JAX's x64 mode off) where float32 loses what the data holds.

    Coordinates are cast after the local frame is taken in float64 (:func:`local_frame`), so
    the cast moves a coordinate by at most half a float32 ulp at the largest |local
    coordinate| m, ``np.spacing(np.float32(m)) / 2`` (:func:`float32_rounding`). The warning
    fires when that rounding exceeds 2^-10 (about 1e-3) of the cloud's finest spacing: the
    smallest positive distance from a point of the seeded sample
    (:func:`hgjax.neighbours.spatial.sample_ids`) to its nearest distinct point (:func:`finest_spacing`).
    The float64 clouds of :func:`hgjax.eval.box_union_cloud` (extent 6, 2e4 to 1e6 points:
    rounding 1e-4 to 3e-4 of that spacing) do not warn; millimetre detail at an extent of 1e7,
    or a dense cluster beside a far outlier, does (:func:`working_dtype`).
    """


def working_dtype(dtype, *, extent=None, spacing=None) -> np.dtype:
    """The dtype kernels run in: the caller's, or float32 for float64 input without x64.

    JAX keeps 64-bit types opt-in (``jax.config.update("jax_enable_x64", True)``). Without
    it, float64 input is computed in float32. Coordinates are first moved to a local frame in
    float64 (:func:`local_frame`), so the cast loses no more than the cloud's own extent
    allows, and a :class:`PrecisionWarning` says so only where that loss matters: when
    float32's rounding at the largest |local coordinate| ``extent``, ``np.spacing(np.float32(
    extent)) / 2``, exceeds 2^-10 of ``spacing``, the smallest positive nearest-distinct
    distance of the seeded sample (:func:`finest_spacing`). Every builder (:func:`hgjax.knn`,
    :func:`hgjax.cube`, :func:`hgjax.neighbourhoods`, :func:`hgjax.resample`) passes both.

    Args:
      dtype: the caller's float dtype.
      extent: the largest |coordinate| of the cloud in its local frame; None: not known.
      spacing: the cloud's finest spacing (:func:`finest_spacing`), or a callable returning
        it, called only when float64 is cast to float32; None: not known. Without both
        ``extent`` and ``spacing`` nothing is judged and nothing is warned.

    Returns:
      np.dtype float32 or float64.

    Warns:
      PrecisionWarning: float64 cast to float32 whose rounding is not small against ``spacing``.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.working_dtype(np.float32)
      dtype('float32')
      >>> hgjax.working_dtype(np.float32, extent=0.5, spacing=1e-4)  # float32 input: never cast
      dtype('float32')
    """
    dtype = np.dtype(dtype)
    if dtype != np.float64 or jax.config.jax_enable_x64:
        return dtype
    if extent is not None and spacing is not None:
        rounding = float32_rounding(extent)
        finest = float(spacing() if callable(spacing) else spacing)
        if rounding > PRECISION_SHARE * finest:
            warnings.warn(f"float64 points are computed in float32 because jax_enable_x64 is off, and float32"
                          f" rounds their local coordinates (up to {float(extent):.3g}) by {rounding:.2g}, more"
                          f" than 2^-10 of their finest spacing {finest:.3g};"
                          ' call jax.config.update("jax_enable_x64", True) for float64 precision',
                          PrecisionWarning, stacklevel=3)
    return np.dtype(np.float32)


def float32_rounding(extent) -> float:
    """Half a float32 ulp at ``extent``: the most a cast to float32 moves a coordinate of magnitude <= ``extent``."""
    with np.errstate(over="ignore"):
        return float(np.spacing(np.abs(np.float32(extent)))) / 2


def frame_extent(local: np.ndarray) -> float:
    """The largest |coordinate| of (N, 3) local coordinates (0.0 for none), without an (N, 3) temporary."""
    return float(max(local.max(initial=0.0), -local.min(initial=0.0)))


def finest_spacing(distinct: np.ndarray) -> float:
    """The smallest positive finite nearest-distinct distance of ``distinct`` (S,)
    (:attr:`hgjax.neighbours.spatial.SampleStats.distinct`); inf when there is none (a single location)."""
    d = np.asarray(distinct, dtype=np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    return float(d.min()) if d.size else np.inf


def local_frame(points) -> tuple[np.ndarray, np.ndarray]:
    """The cloud in a local frame: coordinates minus the centre of its bounding box.

    The subtraction is done in float64 whatever the input dtype, before any cast, so a
    georeferenced cloud (x about 5e5, y about 4e6) keeps millimetre detail in float32.

    Args:
      points: (N, 3) float32 or float64 (validated).

    Returns:
      (local, origin): local (N, 3) float64 with ``local + origin == points`` up to
      rounding, and origin (3,) float64.

    Raises:
      ValueError: the working dtype (:func:`working_dtype`) cannot represent the cloud's
        geometry: its extent overflows, or its resolved spacing underflows, when squared
        (:func:`hgjax._validate.check_extent`).

    Examples:
      >>> import numpy as np, hgjax
      >>> local, origin = hgjax.local_frame(np.array([[500000.0, 4e6, 0], [500002, 4e6, 1]]))
      >>> local.tolist(), origin.tolist()
      ([[-1.0, 0.0, -0.5], [1.0, 0.0, 0.5]], [500001.0, 4000000.0, 0.5])
    """
    p = np.asarray(points, dtype=np.float64)
    lo, hi = axis_bounds(p)
    origin = frame_origin(lo, hi, _computed_in(getattr(points, "dtype", np.float64)))
    return p - origin, origin


def split_frame(local: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray | None]:
    """(hi, lo): coordinates ``local`` (N, 3) as ``dtype`` values hi and what they round off,
    lo = local - hi in ``dtype`` (None when ``local`` already is ``dtype``)."""
    local = np.asarray(local)
    hi = local.astype(dtype)
    if np.dtype(dtype) == local.dtype:
        return hi, None
    return hi, (local - hi.astype(local.dtype)).astype(dtype)


def _computed_in(dtype) -> np.dtype:
    """:func:`working_dtype` of ``dtype``, without its warning."""
    return np.dtype(np.float64 if np.dtype(dtype) != np.float32 and jax.config.jax_enable_x64 else np.float32)


def frame_origin(lo: np.ndarray, hi: np.ndarray, dtype) -> np.ndarray:
    """The local frame's origin: the centre (3,) float64 of the bounding box [``lo``, ``hi``] (3,) each.

    First checks that ``dtype``, the dtype the geometry is computed in, represents the cloud
    (:func:`hgjax._validate.check_extent`: a clear ValueError naming ``points`` otherwise).
    Where lo + hi overflows (a cloud near the largest float64) the centre is lo / 2 + hi / 2.
    """
    _validate.check_extent(lo, hi, dtype)
    with np.errstate(over="ignore"):
        twice = lo + hi
    return np.where(np.isfinite(twice), twice / 2, lo / 2 + hi / 2)


def axis_bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): the per-axis minimum and maximum (3,) of (N, 3) ``points`` (N >= 1), as float64.

    Reduced one column at a time: NumPy's reduction over the first axis of an (N, 3) array
    walks it in short strided runs, several times slower.
    """
    columns = [points[:, a] for a in range(points.shape[1])]
    return (np.array([c.min() for c in columns], dtype=np.float64),
            np.array([c.max() for c in columns], dtype=np.float64))
