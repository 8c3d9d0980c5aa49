"""Mapping a per-neighbourhood kernel over every row of a :class:`Neighbourhoods`.

A kernel is written for ONE neighbourhood, ``fn(offsets (K, 3), valid (K,), *row_args,
*args)``, with ``offsets`` the neighbours minus the point (padding rows zero). The map
vmaps it over blocks of exactly ``BLOCK`` rows (``lax.map`` over the blocks), so every row
is computed by the same compiled block whatever the batch layout: results do not depend on
the chunk size.

Two execution paths give the same values:

* traced (inside the caller's ``jit``, ``vmap`` or ``grad``): one pure JAX program over
  the whole (N, K) neighbourhood array;
* concrete (eager calls, :func:`hgjax.resample`): the host gathers fixed-size chunks
  (C, K, 3) and streams them through ONE jitted kernel per (method, K), so a new cloud size
  never recompiles and peak memory grows with C, not with N. With several devices in
  ``jax.devices()`` each chunk's rows are split over them with ``shard_map``.
"""

from __future__ import annotations

import functools
import sys
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate

BLOCK = 1024  # rows per vmapped block
CHUNK_BLOCKS = 8  # blocks per streamed chunk (per device)


def is_traced(*trees) -> bool:
    """True when any leaf is a JAX tracer (the call runs inside jit, vmap or grad)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees))


def chunk_rows(chunk_size: int | None = None) -> int:
    """Rows per streamed chunk: a multiple of BLOCK per local device, fixed by default.

    Args:
      chunk_size: requested rows (an integer >= 1, rounded up), or None for ``CHUNK_BLOCKS`` blocks.

    Raises:
      TypeError, ValueError: ``chunk_size`` is not an integer >= 1.
    """
    unit = BLOCK * len(jax.devices())
    if chunk_size is None:
        return CHUNK_BLOCKS * unit
    return -(-_validate.check_int(chunk_size, "chunk_size", minimum=1) // unit) * unit


def _blocks(fn: Callable, offsets, valid, row_args, args):
    """vmap ``fn`` over (C, ...) rows, C a multiple of BLOCK, block by block."""
    c = offsets.shape[0]
    split = lambda x: x.reshape((c // BLOCK, BLOCK) + x.shape[1:])  # noqa: E731
    batched = jax.vmap(fn, in_axes=(0, 0) + (0,) * len(row_args) + (None,) * len(args))
    out = jax.lax.map(lambda b: batched(b[0], b[1], *b[2], *args),
                      (split(offsets), split(valid), tuple(split(a) for a in row_args)))
    return jax.tree.map(lambda x: x.reshape((c,) + x.shape[2:]), out)


def offsets_of(points, idx):
    """(N, K, 3) neighbours minus their point (zero for padding) and the (N, K) mask, in JAX."""
    n = points.shape[0]
    ext = jnp.concatenate([points, jnp.zeros((1, 3), points.dtype)])
    valid = idx < n
    return jnp.where(valid[..., None], ext[idx] - points[:, None, :], 0), valid


def map_neighbourhoods(fn: Callable, nb, *, row_args=(), args=(), chunk_size: int | None = None,
                       progress: bool = False, narrow: bool = False):
    """Apply ``fn`` to every neighbourhood of ``nb`` (traced: pure JAX; concrete: streamed).

    Args:
      fn: per-neighbourhood kernel ``fn(offsets (K, 3), valid (K,), *row_args, *args)``; it
        must be hashable and the same object for the same kernel (module-level functions or
        cached partials), since the streamed path compiles once per ``fn``.
      nb: :class:`hgjax.Neighbourhoods` with points (N, 3) and idx (N, K).
      row_args: per-row arrays (N, ...), mapped with the rows.
      args: arrays broadcast to every row (traced: new values do not recompile).
      chunk_size: rows per streamed chunk (concrete path only; never changes results).
      progress: tqdm bar on stderr for long streamed runs.
      narrow: the rows list their neighbours first and padding after, and ``fn`` gives the
        same result whatever the number of padding columns (e.g. exact counts). The
        streamed path then runs the rows in up to three kernels of fewer columns
        (:func:`narrow_groups`): far less work when a few rows set K.

    Returns:
      ``fn``'s outputs stacked over the rows (a pytree of (N, ...) JAX arrays).
    """
    points, idx = nb.points, nb.idx
    n = points.shape[0]
    if is_traced(points, idx, row_args, args):
        points, idx = jnp.asarray(points), jnp.asarray(idx)
        offsets, valid = offsets_of(points, idx)
        pad = -n % BLOCK
        padded = lambda x: jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1))  # noqa: E731
        out = _blocks(fn, padded(offsets), padded(valid), tuple(padded(jnp.asarray(a)) for a in row_args), args)
        return jax.tree.map(lambda x: x[:n], out)
    points, idx, row_args = np.asarray(points), np.asarray(idx), tuple(np.asarray(a) for a in row_args)
    args, chunk = tuple(jax.device_put(np.asarray(a)) for a in args), chunk_rows(chunk_size)
    groups = narrow_groups(idx, n) if narrow else [(np.arange(n), idx.shape[1])]
    if len(groups) > 1:
        parts = [_stream(fn, points, own, idx[own, :k], tuple(a[own] for a in row_args), args, chunk, progress)
                 for own, k in groups]
        back = np.argsort(np.concatenate([own for own, _ in groups]))  # rows back in order
        return jax.tree.map(lambda *xs: jax.device_put(np.concatenate(xs)[back]), *parts)
    return jax.tree.map(jax.device_put, _stream(fn, points, np.arange(n), idx, row_args, args, chunk, progress))


def narrow_groups(idx: np.ndarray, n: int) -> list[tuple[np.ndarray, int]]:
    """Rows of ``idx`` (R, K) (neighbours first, padding N after) as (rows, columns) groups.

    At most three groups (kernels): the widths are K and up to two powers of two below it,
    chosen to minimise rows x columns, fewer groups on ties (each row goes to the narrowest
    group that holds its neighbours). Groups without rows are left out.
    """
    count = (idx < n).sum(axis=1)
    k = idx.shape[1]
    widths = [w for w in (8 << i for i in range(20)) if w < k] + [k]
    need = np.searchsorted(np.asarray(widths), count)  # the narrowest width that holds each row
    hist = np.bincount(need, minlength=len(widths))

    def cost(chosen):
        return sum(int(hist[i]) * next(w for w in chosen if w >= widths[i]) for i in range(len(widths)))

    bounds = np.asarray(min((sorted({a, b, k}) for a in widths for b in widths), key=lambda c: (cost(c), len(c))))
    group = np.searchsorted(bounds, count)
    return [(np.flatnonzero(group == g), int(w)) for g, w in enumerate(bounds) if np.any(group == g)]


def _stream(fn, points, own, idx, row_args, args, chunk, progress):
    """Host path of :func:`map_neighbourhoods`: fixed (C, K, 3) chunks through one kernel.

    Streams the points ``own`` (R,) with their neighbours ``idx`` (R, K); returns NumPy
    outputs (R, ...).
    """
    n, r = points.shape[0], idx.shape[0]
    ext = np.concatenate([points, np.zeros((1, 3), points.dtype)])
    kernel = _sharded(fn, len(row_args), len(args)) if len(jax.devices()) > 1 else _jitted(fn, len(row_args))
    outputs = []
    bar = _progress(r, progress and r > 4 * chunk)
    for start in range(0, r, chunk):
        rows = slice(start, min(start + chunk, r))
        nbr = idx[rows]
        valid = nbr < n
        offsets = np.where(valid[..., None], ext[nbr] - ext[own[rows], None, :], 0).astype(points.dtype)
        pad = chunk - offsets.shape[0]
        fill = lambda x: np.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1))  # noqa: E731
        if outputs:
            # At most one kernel in flight: two programs calling LAPACK eigh at the same time
            # can deadlock in jaxlib's CPU thread pool.
            jax.block_until_ready(outputs[-1])
        outputs.append(kernel(fill(offsets), fill(valid), tuple(fill(a[rows]) for a in row_args), args))
        if bar is not None:
            bar.update(rows.stop - rows.start)
    if bar is not None:
        bar.close()
    return jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:r], *outputs)


@functools.lru_cache(maxsize=None)
def _jitted(fn: Callable, n_row_args: int) -> Callable:
    del n_row_args  # part of the cache key only
    return jax.jit(functools.partial(_blocks, fn))


@functools.lru_cache(maxsize=None)
def _sharded(fn: Callable, n_row_args: int, n_args: int) -> Callable:
    """The block map with the rows of each chunk split over all local devices."""
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("points",))
    rows, rep = jax.sharding.PartitionSpec("points"), jax.sharding.PartitionSpec()
    body = functools.partial(_blocks, fn)
    return jax.jit(jax.shard_map(body, mesh=mesh, in_specs=(rows, rows, (rows,) * n_row_args, (rep,) * n_args),
                                 out_specs=rows, check_vma=False))


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # tqdm is optional; progress is then silent
        return None
    return tqdm(total=total, unit="pt", unit_scale=True, file=sys.stderr, leave=False)
