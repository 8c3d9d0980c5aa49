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
    gathers with the sentinel row, masks with ``idx < N`` and vmaps ``fn`` over blocks of
    exactly ``_stream.BLOCK`` rows (``lax.map`` over the blocks of the chunk). Every row is
    thus computed by the same compiled block whatever the chunk size, which keeps results
    bitwise identical across chunk sizes (XLA may pick other reduction orders for other
    batch shapes). Scalar ``args`` are broadcast (not mapped).
    """

    def block(points_ext, rows, idx, args):
        n = points_ext.shape[0] - 1
        batched = jax.vmap(fn, in_axes=(0, 0, 0) + (None,) * len(args))
        return batched(points_ext[rows], points_ext[idx], idx < n, *args)

    def kernel(points_ext, rows, idx, *args):
        c = rows.shape[0]
        if c % _stream.BLOCK:
            raise ValueError(f"chunk size {c} is not a multiple of {_stream.BLOCK}")
        blocks = (rows.reshape(c // _stream.BLOCK, _stream.BLOCK),
                  idx.reshape(c // _stream.BLOCK, _stream.BLOCK, idx.shape[1]))
        out = jax.lax.map(lambda b: block(points_ext, b[0], b[1], args), blocks)
        return jax.tree.map(lambda x: x.reshape((c,) + x.shape[2:]), out)

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
    return _stream.round_chunk(_validate.check_int(chunk_size, "chunk_size", minimum=1))


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


def safe_sqrt(x: jax.Array) -> jax.Array:
    """sqrt(x) for x > 0 and 0 elsewhere, with finite gradients at 0."""
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def band_ratio(high2: jax.Array, low2: jax.Array) -> jax.Array:
    """sqrt(high2) / (sqrt(high2) + sqrt(low2)) from squared band energies; 0 when both vanish."""
    h, l = safe_sqrt(high2), safe_sqrt(low2)
    return safe_div(h, h + l, 0.0)
