"""Streaming of per-point kernels over fixed-size chunks of a cloud.

A kernel is a jitted function ``kernel(points_ext, rows, idx, *args) -> (C, ...)`` where
``points_ext`` is the (N + 1, 3) sorted cloud with a zero sentinel row appended, ``rows``
(C,) int32 are the sorted-frame rows of the chunk and ``idx`` (C, K) int32 their
neighbours, both padded with the sentinel N. Every chunk has the same shape, so one
compilation serves all of them (the last chunk is padded); the neighbour query runs on the
host chunk by chunk, so peak memory grows with the chunk size, not with N.
"""

from __future__ import annotations

import functools
import math
import sys
import warnings
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from hgjax.neighbourhoods import SpatialIndex

DEFAULT_CHUNK_BYTES = 64 * 2**20  # working set aimed at per chunk
BLOCK = 1024  # rows per vmapped block; chunk sizes are multiples of it


def auto_chunk_size(n: int, bytes_per_point: int) -> int:
    """Rows per chunk so one chunk's working set is about DEFAULT_CHUNK_BYTES.

    The result is a power of two between 1024 and 2**20, and never more than n rounded up to
    a multiple of BLOCK.
    """
    rows = DEFAULT_CHUNK_BYTES // max(bytes_per_point, 1)
    rows = 1 << max(10, min(20, int(math.log2(max(rows, 1)))))
    return min(rows, round_chunk(n))


def round_chunk(chunk_size: int) -> int:
    """Round a chunk size up to a multiple of :func:`block_rows` (the unit kernels compute in)."""
    unit = block_rows()
    return -(-chunk_size // unit) * unit


class PrecisionWarning(UserWarning):
    """float64 input computed in float32 because JAX's x64 mode is off."""


def working_dtype(dtype) -> np.dtype:
    """The dtype kernels run in: the caller's, or float32 for float64 input without x64.

    JAX keeps 64-bit types opt-in (``jax.config.update("jax_enable_x64", True)``). Without
    it, float64 input is computed in float32, results are returned as float64, and a
    :class:`PrecisionWarning` says so (never a silent cast).
    """
    dtype = np.dtype(dtype)
    if dtype == np.float64 and not jax.config.jax_enable_x64:
        warnings.warn("float64 points are computed in float32 because jax_enable_x64 is off;"
                      ' call jax.config.update("jax_enable_x64", True) for float64 precision',
                      PrecisionWarning, stacklevel=3)
        return np.dtype(np.float32)
    return dtype


def _pad_rows(a: np.ndarray, size: int, fill: int) -> np.ndarray:
    if a.shape[0] == size:
        return a
    pad = np.full((size - a.shape[0],) + a.shape[1:], fill, dtype=a.dtype)
    return np.concatenate([a, pad])


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # tqdm is optional; progress is then silent
        return None
    return tqdm(total=total, unit="pt", unit_scale=True, file=sys.stderr, leave=False)


def stream(kernel: Callable, index: SpatialIndex, query: Callable[[slice], np.ndarray], *,
           chunk_size: int, args: Sequence = (), progress: bool = False):
    """Run ``kernel`` over all points of ``index`` in chunks of ``chunk_size`` rows.

    With several devices in ``jax.devices()`` each chunk's rows are split evenly over them
    (``shard_map`` over a 1-D mesh named ``"points"``); every device runs the same block
    kernel on its rows, so results are identical to a single-device run.

    Args:
      kernel: jitted per-chunk kernel (see module docstring).
      index: the spatial index whose sorted frame the rows refer to.
      query: host function mapping a row slice to its (R, K) int32 neighbour indices.
      chunk_size: rows per chunk, a multiple of :func:`block_rows`; every chunk is padded to it.
      args: extra (traced) kernel arguments, replicated on every device.
      progress: show a tqdm bar on stderr when there are more than four chunks.

    Returns:
      The kernel outputs (a pytree of NumPy arrays with leading axis N) in the sorted frame.
    """
    n = index.n
    dtype = working_dtype(index.points.dtype)
    points_ext = jnp.asarray(np.concatenate([index.points, np.zeros((1, 3), index.points.dtype)]), dtype=dtype)
    run = _sharded(kernel, len(args)) if len(jax.devices()) > 1 else kernel
    outputs = []
    bar = _progress(n, progress and n > 4 * chunk_size)
    for rows in index.chunks(chunk_size):
        ids = _pad_rows(np.arange(rows.start, rows.stop, dtype=np.int32), chunk_size, n)
        idx = _pad_rows(query(rows), chunk_size, n)  # overlaps with the previous chunk's kernel
        if outputs:
            # At most one kernel in flight: two programs calling LAPACK eigh at the same time
            # can deadlock in jaxlib's CPU thread pool (seen with jax 0.10.2).
            jax.block_until_ready(outputs[-1])
        outputs.append(run(points_ext, ids, idx, *args))
        if bar is not None:
            bar.update(rows.stop - rows.start)
    if bar is not None:
        bar.close()
    host = jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs]), *outputs)
    return jax.tree.map(lambda x: x[:n], host)


def block_rows() -> int:
    """Rows every chunk size must be a multiple of: BLOCK per local device."""
    return BLOCK * len(jax.devices())


@functools.lru_cache(maxsize=None)
def _sharded(kernel: Callable, n_args: int) -> Callable:
    """``kernel`` with the point axis of rows and idx split over all local devices."""
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("points",))
    rows, rep = jax.sharding.PartitionSpec("points"), jax.sharding.PartitionSpec()
    return jax.jit(jax.shard_map(kernel, mesh=mesh, in_specs=(rep, rows, rows) + (rep,) * n_args,
                                 out_specs=rows, check_vma=False))
