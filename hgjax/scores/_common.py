"""Pieces shared by the per-method score modules: argument checks, gathering, streaming."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbourhoods import SpatialIndex, _resolution

VARIANTS = ("invariant", "reference")


def check_variant(variant: str) -> str:
    return _validate.check_choice(variant, "variant", VARIANTS)


def map_neighbourhoods(fn: Callable) -> Callable:
    """Turn ``fn(centre (3,), nbrs (K, 3), valid (K,), *args)`` into a chunk kernel.

    The returned function takes ``(points_ext (N+1, 3), rows (C,), idx (C, K), *args)``,
    gathers with the sentinel row, masks with ``idx < N`` and vmaps ``fn`` over the chunk.
    Scalar ``args`` are broadcast (not mapped).
    """

    def kernel(points_ext, rows, idx, *args):
        n = points_ext.shape[0] - 1
        centres = points_ext[rows]
        nbrs = points_ext[idx]
        valid = idx < n
        return jax.vmap(fn, in_axes=(0, 0, 0) + (None,) * len(args))(centres, nbrs, valid, *args)

    return kernel


def resolution_or_default(index: SpatialIndex, resolution) -> float:
    """The given resolution, or the cloud's intrinsic resolution (1.0 if that is 0)."""
    if resolution is not None:
        return _validate.check_positive(resolution, "resolution")
    res = _resolution(index)
    return res if res > 0 else 1.0


def chunk_size_or_auto(chunk_size, n: int, bytes_per_point: int) -> int:
    if chunk_size is None:
        return _stream.auto_chunk_size(n, bytes_per_point)
    return _validate.check_int(chunk_size, "chunk_size", minimum=1)


def scalar(value: float, dtype) -> jax.Array:
    """A traced scalar parameter in the working dtype (changing it does not recompile)."""
    return jnp.asarray(value, dtype=_stream.working_dtype(dtype))


def safe_div(num: jax.Array, den: jax.Array, empty) -> jax.Array:
    """num / den, and ``empty`` where den == 0 (no NaN, finite gradients)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), empty)


def finish(index: SpatialIndex, values: np.ndarray, dtype) -> np.ndarray:
    """Return sorted-frame ``values`` in the caller's order and dtype."""
    return index.to_caller(np.asarray(values, dtype=dtype))
