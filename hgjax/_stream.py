"""Mapping a per-neighbourhood kernel over every row of a :class:`Neighbourhoods`.

A kernel is written for ONE neighbourhood, ``fn(offsets (K, 3), valid (K,), *row_args,
*args)``, with ``offsets`` the neighbours minus the point (padding rows zero). One JAX
program per chunk of rows (:func:`_gathered`) gathers the offsets on the device from the
points and the neighbour indices and vmaps ``fn`` over blocks of exactly ``BLOCK`` rows
(``lax.map`` over the blocks), so every row is computed by the same compiled block whatever
the batch layout: results do not depend on the chunk size. It runs two ways:

* pure (:func:`pure_map`: inside the caller's ``jit``, ``vmap`` or ``grad``, and every soft
  score): the whole (N, K) neighbourhood array is one chunk;
* streamed (:class:`Stream`: eager calls, :func:`hgjax.resample`, the tiles): the points go
  to the device once and chunks of rows stream through one jitted program per (method, K)
  and chunk size as the host produces them, a chunk of 1, 2, 4, ... ``CHUNK_BLOCKS`` blocks
  (:func:`chunk_rows`: a small tile runs one block), so a new cloud or tile size compiles
  at most those few chunk shapes (and a new device copy size: :func:`point_rows`), the device
  computes while the host builds the next rows, and peak memory grows with the chunk,
  not with N. With several devices in ``jax.devices()`` each chunk's rows are split over
  them with ``shard_map``.
"""

from __future__ import annotations

import collections
import functools
import sys
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate
from hgjax import _progress as run_progress
from hgjax.neighbours import precision

BLOCK = 1024  # rows per vmapped block
ACCELERATOR_BLOCK = 16384  # rows per vmapped block of a traced map on a GPU/TPU: fewer sequential steps
CHUNK_BLOCKS = 8  # blocks per streamed chunk (per device)
MIN_POINT_ROWS = 1 << 16  # the smallest device copy of a cloud's points (see point_rows)
MIN_WIDTH = 8  # the narrowest kernel of a NarrowStream (columns)


def is_traced(*trees) -> bool:
    """True when the call runs inside jit, vmap or grad: a leaf is a tracer, or a trace is active.

    The second case is a caller's ``jit`` around a function that closes over concrete data
    (``jax.jit(lambda: hgjax.score(nb, "hkc"))``): every JAX value made there is a tracer,
    so the pure JAX path must run, never the host stream.
    """
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees)) or isinstance(jnp.zeros(()),
                                                                                            jax.core.Tracer)


def chunk_rows(chunk_size: int | None = None, total: int = 0) -> int:
    """Rows per streamed chunk: a power of two multiple of BLOCK per local device, from a fixed set.

    The chunk is the requested size (default ``CHUNK_BLOCKS`` blocks), cut down to the
    smallest power of two number of blocks that holds ``total`` rows when there are fewer:
    a tile of a few points runs one block, not a chunk of padding. Without a requested size
    a stream's chunks come from the ``log2(CHUNK_BLOCKS) + 1`` sizes of 1, 2, 4, ...
    ``CHUNK_BLOCKS`` blocks, so a cloud size or tile size never compiles more than those.

    Args:
      chunk_size: requested rows (an integer >= 1, rounded up to whole blocks), or None.
      total: the number of rows the stream will run, or 0 when unknown.

    Raises:
      TypeError, ValueError: ``chunk_size`` is not an integer >= 1.
    """
    unit = BLOCK * len(jax.devices())
    blocks = (CHUNK_BLOCKS if chunk_size is None
              else -(-_validate.check_int(chunk_size, "chunk_size", minimum=1) // unit))
    if total > 0:
        blocks = min(blocks, 1 << (-(-int(total) // unit) - 1).bit_length())
    return blocks * unit


def _blocks(fn: Callable, offsets, valid, row_args, args, block: int = BLOCK):
    """vmap ``fn`` over (C, ...) rows, C a multiple of ``block``, block by block."""
    c = offsets.shape[0]
    split = lambda x: x.reshape((c // block, block) + x.shape[1:])  # noqa: E731
    batched = jax.vmap(fn, in_axes=(0, 0) + (0,) * len(row_args) + (None,) * len(args))
    out = jax.lax.map(lambda b: batched(b[0], b[1], *b[2], *args),
                      (split(offsets), split(valid), tuple(split(a) for a in row_args)))
    return jax.tree.map(lambda x: x.reshape((c,) + x.shape[2:]), out)


def pure_map(fn: Callable, points, idx, *, lo=None, row_args=(), args=()):
    """``fn`` on every row of (points (N, 3), idx (N, K)) as one pure JAX program (jit, vmap, grad).

    The rows are padded to a multiple of the block (:data:`BLOCK` rows on CPU,
    :data:`ACCELERATOR_BLOCK` on a GPU/TPU) with copies of the last row (a real
    neighbourhood, so the padding's zero cotangents meet finite derivatives and gradients
    stay finite) and run as one chunk of :func:`_gathered`, the program that
    :func:`map_rows` streams chunk by chunk.

    Args:
      fn, row_args, args: as :func:`map_neighbourhoods`; ``row_args`` are (N, ...) arrays.
      points: (N, 3) coordinates.
      idx: (N, K) neighbour rows, padded with N.
      lo: (N, 3) what ``points`` round off (:attr:`hgjax.Neighbourhoods.points_lo`), or None.

    Returns:
      ``fn``'s outputs stacked over the rows (a pytree of (N, ...) JAX arrays).
    """
    points, idx = jnp.asarray(points), jnp.asarray(idx)
    n = points.shape[0]
    block = BLOCK if jax.default_backend() == "cpu" else ACCELERATOR_BLOCK
    block = min(block, -(-n // BLOCK) * BLOCK)  # no more padding than a CPU block's
    pad = -n % block
    padded = lambda x: jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1), mode="edge")  # noqa: E731
    hi = jnp.concatenate([points, jnp.zeros((1, 3), points.dtype)])  # row N: the sentinel's
    if lo is not None:
        lo = jnp.concatenate([jnp.asarray(lo, points.dtype), jnp.zeros((1, 3), points.dtype)])
    out = _gathered(fn, hi, lo, n, padded(jnp.arange(n, dtype=idx.dtype)), padded(idx),
                    tuple(padded(jnp.asarray(a)) for a in row_args), args, block)
    return jax.tree.map(lambda x: x[:n], out)


def as_arg(value, dtype):
    """A broadcast argument of :func:`map_neighbourhoods`: a concrete number as a ``dtype`` array
    (a Python number enters a ``dtype`` kernel so under jit), a traced one unchanged."""
    return value if is_traced(value) else np.asarray(value, dtype)


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
      progress: report the rows computed: to the command line's run (:func:`hgjax._progress.current`),
        else as a tqdm bar on stderr for a long stream.
      narrow: the rows list their neighbours first and padding after, and ``fn`` gives the
        same result whatever the number of padding columns (e.g. exact counts). The
        streamed path then runs each row in the kernel as narrow as its neighbours
        (:class:`NarrowStream`): far less work when a few rows set K.

    Returns:
      ``fn``'s outputs stacked over the rows (a pytree of (N, ...) JAX arrays).
    """
    points, idx, lo = nb.points, nb.idx, nb.points_lo
    if is_traced(points, idx, lo, row_args, args):
        return pure_map(fn, points, idx, lo=lo, row_args=row_args, args=args)
    points = np.asarray(points)
    ext = device_points(points, points.dtype, None if lo is None else np.asarray(lo))
    out = map_rows(fn, points, np.arange(points.shape[0]), np.asarray(idx), row_args=row_args, args=args,
                   dtype=points.dtype, ext=ext, chunk_size=chunk_size, progress=progress, narrow=narrow)
    return jax.tree.map(jax.device_put, out)


def map_rows(fn: Callable, points: np.ndarray, own: np.ndarray, idx: np.ndarray, *, row_args=(), args=(), dtype,
             ext: tuple | None = None, chunk_size: int | None = None, progress: bool = False, narrow: bool = False):
    """Host engine of :func:`map_neighbourhoods`: ``fn`` on the rows ``own`` of ``points``.

    The points go to the device once (:func:`device_points`) and the rows stream through
    one :class:`Stream` (a :class:`NarrowStream` when ``narrow``).

    Args:
      fn, row_args, args, chunk_size, progress, narrow: as :func:`map_neighbourhoods`;
        ``row_args`` are (R, ...) arrays aligned with ``own``.
      points: (n, 3) coordinates; ``idx`` indexes them, padding n.
      own: (R,) the row of each neighbourhood's own point.
      idx: (R, K) neighbour rows.
      dtype: the kernel's float dtype.
      ext: :func:`device_points` ``(points, dtype)``, when the caller made them once for
        several calls on the same points; None: made here.

    Returns:
      ``fn``'s outputs stacked over the rows, as NumPy arrays (R, ...).
    """
    stream = (NarrowStream if narrow else Stream)(fn, device_points(points, dtype) if ext is None else ext,
                                                  args=tuple(jax.device_put(np.asarray(a)) for a in args),
                                                  chunk_size=chunk_size, progress=progress, total=np.shape(idx)[0])
    stream.push(own, idx, tuple(np.asarray(a) for a in row_args))
    return stream.collect()


def device_points(points: np.ndarray, dtype, lo: np.ndarray | None = None) -> tuple:
    """(hi, lo or None, n): the n points (n, 3) on the device once, for every chunk of a :class:`Stream`.

    hi holds the points as ``dtype`` values and, for float64 points run in float32, lo the
    remainders points - hi (:func:`hgjax.neighbours.spatial.split_frame`; or ``lo`` as given, the
    points then being hi); a chunk's offsets (C, K, 3) are then gathered on the device as
    (hi_j - hi_i) + (lo_j - lo_i): each neighbourhood's offsets to the precision of
    ``dtype`` whatever the frame's origin, with the same bits in every tile that holds the
    neighbourhood. Both are padded to :func:`point_rows` rows, so a new cloud size compiles
    only when it crosses a power of four above 65,536 points.
    """
    n, dtype = points.shape[0], np.dtype(dtype)
    if lo is None:
        points, lo = precision.split_frame(points, dtype)
    size = point_rows(n)
    hi = np.zeros((size, 3), dtype)
    hi[:n] = points
    pad = None
    if lo is not None:
        pad = np.zeros((size, 3), dtype)
        pad[:n] = lo
    return jax.device_put(hi), None if pad is None else jax.device_put(pad), jax.device_put(np.int32(n))


class Stream:
    """Rows of one kernel sent to the device in chunks of C rows (:func:`chunk_rows`) as the host produces them.

    :meth:`push` cuts the rows it is given into chunks of C rows (their own rows (C,) and
    neighbours (C, K)) and dispatches each full chunk to ONE compiled program at once; JAX
    dispatch is asynchronous, so the device computes while the host builds the next rows.
    :meth:`collect` sends the last chunk, padded, and waits for the outputs. Every row's
    result is the same however the rows were pushed.

    Args:
      fn: per-neighbourhood kernel, as :func:`map_neighbourhoods`.
      ext: :func:`device_points` of the points the rows index.
      args: device arrays broadcast to every row.
      chunk_size, progress: as :func:`map_neighbourhoods`.
      total: the number of rows to come (sets the chunk: :func:`chunk_rows`; and the progress bar).
    """

    def __init__(self, fn: Callable, ext: tuple, *, args=(), chunk_size: int | None = None, progress: bool = False,
                 total: int = 0):
        self.fn, self.ext, self.args, self.n = fn, ext, args, int(ext[2])
        self.chunk = chunk_rows(chunk_size, total)
        self.pending, self.outputs, self.rows = None, [], 0
        self.bar = _counter(total, progress, self.chunk)
        self.uncounted = collections.deque()  # (outputs, rows) of the chunks sent that the bar has not counted

    def push(self, own, idx, row_args=()) -> None:
        """Queue the rows ``own`` (R,) with neighbours ``idx`` (R, K) and ``row_args`` (R, ...) each;
        send every full chunk."""
        part = (np.asarray(own, dtype=np.int32), np.asarray(idx, dtype=np.int32), tuple(np.asarray(a) for a in row_args))
        if self.pending is not None and self.pending[0].shape[0]:
            part = jax.tree.map(lambda a, b: np.concatenate([a, b]), self.pending, part)
        r = part[0].shape[0]
        full = r - r % self.chunk
        for start in range(0, full, self.chunk):
            self._send(jax.tree.map(lambda x: x[start:start + self.chunk], part))
        self.pending = jax.tree.map(lambda x: x[full:], part)

    def collect(self):
        """``fn``'s outputs of every pushed row, in push order, as NumPy arrays (R, ...)."""
        if self.pending[0].shape[0] or not self.outputs:
            self._send(self.pending)
        out = jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:self.rows], *self.outputs)
        if self.bar is not None:
            self._count(wait=True)
            self.bar.close()
        return out

    def _send(self, part) -> None:
        own, idx, row_args = part
        r = own.shape[0]
        pad = self.chunk - r
        fill = lambda x, v=0: x if not pad else np.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1),  # noqa: E731
                                                       constant_values=v)
        kernel = (_sharded(self.fn, len(row_args), len(self.args)) if len(jax.devices()) > 1
                  else _jitted(self.fn, len(row_args)))
        self.outputs.append(kernel(*self.ext, fill(own), fill(idx, self.n), tuple(fill(a) for a in row_args), self.args))
        self.rows += r
        if self.bar is not None:
            self.uncounted.append((self.outputs[-1], r))
            self._count(wait=False)

    def _count(self, wait: bool) -> None:
        """Count in the bar the rows of the chunks computed, in order (every one sent when ``wait``): the
        device can run behind the host, which sends chunks as fast as it builds them."""
        while self.uncounted and (wait or all(x.is_ready() for x in jax.tree.leaves(self.uncounted[0][0]))):
            self.bar.update(self.uncounted.popleft()[1])


def point_rows(n: int) -> int:
    """Rows of the device copy of n points: the smallest power of four above n, at least 2^16.

    Row n (and every row after it) is zero padding; few distinct sizes mean few compiled
    kernels across clouds.
    """
    return max(MIN_POINT_ROWS, 1 << (2 * -(-int(n).bit_length() // 2)))


def narrow_widths(count: np.ndarray, *, half_steps: bool = False) -> np.ndarray:
    """The kernel width of rows holding ``count`` (R,) neighbours: the next power of two, at least MIN_WIDTH.

    ``half_steps``: the next of the powers of two and their multiples by 1.5 (..., 64, 96, 128,
    192, ...), for wide rows whose padding costs more than the few more compiled widths.
    """
    count = np.maximum(np.asarray(count), 1)
    width = np.maximum(MIN_WIDTH, 1 << np.frexp(count - 1)[1])
    if half_steps:
        width = np.where((count <= 3 * width // 4) & (width > MIN_WIDTH), 3 * width // 4, width)
    return width


def narrow_split(idx, n: int):
    """The rows of ``idx`` (R, K) (neighbours first, padded with ``n``) grouped by :func:`narrow_widths`.

    Yields:
      (rows, cut): rows (R_w,) the rows of one width w, cut (R_w, w) their columns, cut or
      padded with ``n`` to w; one (empty, (0, MIN_WIDTH)) group when R = 0.
    """
    idx = np.asarray(idx)
    width = narrow_widths((idx < n).sum(axis=1))
    for w in np.unique(width) if width.size else [MIN_WIDTH]:
        rows = np.flatnonzero(width == w)
        cut = idx[rows, :w]
        if cut.shape[1] < w:
            cut = np.pad(cut, ((0, 0), (0, w - cut.shape[1])), constant_values=n)
        yield rows, cut


class NarrowStream:
    """Rows of a narrow kernel, each streamed through the kernel as narrow as its neighbours.

    For kernels whose result does not depend on the number of padding columns (``narrow``
    in :func:`map_neighbourhoods`): a pushed row goes to one :class:`Stream` per width, that
    of :func:`narrow_widths` of its neighbour count, so a few wide rows never widen the
    others. Same interface and results as :class:`Stream`.
    """

    def __init__(self, fn: Callable, ext: tuple, *, args=(), chunk_size: int | None = None, progress: bool = False,
                 total: int = 0):
        self.new = functools.partial(Stream, fn, ext, args=args, chunk_size=chunk_size, total=total)
        self.n, self.streams, self.widths = int(ext[2]), {}, []
        self.bar = _counter(total, progress, chunk_rows(chunk_size, total))

    def push(self, own, idx, row_args=()) -> None:
        """Queue the rows ``own`` (R,) with neighbours ``idx`` (R, K), listed first, and ``row_args``."""
        width = np.empty(np.shape(idx)[0], dtype=np.int64)
        for rows, cut in narrow_split(idx, self.n):
            w = width[rows] = cut.shape[1]
            if w not in self.streams:
                self.streams[w] = self.new()
            self.streams[w].push(np.asarray(own)[rows], cut, tuple(np.asarray(a)[rows] for a in row_args))
        self.widths.append(width)
        if self.bar is not None:
            self.bar.update(width.size)

    def collect(self):
        """``fn``'s outputs of every pushed row, in push order, as NumPy arrays (R, ...)."""
        width = np.concatenate(self.widths)
        if self.bar is not None:
            self.bar.close()
        order = np.argsort(width, kind="stable")  # the rows of each width in push order, narrowest first
        back = np.empty_like(order)
        back[order] = np.arange(order.size)
        parts = [self.streams[w].collect() for w in sorted(self.streams)]
        return jax.tree.map(lambda *xs: np.concatenate(xs)[back], *parts)


def _gathered(fn: Callable, hi, lo, n, own, nbr, row_args, args, block: int = BLOCK):
    """Offsets of the chunk's neighbourhoods gathered on the device, then the block map of ``fn``."""
    valid = nbr < n
    offsets = hi[nbr] - hi[own][:, None, :]
    if lo is not None:
        offsets = offsets + (lo[nbr] - lo[own][:, None, :])
    return _blocks(fn, jnp.where(valid[..., None], offsets, 0), valid, row_args, args, block)


@functools.lru_cache(maxsize=None)
def _jitted(fn: Callable, n_row_args: int) -> Callable:
    del n_row_args  # part of the cache key only
    return jax.jit(functools.partial(_gathered, fn))


@functools.lru_cache(maxsize=None)
def _sharded(fn: Callable, n_row_args: int, n_args: int) -> Callable:
    """The gathered block map with the rows of each chunk split over all local devices."""
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("points",))
    rows, rep = jax.sharding.PartitionSpec("points"), jax.sharding.PartitionSpec()
    body = functools.partial(_gathered, fn)

    def run(hi, lo, n, own, nbr, row_args, args):
        return jax.shard_map(lambda h, lo_, n_, o, b, ra, a: body(h, lo_, n_, o, b, ra, a), mesh=mesh,
                             in_specs=(rep, None if lo is None else rep, rep, rows, rows, (rows,) * n_row_args,
                                       (rep,) * n_args), out_specs=rows, check_vma=False)(hi, lo, n, own, nbr,
                                                                                        row_args, args)

    return jax.jit(run)


def _counter(total: int, progress: bool, chunk: int):
    """The counter of a stream's ``total`` rows sent in chunks of ``chunk``, with ``progress``: the command line's
    run's (:func:`hgjax._progress.current`), else a tqdm bar for a stream of more than 4 chunks."""
    if not progress:
        return None
    run = run_progress.current()
    if run is not None:
        return run.rows(total)
    if total <= 4 * chunk:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # tqdm is optional; progress is then silent
        return None
    return tqdm(total=total, desc="hgjax score", unit="pt", unit_scale=True, file=sys.stderr, leave=False)
