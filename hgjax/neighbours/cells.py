"""Traced neighbour search: the host builder's neighbour sets, in pure JAX, with no capacity to outgrow.

The host builder (:mod:`hgjax.neighbours.spatial`) answers every query with SciPy's k-d tree, which JAX
cannot trace. This module answers the same queries with sorted cells read in fixed-size steps,
so that a search runs under ``jax.jit``, ``jax.vmap`` (equal-N clouds, or a padded batch with a
per-cloud ``count``) and inside ``jax.grad`` (the choice of neighbours is discrete: no gradient
flows through it), on any backend, and no cloud, density or motion can truncate it.

Algorithm (jax-md's cell list without its dense grid of the box and without its capacity;
pytorch3d's ``knn_points`` without its (N, N) work):

1. Cells of a traced edge e: ``floor((p - lo) / e)`` per axis, three int32 coordinates; the
   points are sorted by (z, y, x) cell (lexicographic ``lax.sort`` on the three int32 keys, so
   no 64-bit key and no dense grid: a 2 km x 2 km tile costs what a unit box costs).
2. Sorted by (z, y, x), the three cells x - 1, x, x + 1 of one (z, y) row are one contiguous
   run. A query's 27 neighbouring cells are 9 runs, located by binary searches on the sorted
   keys and read, laid end to end, ``slots`` candidates at a time: a ``while_loop`` until the
   fullest block of the rows is read, each step merged into a running selection. ``slots``
   sets the speed, never the answer.
3. Exact host keys (below) for the candidates; the first columns by (key, global id), the point
   itself first. ``lax.top_k`` preselects the columns plus ``PRESELECT_EXTRA`` by a float32 key
   that never decreases where the exact key grows: where those float32 keys differ, top_k's
   order is the exact one; where some are equal (ties), the preselection is ranked exactly by
   (key, gid); where a block of rows cannot be certain of the preselection (more ties at the
   cut than the margin: lattices, exact duplicates), one exact multi-key ``lax.sort`` of every
   candidate decides (``lax.cond`` each time). Rows are processed in blocks of ``chunk`` rows
   (``lax.map``): memory is about chunk x (columns + slots) candidates, never (N, N).
4. Passes: a row whose reach (the k-th distance, or the radius) passes the boundary of its
   27-cell block (less a rounding margin) is searched again at a wider edge that covers what
   it found, with the other such rows (``spill`` at a time, compacted; one ``while_loop``), so
   the few rows a sampled edge misses (corners, sparse patches) cost a few extra rows, not a
   wider edge for every row. The edge only grows, so the passes end: at the latest when one
   block holds the whole cloud.
5. Honest report: a ball wider than its static columns, or a reach still outside its block
   after :data:`PASSES` passes, could be wrong; the result says so (:attr:`Found.overflow`)
   with the columns and the edge that would do (:attr:`Found.columns_needed`,
   :attr:`Found.edge_needed`). :func:`grown` re-runs eagerly until no overflow; the
   neighbourhood builders stop a traced program that overflows (:func:`hgjax.neighbours.backend.guard`).

Same answers as the host, bit for bit, by the exact arithmetic of :mod:`hgjax._exact`:

* Under x64 (``jax.enable_x64``) the search computes exactly what the host computes: the float64
  local frame of :func:`hgjax.neighbours.spatial.local_frame` (the bounding-box centre subtracted in
  float64, whatever the input dtype), squared distances summed x, y, z in order and rooted as
  cKDTree does (``sqrt((dx*dx + dy*dy) + dz*dz)``), ties by (distance, global id), the point
  itself first. Same bits, hence the same sets and order.
* Without x64, float64 does not exist in JAX. Coordinate differences are then made exact with
  TwoSum, and the squared distance is carried as a normalised float32 pair (hi, lo), about 46
  bits, summed over the axes in a canonical order (by magnitude) so that equal distances made
  of the same components are equal to the last bit. The order equals the host's float64 order
  except where two distances that the host tells apart differ by less than about 2^-44
  relative, or where float64 rounding itself breaks an exact tie: not seen on any test cloud.

HKC/HKF's per-point spacing (:func:`hgjax.neighbours.spatial.local_spacing`) is
:func:`hgjax.neighbours.balls.local_spacing` of a 17-nearest search, in the host's float64 operations and order (NumPy's pairwise mean); their
ball is :func:`within` with ``max_count``; GFR's capped radius graph is :func:`traced_knn` with
``metric="l2sq"`` and ``radius``.

On a CPU the k-d tree stays the default (``bench/results/device_search.md``): the selection
(``top_k`` over the slots read) and the binary searches dominate, both the fast path of an
accelerator.

Why not a library: ``jax-md``'s ``partition.cell_list`` allocates a dense grid of the box
(a 2 km tile at 0.5 m cells is 6e10 cells), answers radius queries only, and breaks ties by
memory order; ``jaxkd`` (a JAX k-d tree) has no (distance, index) tie order, computes in the
working dtype (not the host's float64) and measured 10-25x the cKDTree floor here. Neither gives
the host's neighbour sets.

Sizes that set shapes are static and recompile: ``k``, ``columns``, ``slots``, ``chunk``,
``dedupe``, ``metric``, ``max_count`` and N. Float parameters (``edge``, ``radius``) and
``count`` are traced.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from hgjax import _exact
from hgjax.neighbours import spatial

__all__ = ["Found", "grown", "traced_knn", "within"]

SENTINEL_CELL = np.iinfo(np.int32).max  # cell of a padding row or of a point that is no candidate
MAX_CELL = 1 << 30  # cell coordinates are clipped here (never reached by a sensible edge)
SAMPLES = 64  # points whose brute-force k-th distance sets the default edge
SAMPLE_BLOCK = 1 << 16  # columns per block of that brute force (one top_k per block)
EDGE_MARGIN = 1.1  # default edge: the largest sampled reach times this
CHUNK = 256  # rows per block of the search on a CPU
ACCELERATOR_CHUNK = 8192  # rows per block on a GPU/TPU: fewer, wider steps keep the device busy
SPILL_FRACTION = 8  # by default up to N / 8 rows at a time are searched again at a wider edge
SLOTS = 256  # candidates a query reads per step of its block (a speed setting: blocks are read whole)
PASSES = 64  # later passes at most (each up to ``spill`` rows at a wider edge) before a row is reported uncovered
METRICS = ("l2", "l2sq", "linf")
_KEYS = ("hi", "lo", "gid", "cidx")  # a candidate's fields: exact key (hi, lo), tie key, caller index


@functools.partial(jax.tree_util.register_dataclass,
                   data_fields=["idx", "dist", "reach", "columns_needed", "uncovered", "edge", "edge_needed"],
                   meta_fields=["slots"])
@dataclasses.dataclass(frozen=True)
class Found:
    """The result of a traced search: padded neighbour rows and an honest overflow report.

    A registered pytree: under ``jax.vmap`` every field gains the batch axis (the scalars
    become (B,)).

    Attributes:
      idx: (N, K) int32 neighbour indices into the caller's points, sorted by (distance,
        global id), the point itself first (with ``dedupe``: the first copy of its location);
        padded with the sentinel N. Rows of padding points (``count``) are all N.
      dist: (N, K) the distances of ``idx`` (0 for the point itself; inf at padding): the
        host's float64 values under x64, float32 approximations without it. Squared for
        ``metric="l2sq"``, Chebyshev for ``"linf"``.
      reach: (N,) per row: the k-th distance (:func:`traced_knn`; inf where fewer than k points
        exist) or the radius used (:func:`within`, shrunk by ``max_count``).
      columns_needed: int32 scalar, the widest row (:func:`within`; ``k`` or fewer for traced_knn).
      uncovered: bool scalar, True when some row's reach still passed the boundary of its
        27-cell block after the last level (points outside it may belong to the row).
      edge: scalar, the first level's cell edge (the one to pass again).
      edge_needed: scalar, an edge that covers every row seen (inf when some row found
        fewer than k points and its block is not the whole cloud: grow the edge).
      slots: the candidates a query read per step (static; any block is read whole).
    """

    idx: jax.Array
    dist: jax.Array
    reach: jax.Array
    columns_needed: jax.Array
    uncovered: jax.Array
    edge: jax.Array
    edge_needed: jax.Array
    slots: int = 0

    @property
    def overflow(self):
        """bool (scalar, or (B,) under vmap): the result may be wrong (a row wider than ``idx``,
        or a reach outside its block after the last pass); re-run with :func:`grown`."""
        return (self.columns_needed > self.idx.shape[-1]) | self.uncovered


# ----------------------------------------------------------------------------- distance keys
# (the exact arithmetic they are built on: :mod:`hgjax._exact`)


def _abs_diffs(q, c):
    """Per axis |q - c| as exact normalised pairs (hi, lo), each (..., 3)."""
    h, l = _exact.two_sum(q, -c)
    neg = h < 0
    return jnp.where(neg, -h, h), jnp.where(neg, -l, l)


def _sorted3(h, l):
    """The three pairs (..., 3) sorted ascending (a compare-exchange network): a canonical order."""
    hs, ls = [h[..., a] for a in range(3)], [l[..., a] for a in range(3)]
    for i, j in ((0, 1), (1, 2), (0, 1)):
        swap = _exact.pair_less(hs[j], ls[j], hs[i], ls[i])
        hs[i], hs[j] = jnp.where(swap, hs[j], hs[i]), jnp.where(swap, hs[i], hs[j])
        ls[i], ls[j] = jnp.where(swap, ls[j], ls[i]), jnp.where(swap, ls[i], ls[j])
    return hs, ls


def _pair_keys(q, c, metric):
    """float32 pair keys (hi, lo) of the distances from queries q (..., 1, 3) to candidates c (..., C, 3)."""
    h, l = _abs_diffs(q, c)
    hs, ls = _sorted3(h, l)
    if metric == "linf":
        return hs[2], ls[2]
    sq = [_exact.pair_square(hs[a], ls[a]) for a in range(3)]
    s = _exact.pair_add(*sq[2], *sq[1])
    return _exact.pair_add(*s, *sq[0])


def _host_keys(q, c, metric):
    """float64 keys exactly as cKDTree computes them on the local frame (query minus point)."""
    d = q - c
    if metric == "linf":
        return jnp.max(jnp.abs(d), axis=-1), None
    sq = _exact.mul(d, d)
    s = (sq[..., 0] + sq[..., 1]) + sq[..., 2]
    return (s if metric == "l2sq" else jnp.sqrt(s)), None


def _in_units(hi, metric):
    """A key's leading part in the metric's units (the pair key of "l2" is a squared distance)."""
    return jnp.sqrt(jnp.maximum(hi, 0)) if metric == "l2" and not _x64() else jnp.maximum(hi, 0)


def _as_distance(value, metric):
    """A value in the metric's units as a distance (the coverage test compares distances)."""
    return jnp.sqrt(value) if metric == "l2sq" else value


def _below(hi, lo, h, metric, h_lo=None):
    """Whether keys (B, W) lie strictly below the radii ``h`` (B,) (plus their pairs' trailing parts
    ``h_lo`` (B,), where given), in the metric's units."""
    h = h[:, None]
    if lo is None:
        return hi < h
    h_lo = jnp.zeros_like(h) if h_lo is None else h_lo[:, None]
    if metric == "l2":  # the squared radius as an exact pair (an infinite radius stays infinite)
        hh, hl = _exact.pair_square(h, h_lo)
        finite = jnp.isfinite(h)
        return _exact.pair_less(hi, lo, jnp.where(finite, hh, h), jnp.where(finite, hl, 0))
    return _exact.pair_less(hi, lo, h, h_lo)


def _x64() -> bool:
    return bool(jax.config.jax_enable_x64)


# ----------------------------------------------------------------------------- the cell structure

@functools.partial(jax.tree_util.register_dataclass,
                   data_fields=["coords", "real", "gid", "qorder", "rep", "qcell", "keys", "cpoint", "cgid", "cidx",
                                "n_cand", "lo", "edge", "delta"], meta_fields=[])
@dataclasses.dataclass(frozen=True)
class _Cloud:
    """Everything a block of queries reads (all in the search's coordinates)."""

    coords: jax.Array  # (N, 3) computation coordinates (caller order)
    real: jax.Array  # (N,) bool
    gid: jax.Array  # (N,) int32 tie key
    qorder: jax.Array  # (N,) caller index of each query position (cells, then coordinates)
    rep: jax.Array  # (N,) the point whose radius a point's query uses (``dedupe``: its location's first copy)
    qcell: jax.Array  # (N, 3) int32 cell of each caller point (0 for padding)
    keys: tuple  # 3 x (N,) int32 sorted candidate cells (z, y, x), SENTINEL_CELL for non-candidates
    cpoint: jax.Array  # (N, 3) candidate coordinates in that order
    cgid: jax.Array  # (N,) candidate tie keys
    cidx: jax.Array  # (N,) candidate caller indices
    n_cand: jax.Array  # int32 scalar, the number of candidates
    lo: jax.Array  # (3,) the cells' origin
    edge: jax.Array  # scalar
    delta: jax.Array  # scalar rounding margin, in edges


def _coordinates(points, real, frame: bool = True):
    """The search's coordinates: the host's float64 local frame under x64 (the points as given
    when ``frame`` is False: already in the host's frame, as a tile's index holds them), else
    the float32 input."""
    if _x64():
        p = points.astype(jnp.float64)
        if not frame:
            return p
        lo = jnp.min(jnp.where(real[:, None], p, jnp.inf), axis=0)
        hi = jnp.max(jnp.where(real[:, None], p, -jnp.inf), axis=0)
        return p - ((lo + hi) / 2)[None, :]
    return points.astype(jnp.float32)


def _eligible(coords, real, cell, dedupe):
    """(qorder, candidate mask, rep): the query order (cells, then coordinates, then index),
    which points are candidates (every real point, or with ``dedupe`` the first copy of each
    location) and each point's representative (itself, or with ``dedupe`` its location's first copy)."""
    n = coords.shape[0]
    iota = jnp.arange(n, dtype=jnp.int32)
    cz, cy, cx = cell[:, 2], cell[:, 1], cell[:, 0]
    if not dedupe:
        qorder = lax.sort((cz, cy, cx, iota), num_keys=4)[-1]
        return qorder, real, iota
    out = lax.sort((cz, cy, cx, coords[:, 0], coords[:, 1], coords[:, 2], iota), num_keys=7)
    qorder = out[-1]
    p = coords[qorder]
    same = jnp.concatenate([jnp.zeros(1, bool), jnp.all(p[1:] == p[:-1], axis=1)])
    first = ~same & real[qorder]  # (padding rows sort last: a real row never follows one)
    rep = qorder[lax.cummax(jnp.where(same, 0, iota))]
    return qorder, jnp.zeros(n, bool).at[qorder].set(first), jnp.zeros(n, jnp.int32).at[qorder].set(rep)


def _cloud(points, count, gid, edge, dedupe, frame: bool = True) -> _Cloud:
    n = points.shape[0]
    iota = jnp.arange(n, dtype=jnp.int32)
    real = iota < (n if count is None else count)
    coords = _coordinates(lax.stop_gradient(points), real, frame)
    gid = iota if gid is None else jnp.asarray(gid, jnp.int32)
    lo = jnp.min(jnp.where(real[:, None], coords, jnp.inf), axis=0)
    t = (coords - lo[None, :]) / edge
    top = jnp.max(jnp.where(real[:, None], t, 0))
    eps = jnp.finfo(coords.dtype).eps / 2
    delta = 16 * eps * (jnp.minimum(top, MAX_CELL) + 4)
    cell = jnp.floor(jnp.clip(t, 0, MAX_CELL)).astype(jnp.int32)
    cell = jnp.where(real[:, None], cell, SENTINEL_CELL)
    qorder, cand, rep = _eligible(coords, real, cell, dedupe)
    ccell = jnp.where(cand[:, None], cell, SENTINEL_CELL)
    corder = lax.sort((ccell[:, 2], ccell[:, 1], ccell[:, 0], iota), num_keys=4)[-1]
    keys = tuple(ccell[corder, a] for a in (2, 1, 0))
    return _Cloud(coords, real, gid, qorder, rep, jnp.where(real[:, None], cell, 0), keys, coords[corder],
                  gid[corder], corder, jnp.sum(cand, dtype=jnp.int32), lo, edge, delta)


def _lower_bound(keys, q):
    """The number of sorted triples ``keys`` (3 x (N,)) lexicographically below each ``q`` (3 x (...)).

    A binary search by halving steps in a ``fori_loop`` (unrolled, XLA's fusion would copy each
    step into every later one).
    """
    n = keys[0].shape[0]
    steps = max(n.bit_length(), 1)

    def step(i, pos):
        cand = pos + (1 << (steps - 1)) // (1 << i)
        probe = jnp.minimum(cand, n) - 1
        kz, ky, kx = (k[probe] for k in keys)
        less = (kz < q[0]) | ((kz == q[0]) & ((ky < q[1]) | ((ky == q[1]) & (kx < q[2]))))
        return jnp.where((cand <= n) & less, cand, pos)

    return lax.fori_loop(0, steps, step, jnp.zeros(q[0].shape, jnp.int32))


_ROWS = tuple(itertools.product((-1, 0, 1), repeat=2))  # (dz, dy) of the 9 runs


def _block(cloud: _Cloud, qi):
    """Where the queries ``qi`` (B,) (caller indices) read their 27-cell blocks.

    Sorted by (z, y, x) cell, a block is 9 runs of the sorted candidates (three cells of one
    (z, y) row each), located by binary searches.

    Returns:
      dict of (B, 9) ``begin`` and ``ends`` (where each run starts among the sorted candidates,
      and where it ends among the block's slots laid end to end) and (B,) ``slack`` (the
      distance the block is known to cover), ``complete`` (the block holds every candidate of
      the cloud) and ``count`` (the block's candidates).
    """
    cell = cloud.qcell[qi]  # (B, 3) x, y, z
    dz = jnp.array([r[0] for r in _ROWS], jnp.int32)
    dy = jnp.array([r[1] for r in _ROWS], jnp.int32)
    z, y = cell[:, 2:3] + dz[None, :], cell[:, 1:2] + dy[None, :]  # (B, 9)
    x = jnp.broadcast_to(cell[:, 0:1], z.shape)
    begin = _lower_bound(cloud.keys, (z, y, x - 1))
    ends = jnp.cumsum(_lower_bound(cloud.keys, (z, y, x + 2)) - begin, axis=1)
    # The block [c - 1, c + 2) per axis, in edges from the query, less the rounding margin.
    t = (cloud.coords[qi] - cloud.lo[None, :]) / cloud.edge
    c = cell.astype(t.dtype)
    room = jnp.min(jnp.minimum(t - (c - 1), (c + 2) - t), axis=1)
    count = ends[:, -1]
    return dict(begin=begin, ends=ends, slack=cloud.edge * (room - cloud.delta), complete=count == cloud.n_cand,
                count=count)


def _slots(cloud: _Cloud, qi, block, offset, slots: int, metric: str):
    """The candidates in slots [offset, offset + slots) of each query's block and their exact keys.

    Slot j is the j-th point of the block's 9 runs laid end to end.

    Returns:
      dict of (B, slots) ``hi``, ``lo`` (None under x64), ``gid`` and ``cidx`` (caller index,
      -1 where the slot is past the block's end).
    """
    n = cloud.coords.shape[0]
    begin, ends = block["begin"], block["ends"]
    slot = offset + jnp.arange(slots, dtype=jnp.int32)
    run = jnp.sum(slot[None, :, None] >= ends[:, None, :], axis=2)  # (B, S) which run a slot reads
    valid = run < len(_ROWS)
    run = jnp.minimum(run, len(_ROWS) - 1)
    start = jnp.take_along_axis(jnp.concatenate([jnp.zeros_like(ends[:, :1]), ends[:, :-1]], axis=1), run, axis=1)
    pos = jnp.clip(jnp.take_along_axis(begin, run, axis=1) + slot[None, :] - start, 0, n - 1)
    cand = cloud.cpoint[pos]  # (B, S, 3)
    q = cloud.coords[qi][:, None, :]
    cidx = cloud.cidx[pos]
    me = cidx == qi[:, None]
    if _x64():
        hi, lo = _host_keys(q, cand, metric)
    else:
        hi, lo = _pair_keys(q, cand, metric)
        lo = jnp.where(valid & ~me, lo, 0)
    hi = jnp.where(valid, jnp.where(me, -1, hi), jnp.inf)
    gid = jnp.where(valid, cloud.gid[cidx], np.iinfo(np.int32).max)
    return dict(hi=hi, lo=lo, gid=gid, cidx=jnp.where(valid, cidx, -1))


def _scan(cloud: _Cloud, qi, block, width: int, slots: int, metric: str, fold=None, acc=None):
    """The first ``width`` candidates of each query's whole block by (key, global id), exactly.

    The block is read ``slots`` at a time (a ``while_loop`` until the fullest block of the
    rows is read) and merged into a running selection, so no block is ever truncated and
    memory is about B x (width + slots) candidates whatever the density. ``fold(acc, c)``
    also sees every chunk of candidates (e.g. to count those inside a radius).

    Returns:
      (best, acc): dict of (B, width) ``hi``, ``lo``, ``gid``, ``cidx`` (inf keys and -1
      past the block's candidates), and the folded value.
    """
    b = qi.shape[0]
    x64 = _x64()
    dtype = jnp.float64 if x64 else jnp.float32
    best = dict(hi=jnp.full((b, width), jnp.inf, dtype), lo=None if x64 else jnp.zeros((b, width), dtype),
                gid=jnp.full((b, width), np.iinfo(np.int32).max, jnp.int32), cidx=jnp.full((b, width), -1, jnp.int32))
    total = jnp.max(block["count"])

    def step(state):
        offset, best, acc = state
        c = _slots(cloud, qi, block, offset, slots, metric)
        if fold is not None:
            acc = fold(acc, c)
        both = {name: (None if c[name] is None else jnp.concatenate([best[name], c[name]], axis=1)) for name in _KEYS}
        return offset + slots, _select(both, width, cloud.edge, metric), acc

    _, best, acc = lax.while_loop(lambda s: s[0] < total, step, (jnp.int32(0), best, acc))
    return best, acc


def _exact_less(a, b):
    """Strict order of candidates by (hi, lo, gid, slot) between two dicts of broadcastable arrays."""
    lt = a["gid"] < b["gid"]
    eq = a["gid"] == b["gid"]
    lt = lt | (eq & (a["slot"] < b["slot"]))
    if a["lo"] is not None:
        lt = (a["lo"] < b["lo"]) | ((a["lo"] == b["lo"]) & lt)
    return (a["hi"] < b["hi"]) | ((a["hi"] == b["hi"]) & lt)


PRESELECT_EXTRA = 16  # candidates preselected beyond the columns kept (the fast path's margin for ties)
RANK_LIMIT = 64  # preselections up to this size are ordered by pairwise ranks, larger ones by a sort


def _fields(c):
    return [name for name in ("hi", "lo", "gid", "cidx") if c[name] is not None]


def _sorted_exact(c, width: int):
    """The first ``width`` candidates (B, C) by (hi, lo, gid): one exact multi-key sort of every candidate."""
    names = _fields(c)
    out = lax.sort(tuple(c[name] for name in names), num_keys=len(names) - 1)
    got = {name: x[:, :width] for name, x in zip(names, out)}
    got.setdefault("lo", None)
    return got


def _approximate(hi, edge, metric: str):
    """float32 keys that never decrease where the exact keys ``hi`` grow: ``hi`` itself in float32;
    float64 keys (x64) first divided by the cell ``edge`` (twice for ``metric="l2sq"``): a block's
    keys are a few edges at most, so keys beyond float32's range (a cloud scaled by 1e150 or
    1e-138) neither overflow nor all round to 0 (correctly rounded divisions and casts are monotone)."""
    if hi.dtype != jnp.float64:
        return hi
    scaled = hi / edge
    return (scaled / edge if metric == "l2sq" else scaled).astype(jnp.float32)


def _sorted_fast(c, width: int, edge, metric: str):
    """The first ``width`` candidates by (hi, lo, gid), and (B,) whether that is certain.

    ``lax.top_k`` preselects ``width + PRESELECT_EXTRA`` candidates by a float32 key that is
    monotone in the exact one (never decreasing where the exact key grows,
    :func:`_approximate`); they are then ordered exactly. Certain where the preselection's last
    key exceeds its ``width``-th (every candidate up to the ``width``-th exact one is then
    inside), or where the row holds fewer candidates than that.
    """
    cap = c["hi"].shape[1]
    p = min(width + PRESELECT_EXTRA, cap)
    approx = _approximate(c["hi"], edge, metric)
    top, at = lax.top_k(-approx, p)
    pick = {name: (None if c[name] is None else jnp.take_along_axis(c[name], at, axis=1))
            for name in ("hi", "lo", "gid", "cidx")}
    pick["slot"] = at
    w = min(width, p)
    a = -top  # ascending approximate keys
    certain = (a[:, -1] > a[:, w - 1]) | jnp.isinf(a[:, w - 1]) | (p == cap)
    names = [name for name in ("hi", "lo", "gid", "cidx") if pick[name] is not None]

    def ranked():
        if p > RANK_LIMIT:
            got = _sorted_exact(pick, w)
            return tuple(got[name] for name in names)
        x = {name: (None if v is None else v[:, :, None]) for name, v in pick.items()}
        y = {name: (None if v is None else v[:, None, :]) for name, v in pick.items()}
        rank = jnp.sum(_exact_less(x, y), axis=1)  # (B, P): how many candidates precede each
        where = jnp.argmax(rank[:, None, :] == jnp.arange(w)[None, :, None], axis=2)  # (B, W) the one at each rank
        return tuple(jnp.take_along_axis(pick[name], where, axis=1) for name in names)

    # Where the approximate keys of the first columns (and the cut) differ, top_k's order is the
    # exact one (the approximation never reorders); only equal ones need the exact ranking.
    m = min(w + 1, p)
    tied = jnp.any((a[:, 1:m] == a[:, :m - 1]) & jnp.isfinite(a[:, :m - 1]), axis=1) if m > 1 else jnp.zeros_like(certain)
    out = lax.cond(jnp.any(tied), ranked, lambda: tuple(pick[name][:, :w] for name in names))
    got = dict(zip(names, out))
    got.setdefault("lo", None)
    return got, certain


def _select(c, width: int, edge, metric: str):
    """The first ``width`` candidates of every row (pads with inf keys): the fast path where it is
    certain for the whole block of rows, else one exact sort (``lax.cond``); ``edge`` and
    ``metric`` as :func:`_approximate`."""
    cap = c["hi"].shape[1]
    if width > cap:  # fewer slots than columns: pad the candidates
        pad = width - cap
        c = dict(c, hi=jnp.pad(c["hi"], ((0, 0), (0, pad)), constant_values=jnp.inf),
                 lo=None if c["lo"] is None else jnp.pad(c["lo"], ((0, 0), (0, pad))),
                 gid=jnp.pad(c["gid"], ((0, 0), (0, pad)), constant_values=np.iinfo(np.int32).max),
                 cidx=jnp.pad(c["cidx"], ((0, 0), (0, pad)), constant_values=-1))
    keys = {name: c[name] for name in ("hi", "lo", "gid", "cidx")}
    fast, certain = _sorted_fast(dict(keys), width, edge, metric)
    ok = jnp.all(certain)
    names = [name for name in ("hi", "lo", "gid", "cidx") if keys[name] is not None]
    out = lax.cond(ok, lambda: tuple(fast[name] for name in names),
                   lambda: tuple(_sorted_exact(dict(keys), width)[name] for name in names))
    got = dict(zip(names, out))
    got.setdefault("lo", None)
    return got


def _default_edge(coords, real, cand_mask, k: int):
    """A traced edge: EDGE_MARGIN x the largest k-th distance over SAMPLES points (brute force)."""
    n = coords.shape[0]
    count = jnp.sum(real, dtype=jnp.int32)
    s = min(SAMPLES, n)
    rows = (jnp.arange(s, dtype=jnp.int32) * jnp.maximum(count, 1)) // s
    q = coords[rows]
    kk = min(k, n)
    block = min(SAMPLE_BLOCK, n)
    blocks = -(-n // block)
    pad = blocks * block - n
    c = jnp.concatenate([coords, jnp.zeros((pad, 3), coords.dtype)]).reshape(blocks, block, 3)
    ok = jnp.concatenate([cand_mask, jnp.zeros(pad, bool)]).reshape(blocks, block)
    lo = jnp.min(jnp.where(real[:, None], coords, jnp.inf), axis=0)
    hi = jnp.max(jnp.where(real[:, None], coords, -jnp.inf), axis=0)
    extent = jnp.max(hi - lo)
    unit = jnp.where(extent > 0, extent, 1)  # distances in extents: float32 holds them at any scale

    def step(best, xs):
        cb, okb = xs
        d = (q[:, None, :] - cb[None]) / unit
        # float32 (an estimate; XLA's CPU top_k is fast for float32 only)
        sq = jnp.where(okb[None], jnp.sum(d * d, axis=-1), jnp.inf).astype(jnp.float32)
        both = jnp.concatenate([best, sq], axis=1)
        return -lax.top_k(-both, kk)[0], None

    best, _ = lax.scan(step, jnp.full((s, kk), jnp.inf, jnp.float32), (c, ok))
    reach = jnp.sqrt(best[:, -1].astype(coords.dtype)) * unit
    floor = extent * (2.0 ** (-16 if coords.dtype == jnp.float32 else -28))
    finite = jnp.where(jnp.isfinite(reach), reach, 0)
    edge = jnp.maximum(EDGE_MARGIN * jnp.max(finite), floor)
    # no finite reach (fewer than k candidates anywhere): one cell holds the whole cloud
    edge = jnp.where(jnp.all(jnp.isfinite(reach)), edge, 2 * extent)
    return jnp.where(edge > 0, edge, 1.0)


def _edge(points, count, edge, dedupe, k, frame: bool = True):
    """The given edge in the computation dtype, or the default from the data."""
    n = points.shape[0]
    real = jnp.arange(n) < (n if count is None else count)
    coords = _coordinates(lax.stop_gradient(points), real, frame)
    if edge is not None:
        return jnp.asarray(edge, coords.dtype)
    cand = real
    if dedupe:
        iota = jnp.arange(n, dtype=jnp.int32)
        out = lax.sort((coords[:, 0], coords[:, 1], coords[:, 2], iota), num_keys=4)
        p = jnp.stack(out[:3], axis=1)
        same = jnp.concatenate([jnp.zeros(1, bool), jnp.all(p[1:] == p[:-1], axis=1)])
        cand = jnp.zeros(n, bool).at[out[3]].set(~same) & real
    return _default_edge(coords, real, cand, k)


def _chunk(chunk, n: int) -> int:
    """Rows per block: ``chunk``, or the backend's default (:data:`CHUNK` on CPU, :data:`ACCELERATOR_CHUNK` else)."""
    if chunk is None:
        chunk = CHUNK if jax.default_backend() == "cpu" else ACCELERATOR_CHUNK
    return max(1, min(chunk, n))


def _spill(spill, n: int) -> int:
    """Rows of the second level: ``spill``, or N / 8 by default."""
    if spill is None:
        return max(1, n // SPILL_FRACTION)
    if not isinstance(spill, (int, np.integer)) or isinstance(spill, bool) or spill < 0:
        raise ValueError(f"spill must be a non-negative int or None; got {spill!r}")
    return int(spill)


def _check(points, k_or_columns: int, slots: int, chunk: int, metric: str):
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (N, 3); got {points.shape}")
    if not jnp.issubdtype(points.dtype, jnp.floating):
        raise TypeError(f"points must be floating point; got {points.dtype}")
    if points.shape[0] < 1:
        raise ValueError("points must hold at least one point")
    for name, value in (("k", k_or_columns), ("slots", slots), ("chunk", chunk)):
        if name == "chunk" and value is None:
            continue
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
            raise ValueError(f"{name} must be a positive int; got {value!r}")
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; expected one of {sorted(METRICS)}")


def _grow(limit, delta):
    """The edge that covers a reach ``limit`` at any place in a cell (inf stays inf)."""
    return jnp.where(jnp.isfinite(limit), limit * (1 + 4 * delta) * 1.0001, jnp.inf)


def _run(points, count, gid, edge, dedupe: bool, rows, chunk: int, spill: int, frame: bool = True):
    """``rows(cloud, qi)`` over every row, then the rows whose reach passed their block again.

    One ``while_loop`` of passes over ``size`` rows each (``lax.map`` over chunks inside), so
    the row kernel is compiled once: the first passes take the rows in cell order at ``edge``;
    each later pass (up to :data:`PASSES`, none when ``spill`` is 0)
    takes up to ``size`` rows whose reach passed their block (compacted), at an edge that
    covers the reaches they found (four times the last edge where a row found too few).

    Returns:
      (out, cloud): the per-row outputs (caller order) and the first level's cloud.
    """
    cloud = _cloud(points, count, gid, edge, dedupe, frame)
    n = cloud.coords.shape[0]
    size = -(-max(1, min(n, spill or n // SPILL_FRACTION)) // chunk) * chunk
    first = -(-n // size)  # passes of the first level
    last_pass = first + (PASSES if spill else 0)
    order = jnp.concatenate([cloud.qorder, jnp.full(first * size - n, n, jnp.int32)])  # n: no row
    shapes = jax.eval_shape(functools.partial(rows, cloud), jnp.zeros(chunk, jnp.int32))
    out = jax.tree.map(lambda x: jnp.zeros((n,) + x.shape[1:], x.dtype), shapes)

    def wrong(out):
        return cloud.real & ~out["ok"]

    def step(state):
        out, level, last, t = state
        spilling = t >= first

        def widen():
            grow = _grow(out["limit"], cloud.delta)
            wider = jnp.max(jnp.where(wrong(out), jnp.where(jnp.isfinite(grow), grow, 4 * last), 0))
            wider = jnp.maximum(wider, last)
            return _cloud(points, count, gid, wider, dedupe, frame), wider

        level, last = lax.cond(spilling, widen, lambda: (level, last))
        which = jnp.where(spilling, jnp.nonzero(wrong(out), size=size, fill_value=n)[0],
                          lax.dynamic_slice(order, (jnp.minimum(t, first - 1) * size,), (size,)))
        got = lax.map(functools.partial(rows, level), jnp.minimum(which, n - 1).reshape(-1, chunk))
        got = jax.tree.map(lambda x: x.reshape((size,) + x.shape[2:]), got)
        out = jax.tree.map(lambda x, y: x.at[which].set(y, mode="drop"), out, got)
        return out, level, last, t + 1

    def more(state):
        out, _, _, t = state
        return (t < first) | ((t < last_pass) & jnp.any(wrong(out)))

    out, _, _, _ = lax.while_loop(more, step, (out, cloud, cloud.edge, jnp.int32(0)))
    return out, cloud


def _found(cloud: _Cloud, out, slots: int, columns_needed, empty_reach) -> Found:
    """The :class:`Found` of per-row outputs: padding rows emptied, the overflow report summed up."""
    n = cloud.coords.shape[0]
    real = cloud.real
    bad = real & ~out["ok"]
    edge_needed = jnp.maximum(cloud.edge, jnp.max(jnp.where(bad, _grow(out["limit"], cloud.delta), 0)))
    return Found(jnp.where(real[:, None], out["idx"], n).astype(jnp.int32),
                 jnp.where(real[:, None], out["dist"], jnp.inf),
                 jnp.where(real, out["reach"], empty_reach),
                 columns_needed=columns_needed, uncovered=jnp.any(bad), edge=cloud.edge, edge_needed=edge_needed,
                 slots=slots)


# ----------------------------------------------------------------------------- public queries

def traced_knn(points, k: int, *, dedupe: bool = False, slots: int = SLOTS, edge=None, count=None, gid=None,
        radius=None, metric: str = "l2", chunk: int | None = None, spill: int | None = None,
        frame: bool = True) -> Found:
    """The point itself and its k - 1 nearest points by (distance, global id): :func:`hgjax.neighbours.nearest.knn`, traced.

    Pure JAX: runs under ``jax.jit`` and ``jax.vmap``; no gradient flows through the choice.

    Args:
      points: (N, 3) float points (any frame: distances are translation-invariant; under
        x64 they are computed in the host's float64 local frame).
      k: neighbourhood size counting the point itself (static).
      dedupe: count exact duplicates once, as the host's ``dedupe`` (static): every copy gets
        the row of its location, whose first column is the location's first copy.
      slots: candidates a query reads per step of its block (static; a speed setting only:
        every block is read whole, however many points it holds).
      edge: the cell edge (traced), or None for a default from the data (the largest k-th
        distance of 64 sampled points, brute force, times 1.1).
      count: int32 scalar, the number of real points (the first ``count`` rows; traced), or
        None (all). Padding rows are neither neighbours nor queried.
      gid: (N,) int32 global ids that break ties (default the row numbers).
      radius: optional upper bound (traced, scalar or (N,)): only points closer than it
        (in the units of ``metric``) are listed: GFR's capped radius graph with
        ``metric="l2sq"``. With ``dedupe`` every copy uses its location's first copy's.
      metric: ``"l2"`` (the host's k-nearest: rank by the rooted distance), ``"l2sq"`` (rank
        by squared distances, as GFR) or ``"linf"`` (Chebyshev) (static).
      chunk: rows per block (static; default :data:`CHUNK` on CPU, :data:`ACCELERATOR_CHUNK` on a
        GPU/TPU): memory is about chunk x (k + slots) candidates.
      spill: rows searched again, at a time, at a wider edge when their reach passes their
        block (static; default N / 8, rounded up to whole chunks; 0: none), for at most
        :data:`PASSES` passes. The default edge comes from a sample, so the few rows it
        misses (corners, sparse patches) are redone here, not by the caller; rows still
        missed are reported (``uncovered``).
      frame: under x64, move the points to the host's local frame first (static); False for
        points already in the host's frame (a tile's index), whose distances are then the
        host's own.

    Returns:
      :class:`Found` with idx (N, k) int32 padded with N (fewer than k candidates, or beyond
      ``radius``), dist (N, k), reach (N,) the k-th distance.

    Raises:
      TypeError, ValueError: invalid shapes or static arguments.

    Examples:
      >>> import numpy as np, jax
      >>> from hgjax.neighbours import balls, cells, nearest
      >>> p = np.random.default_rng(0).random((200, 3)).astype(np.float32)
      >>> found = jax.jit(lambda p: cells.traced_knn(p, 8))(p)
      >>> found.idx.shape, bool(found.overflow), bool((found.idx[:, 0] == np.arange(200)).all())
      ((200, 8), False, True)
    """
    points = jnp.asarray(points)
    _check(points, k, slots, chunk, metric)
    n = points.shape[0]
    e = _edge(points, count, edge, dedupe, k, frame)
    bound = None if radius is None else jnp.broadcast_to(jnp.asarray(radius, e.dtype), (n,))

    def rows(cloud, qi):
        block = _block(cloud, qi)
        s, _ = _scan(cloud, qi, block, k, slots, metric)
        hi, lo = s["hi"], s["lo"]
        found = hi < jnp.inf
        if bound is not None:
            found = found & _below(hi, lo, bound[cloud.rep[qi]], metric)
        value = _in_units(hi, metric)
        reach = jnp.where(found[:, -1], value[:, -1], jnp.inf)
        limit = _as_distance(reach if bound is None else jnp.minimum(reach, bound[cloud.rep[qi]]), metric)
        ok = block["complete"] | (limit < block["slack"])
        return dict(idx=jnp.where(found, s["cidx"], n), dist=jnp.where(found, value, jnp.inf), reach=reach,
                    limit=limit, ok=ok)

    out, cloud = _run(points, count, gid, e, dedupe, rows, _chunk(chunk, n), _spill(spill, n), frame)
    return _found(cloud, out, slots, jnp.int32(k), jnp.inf)


def within(points, radius, *, columns: int, dedupe: bool = False, slots: int = SLOTS, edge=None, count=None,
           gid=None, metric: str = "l2", max_count: int | None = None, chunk: int | None = None,
           spill: int | None = None, radius_lo=None, frame: bool = True) -> Found:
    """Every point closer than ``radius`` (strictly), by (distance, global id): the host's
    :meth:`hgjax.neighbours.spatial.SpatialIndex.cube` (``metric="linf"``: the cube of HKC/HKF's reference
    variant; ``"l2"``: the ball of their invariant variant), traced.

    Args:
      points: (N, 3) float points.
      radius: traced scalar or (N,) per-point radius (half-width), > 0, in the search's
        float dtype (float64 under x64). With ``dedupe`` every copy uses its location's first
        copy's radius (the host queries each location once).
      columns: columns K of ``idx`` (static); a wider row is reported (``columns_needed``).
      dedupe, edge, count, gid, chunk, spill, frame: as :func:`traced_knn`.
      slots: as :func:`traced_knn`; a ball reads at least twice its columns (with ``max_count``, the
        larger of the two) per step, so that a step is not mostly the running selection. The default edge is the
        largest radius times 1.1 (traced).
      metric: ``"l2"``, ``"l2sq"`` (``radius`` is then a squared radius) or ``"linf"`` (static).
      max_count: the host's ``max_count`` (static): a row whose ball holds ``max_count``
        points or more shrinks its radius to the distance of its ``max_count``-th nearest
        point, so it holds fewer, all of them.
      radius_lo: without x64, the trailing part of a float32 pair (``radius``, ``radius_lo``)
        that carries a float64 radius (scalar or (N,)), compared exactly; None: 0.

    Returns:
      :class:`Found` with idx (N, K) int32 padded with N, dist (N, K), reach (N,) the radius
      used (shrunk where ``max_count`` applies).

    Raises:
      TypeError, ValueError: invalid shapes or static arguments.

    Examples:
      >>> import numpy as np
      >>> from hgjax.neighbours import cells
      >>> p = np.array([[0., 0, 0], [1, 0, 0], [5, 0, 0]], np.float32)
      >>> found = cells.within(p, 1.5, columns=4, metric="linf")
      >>> (np.asarray(found.idx) < 3).sum(axis=1).tolist(), bool(found.overflow)
      ([2, 2, 1], False)
    """
    points = jnp.asarray(points)
    _check(points, columns, slots, chunk, metric)
    if max_count is not None and (not isinstance(max_count, int) or max_count < 1):
        raise ValueError(f"max_count must be a positive int or None; got {max_count!r}")
    n = points.shape[0]
    real = jnp.arange(n) < (n if count is None else count)
    dtype = _coordinates(jnp.zeros((1, 3), points.dtype), jnp.ones(1, bool)).dtype
    bound = jnp.broadcast_to(jnp.asarray(radius, dtype), (n,))
    bound_lo = None if radius_lo is None else jnp.broadcast_to(jnp.asarray(radius_lo, dtype), (n,))
    if edge is None:
        top = jnp.max(jnp.where(real, bound, 0))
        edge = EDGE_MARGIN * (jnp.sqrt(top) if metric == "l2sq" else top)
    width = columns if max_count is None else max(columns, max_count)

    def rows(cloud, qi):
        block = _block(cloud, qi)
        h = bound[cloud.rep[qi]]  # with dedupe, every copy asks its location's first copy's query
        h_lo = None if bound_lo is None else bound_lo[cloud.rep[qi]]

        def inside(acc, c):  # every candidate of the ball, counted exactly
            return acc + jnp.sum(_below(c["hi"], c["lo"], h, metric, h_lo), axis=1, dtype=jnp.int32)

        s, held = _scan(cloud, qi, block, width, max(slots, 2 * width), metric, inside, jnp.zeros(qi.shape, jnp.int32))
        take = _below(s["hi"], s["lo"], h, metric, h_lo)
        used = h
        if max_count is not None:  # a full ball shrinks to exclude its max_count-th point
            full = held >= max_count
            m = max_count - 1
            cut_hi = jnp.maximum(s["hi"][:, m], 0)
            cut_lo = jnp.zeros_like(h) if s["lo"] is None else jnp.where(s["hi"][:, m] < 0, 0, s["lo"][:, m])
            below_cut = _exact.pair_less(s["hi"], jnp.zeros_like(s["hi"]) if s["lo"] is None else s["lo"],
                                         cut_hi[:, None], cut_lo[:, None])
            take = jnp.where(full[:, None], below_cut, take)
            held = jnp.where(full, jnp.sum(below_cut, axis=1, dtype=jnp.int32), held)
            used = jnp.where(full, _in_units(cut_hi, metric), h)
        take = take[:, :columns]
        ok = block["complete"] | (_as_distance(used, metric) < block["slack"])
        return dict(idx=jnp.where(take, s["cidx"][:, :columns], n),
                    dist=jnp.where(take, _in_units(s["hi"][:, :columns], metric), jnp.inf),
                    reach=used, limit=_as_distance(used, metric), ok=ok, width=held)

    out, cloud = _run(points, count, gid, jnp.asarray(edge, dtype), dedupe, rows, _chunk(chunk, n), _spill(spill, n),
                      frame)
    columns_needed = jnp.max(jnp.where(cloud.real, out["width"], 0)).astype(jnp.int32)
    return _found(cloud, out, slots, columns_needed, 0)


# ----------------------------------------------------------------------------- eager regrowth

def grown(query, points, *args, edge=None, max_rounds: int = 12, **kwargs) -> Found:
    """Run ``query`` (:func:`traced_knn` or :func:`within`) eagerly until it does not overflow (host loop, not jittable).

    Each round is one jitted call; a round that overflows is run again with the columns (of
    :func:`within`) that it reports needed, rounded up to a power of two, or with the edge it
    reports needed (four times the edge where a row found too few points). Nothing is ever
    truncated: the result is the traced query's exact answer.

    Args:
      query: :func:`traced_knn` or :func:`within`.
      points, *args, **kwargs: the query's arguments (``k`` of :func:`traced_knn` and ``radius`` of
        :func:`within` may be positional).
      edge: the first round's edge (default: the query's own default).
      max_rounds: rounds before giving up.

    Returns:
      :class:`Found` with ``overflow`` False.

    Raises:
      RuntimeError: still overflowing after ``max_rounds`` rounds.

    Examples:
      >>> import numpy as np
      >>> from hgjax.neighbours import cells
      >>> p = np.random.default_rng(0).random((300, 3))
      >>> found = cells.grown(cells.within, p, 0.2, columns=8)
      >>> bool(found.overflow), found.idx.shape[1] >= int(found.columns_needed)
      (False, True)
    """
    first = "k" if query is traced_knn else "radius"
    if args:
        kwargs[first] = args[0]
    static = {name: kwargs.pop(name) for name in ("k", "columns", "dedupe", "metric", "max_count", "chunk", "spill",
                                                  "frame", "slots")
              if name in kwargs}
    found = None
    for _ in range(max_rounds):
        found = _jitted(query, tuple(sorted(static.items())))(points, edge=edge, **kwargs)
        if not bool(found.overflow):
            return found
        if "columns" in static and int(found.columns_needed) > static["columns"]:
            static["columns"] = spatial.bucket(int(found.columns_needed))
        edge = found.edge
        if bool(found.uncovered):
            need = float(found.edge_needed)
            edge = need if math.isfinite(need) else 4 * float(found.edge)
    raise RuntimeError(f"the traced search still overflows after {max_rounds} rounds (edge {float(found.edge)!r})")


@functools.lru_cache(maxsize=None)
def _jitted(query, static: tuple):
    """``query`` jitted with its static arguments bound: one compiled program per (static, shape)."""
    return jax.jit(functools.partial(query, **dict(static)))
