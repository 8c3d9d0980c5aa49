"""GFR's radius graph by the traced search (``search="jax"``): :func:`hgjax.neighbours.radius_graph.graph` in pure JAX.

The same :class:`hgjax.Neighbourhoods` as :func:`hgjax.scores.gfr.neighbourhoods` builds on the
host (``idx``, ``first``, ``points``), built on :mod:`hgjax.neighbours.cells`: under ``jax.jit``
(static N, ``max_nn`` and columns), ``jax.vmap`` and inside ``jax.grad`` (the
graph is discrete: no gradient flows through its choice). Both graphs of
:mod:`hgjax.scores.gfr`:

* ``"invariant"``: the squared radius (``radius_factor`` x resolution)^2, the resolution the
  median nearest-distinct distance over the seeded sample :func:`hgjax.neighbours.spatial.sample_ids`
  (static ids: N is static), computed traced; each location keeps its ``max_nn`` nearest other
  locations with 0 < q < r by (q, global id) (:func:`hgjax.neighbours.cells.traced_knn` with ``dedupe``,
  ``metric="l2sq"`` and ``radius``); a pair is stored between the first points of its two
  locations, in the row of the smaller index, when either end keeps the other (one sort of
  the kept pairs, then a scatter into static columns).
* ``"reference"``: the authors' rules on the float32 local frame: r = min(10 minNN, 2 maxNN)
  from every point's float32 squared distance to its nearest other point (a 3-nearest
  search), then each row's ``max_nn`` partners j > i with 0 < q < r (float32 q, compared in
  float32 as the host compares them), ranked by (q, j), from the ball of each point
  (:func:`hgjax.neighbours.cells.within`, a hair wider than sqrt(r)).

Exact (:mod:`hgjax._exact`): under x64 every value is the host's float64 value (the search's
keys are the host's, the radius the host's operations in the host's order). Without x64
(float32 input) the search's keys are float32 pairs (about 46 bits) and the radius is carried
as a pair: a pair or a radius that the host tells apart from another by less than about 2^-44
relative may compare otherwise. That includes a pair whose length equals the radius in exact
arithmetic, where the host's float64 rounding of q and r decides (measured: ten equal steps on
a line, the invariant radius being ten resolutions; no such pair on the smooth or rounded test
clouds, nor on the GPU at 2e4 points): use x64 for the host's bits on lattices. float64 input
without x64 is searched in float32 (JAX casts it on entry), so its graph may differ from the
host's float64 one.

Widths: the kept lists are (N, max_nn + 1), the reference balls (N, columns), the output (N,
columns): memory is bounded by these, never (N, N); the searches read their cells in fixed-size
steps, so no cell holds too many points. Eagerly (:func:`build` on concrete points) the columns
are the host's (the fullest row rounded up to a power of two); under ``jit`` a row (or a
reference ball) wider than the static columns stops the program, naming the ``capacity`` it
needs (:func:`hgjax.neighbours.backend.guard`), never a truncated graph.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from hgjax import _exact, _stream, _validate
from hgjax.neighbours import backend, cells, radius_graph, spatial

__all__ = ["build"]


MAX_ROUNDS = 12  # eager rounds of growth before giving up
JIT_ROW_SHARE = 2  # a row's columns under jit, in max_nn (the rows of a 600-point lattice hold up to 1.5 max_nn)
RADIUS_MARGIN = 2.0 ** -20  # float32 pairs: the search's radius over r's leading part (then the exact pair test)
ROW_BLOCK = 4096  # rows per block of the graph's own per-row work (exact keys, the reference's ranking)
SKIP_SQ = np.float32(radius_graph.SKIP_SQ_DIST)  # the host compares float32 q with it in float32 (NumPy 2)



def build(points, *, variant: str, radius_factor, max_nn: int, capacity: int | None, cell_slots: int | None,
          cell_edge) -> spatial.Neighbourhoods:
    """GFR's neighbourhoods (:func:`hgjax.scores.gfr.neighbourhoods`) by the traced search.

    Args:
      points: (N, 3) float32 or float64; a tracer under ``jit``.
      variant, radius_factor, max_nn: as :func:`hgjax.neighbours.radius_graph.graph` (validated here).
      capacity: columns of ``idx`` (static; the reference variant's ball columns too). Eagerly
        as the host: None sizes them to the fullest row (rounded up to a power of two), counted
        before the rows are written (and the reference ball's by the host's k-d tree,
        :func:`reference_ball`), so each size compiles once; a fixed one too small raises. Under
        ``jit`` default ``bucket(2 max_nn)`` (a row lists what it keeps and what keeps it:
        lattices and tied clouds pass ``max_nn``); a wider row raises, naming the capacity it needs
        (:func:`hgjax.capacity` counts it for a cloud).
      cell_slots: candidates the searches read per step (static; default
        :data:`hgjax.neighbours.backend.CELL_SLOTS`): speed only.
      cell_edge: the first edge of the graph's search (traced), or None for one from the data:
        speed only.

    Returns:
      :class:`hgjax.Neighbourhoods` with the host's ``idx`` and ``first`` (eagerly: None
      where no two points coincide, as the host; under ``jit`` an (N,) array for the
      invariant graph, the identity without duplicates, which scores alike) and ``params``
      recording ``search="jax"`` (the columns are ``idx.shape[-1]``, not a parameter: two
      eager builds stack, :func:`hgjax.stack_neighbourhoods`).

    Raises:
      TypeError, ValueError: invalid arguments; a fixed capacity too small (eagerly, or under
        ``jit`` when the compiled program runs).

    Examples:
      >>> import numpy as np, hgjax
      >>> p = np.random.default_rng(0).random((300, 3)).astype(np.float32)
      >>> nb = hgjax.neighbourhoods(p, "gfr", search="jax")
      >>> bool((np.asarray(nb.idx) == hgjax.neighbourhoods(p, "gfr").idx).all()), dict(nb.params)["search"]
      (True, 'jax')
    """
    variant, factor, max_nn = radius_graph.graph_params(variant, radius_factor, max_nn)
    traced = _stream.is_traced(points)
    pts = backend.checked_points(points)
    slots = backend.CELL_SLOTS if cell_slots is None else _validate.check_int(cell_slots, "cell_slots", minimum=1)
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    params = {"variant": variant, "radius_factor": radius_factor, "max_nn": max_nn, "search": "jax"}
    n = pts.shape[0]
    statics = dict(variant=variant, factor=factor, max_nn=max_nn, slots=slots)
    ball = spatial.bucket(max_nn) if cap is None else cap  # the reference's ball columns
    if traced:
        columns = spatial.bucket(JIT_ROW_SHARE * max_nn) if cap is None else cap
        lists, report = _search(jnp.asarray(pts), None, cell_edge, ball=ball, **statics)
        idx, first, width = _assemble(lists, variant=variant, columns=columns)
        wide = jnp.maximum(jnp.where(report["ball"] > ball, report["ball"], 0), jnp.where(width > columns, width, 0))
        overflow = backend.guard(jnp.where(report["uncovered"], -1, wide).astype(jnp.int32))
        local, lo = backend.traced_frame(pts)
        return spatial.Neighbourhoods(local, idx, first=first, params=spatial.record(params), overflow=overflow,
                                      points_lo=lo)
    p = jnp.asarray(pts)
    if variant == "reference":  # the ball's columns counted first: one program
        ball = spatial.bucket(radius_graph.reference_ball(pts))
    edges = [None, cell_edge]
    for _ in range(MAX_ROUNDS):
        lists, report = _jitted_search(ball=ball, **statics)(p, *edges)
        if int(report["ball"]) > ball:  # a reference ball wider than its columns: as many columns as it holds
            ball = spatial.bucket(int(report["ball"]))
            continue
        if not bool(report["uncovered"]):
            break
        for s, name in enumerate(("near", "main")):  # the search whose reach passed its block: a wider edge
            if bool(report[f"uncovered_{name}"]):
                need = float(report[f"edge_needed_{name}"])
                edges[s] = need if np.isfinite(need) else 4 * float(report[f"edge_{name}"])
    else:
        raise RuntimeError(f"the traced graph search still overflows after {MAX_ROUNDS} rounds")
    pairs, width = _jitted_pairs(variant)(lists)  # the fullest row, counted before any columns
    width = int(width)
    _validate.check_capacity(cap, width, "GFR row")
    idx, first = _jitted_rows(variant, spatial.bucket(width) if cap is None else cap)(pairs)
    idx = np.asarray(idx)
    first = None if first is None else np.asarray(first)
    if first is not None and (first == np.arange(n)).all():
        first = None
    host = np.asarray(pts)
    local = spatial.local_frame(host)[0]
    dtype = spatial.working_dtype(host.dtype, extent=spatial.frame_extent(local),
                                  spacing=lambda: spatial.pair_spacing(local, idx, first))
    return spatial.Neighbourhoods(jnp.asarray(local.astype(dtype)), jnp.asarray(idx),
                                  first=None if first is None else jnp.asarray(first, jnp.int32),
                                  params=spatial.record(params), overflow=jnp.zeros((), jnp.int32))


@functools.lru_cache(maxsize=None)
def _jitted_search(**statics):
    return jax.jit(functools.partial(_search, **statics))


@functools.lru_cache(maxsize=None)
def _jitted_pairs(variant: str):
    return jax.jit(functools.partial(_pairs_of, variant=variant))


@functools.lru_cache(maxsize=None)
def _jitted_rows(variant: str, columns: int):
    return jax.jit(functools.partial(_rows, variant=variant, columns=columns))


# ----------------------------------------------------------------------------- the searches


def _search(points, edge_near, edge_main, *, slots: int, ball: int, variant: str, factor, max_nn: int):
    """(lists, report): each row's partners before the symmetrisation, and the searches' report.

    ``edge_near`` is the first edge of the nearest-point search that sets the radius,
    ``edge_main`` the graph search's (None: from the data); ``ball`` the reference's ball
    columns (the report's ``ball`` the widest ball: more overflows).
    """
    if variant == "reference":
        lists, near, main = _reference_lists(points, edge_near, edge_main, slots, ball, max_nn)
        widest = main.columns_needed
    else:
        lists, near, main = _invariant_lists(points, edge_near, edge_main, slots, factor, max_nn)
        widest = jnp.int32(0)
    report = {"ball": widest, "uncovered": near.uncovered | main.uncovered,
              "uncovered_near": near.uncovered, "uncovered_main": main.uncovered,
              "edge_needed_near": near.edge_needed, "edge_needed_main": main.edge_needed,
              "edge_near": near.edge, "edge_main": main.edge}
    return lists, report


def _median(h, l, valid):
    """NumPy's median of the valid values (S,) (the mean of the two middle ones for an even count;
    0.0 if none), ``l`` None for float64 values, else float32 pairs (h, l)."""
    big = jnp.where(valid, h, jnp.inf)
    c = jnp.sum(valid, dtype=jnp.int32)
    m = c // 2
    lo_at, hi_at = jnp.maximum(m - 1, 0), m
    if l is None:
        v = jnp.sort(big)
        mid = jnp.where(c % 2 == 1, v[hi_at], (v[lo_at] + v[jnp.minimum(hi_at, v.shape[0] - 1)]) / 2)
        return jnp.where(c > 0, mid, 0.0), None
    vh, vl = lax.sort((big, jnp.where(valid, l, 0)), num_keys=2)
    top = jnp.minimum(hi_at, vh.shape[0] - 1)
    sh, sl = _exact.pair_add(vh[lo_at], vl[lo_at], vh[top], vl[top])
    odd = c % 2 == 1
    mh, ml = jnp.where(odd, vh[top], sh / 2), jnp.where(odd, vl[top], sl / 2)
    return jnp.where(c > 0, mh, 0), jnp.where(c > 0, ml, 0)


def _gathered_pair_keys(points, rows, cols):
    """float32 pair keys (hi, lo) of the squared distances from ``rows`` (R,) to ``cols`` (R, K) (padding n: 0)."""
    n = points.shape[0]
    q = points[rows][:, None, :]
    c = points[jnp.minimum(cols, n - 1)]
    return cells._pair_keys(q, c, "l2sq")


def _invariant_lists(points, edge_near, edge_main, slots: int, factor: float, max_nn: int):
    """((kept (N, K), first (N,)), near, main): what each location keeps (the row of its first copy:
    itself first, then its kept locations) and each point's ``first`` (its location's first copy),
    and the two searches' :class:`Found`."""
    n = points.shape[0]
    x64 = cells._x64()
    near = cells.traced_knn(points, min(2, n), dedupe=True, slots=slots, edge=edge_near)
    ids = spatial.sample_ids(n)  # static: N is
    if n >= 2:
        j = near.idx[ids, 1]
        valid = j < n
    else:
        j, valid = jnp.zeros(ids.shape, jnp.int32), jnp.zeros(ids.shape, bool)
    if x64:  # the k-d tree's distance of the nearest distinct location: the search's own bits
        res, _ = _median(near.reach[ids] if n >= 2 else jnp.zeros(ids.shape), None, valid)
        t = _exact.mul(jnp.asarray(factor, res.dtype), res)
        r = _exact.mul(t, t)
        radius = r
    else:
        qh, ql = _gathered_pair_keys(points.astype(jnp.float32), jnp.asarray(ids), j[:, None])
        dh, dl = _exact.pair_sqrt(qh[:, 0], ql[:, 0])
        mh, ml = _median(dh, dl, valid)
        th, tl = _exact.pair_mul(*_exact.pair_const(factor), mh, ml)
        rh, rl = _exact.pair_square(th, tl)
        radius = rh * (1 + RADIUS_MARGIN)  # a superset; the exact pair test below
    k = min(max_nn + 1, n)
    main = cells.traced_knn(points, k, dedupe=True, slots=slots, edge=edge_main, radius=radius, metric="l2sq")
    kept = main.idx
    if not x64:
        rows = jnp.arange(n, dtype=jnp.int32)
        kh, kl = _chunked(lambda r, c: _gathered_pair_keys(points.astype(jnp.float32), r, c), rows, kept)
        inside = _exact.pair_less(kh, kl, rh, rl) & (kept < n)
        kept = jnp.concatenate([kept[:, :1], jnp.where(inside[:, 1:], kept[:, 1:], n)], axis=1)  # itself kept
    return (kept, near.idx[:, 0]), near, main  # (a radius of 0, one location: only kept's own row lists itself)


def _chunked(fn, rows, cols):
    """``fn(rows, cols)`` over blocks of :data:`ROW_BLOCK` rows (bounds the (R, K, 3) gathers), the last
    block padded with copies of the last row; ``fn`` maps (B,), (B, K) to arrays (B, ...)."""
    n, block = rows.shape[0], ROW_BLOCK
    if n <= block:
        return fn(rows, cols)
    blocks = -(-n // block)
    pad = blocks * block - n
    r = jnp.concatenate([rows, jnp.broadcast_to(rows[-1:], (pad,))]).reshape(blocks, block)
    c = jnp.concatenate([cols, jnp.broadcast_to(cols[-1:], (pad,) + cols.shape[1:])]).reshape(
        (blocks, block) + cols.shape[1:])
    out = lax.map(lambda rc: fn(*rc), (r, c))
    return jax.tree.map(lambda x: x.reshape((blocks * block,) + x.shape[2:])[:n], out)


def _q32(a, b):
    """The host's float32 squared distances ||b - a||^2 (a (..., 3), b (..., 3)): differences, squares
    and sums each rounded to float32, summed x, y, z in order (:func:`hgjax.neighbours.radius_graph.sq_dist`)."""
    d = b - a
    sq = _exact.mul(d, d)
    return (sq[..., 0] + sq[..., 1]) + sq[..., 2]


def _reference_lists(points, edge_near, edge_main, slots: int, ball_columns: int, max_nn: int):
    """(rows (N, W), near, main): each row's partners j > i of its stored pairs, ascending, padded with N."""
    n = points.shape[0]
    x64 = cells._x64()
    if x64:  # the host's float64 local frame, rounded to float32 (the authors' coordinates)
        p = jnp.asarray(points, jnp.float64)
        lo, hi = p.min(axis=0, keepdims=True), p.max(axis=0, keepdims=True)
        p32 = (p - (lo + hi) / 2).astype(jnp.float32)
    else:
        p32 = backend.traced_frame(points)[0].astype(jnp.float32)
    k = min(3, n)
    near = cells.traced_knn(p32, k, slots=slots, edge=edge_near)
    if k > 1:
        js = near.idx[:, 1:]
        q = _q32(p32[:, None, :], p32[jnp.minimum(js, n - 1)])
        q = jnp.where(js < n, q, jnp.inf).min(axis=1)
    else:
        q = jnp.full((n,), jnp.inf, jnp.float32)
    ok = jnp.isfinite(q) & (q > SKIP_SQ)
    any_ok = jnp.any(ok)
    qmin = jnp.min(jnp.where(ok, q, jnp.inf))
    qmax = jnp.max(jnp.where(ok, q, -jnp.inf))
    if x64:
        mn, mx = jnp.sqrt(qmin.astype(jnp.float64)), jnp.sqrt(qmax.astype(jnp.float64))
        mx = jnp.where(mn == mx, _exact.mul(5.0, mn), mx)
        r = jnp.minimum(_exact.mul(10.0, mn), _exact.mul(2.0, mx))
        r32 = r.astype(jnp.float32)  # the host compares float32 q with r in float32
    else:
        mnh, mnl = _exact.pair_sqrt(qmin, jnp.float32(0))
        mxh, mxl = _exact.pair_sqrt(qmax, jnp.float32(0))
        same = qmin == qmax
        mxh, mxl = jnp.where(same, 5 * mnh, mxh), jnp.where(same, 5 * mnl, mxl)
        ah, al = _exact.pair_mul(jnp.float32(10), jnp.float32(0), mnh, mnl)
        bh, bl = 2 * mxh, 2 * mxl
        first_a = _exact.pair_less(ah, al, bh, bl)
        r32 = jnp.where(first_a, ah, bh)  # a normalised pair's leading part: r rounded to float32
    r32 = jnp.where(any_ok, r32, 0)
    ball = r32.astype(p32.dtype if not x64 else jnp.float64) * (1 + radius_graph.BALL_MARGIN)
    if edge_main is None:  # within's own default, 1.1 sqrt(ball), unless the ball is empty (r = 0: no pair)
        extent = jnp.max(p32.max(axis=0) - p32.min(axis=0)).astype(ball.dtype)
        edge_main = jnp.where(ball > 0, cells.EDGE_MARGIN * jnp.sqrt(ball), jnp.maximum(extent, 1) * 2.0 ** -16)
    main = cells.within(p32, ball, columns=ball_columns, slots=slots, edge=edge_main, metric="l2sq")
    width = min(max_nn, ball_columns)

    def rank(rows, js):
        q = _q32(p32[rows][:, None, :], p32[jnp.minimum(js, n - 1)])
        take = (js < n) & (js > rows[:, None]) & (q > 0) & (q < r32)
        key_q, key_j = lax.sort((jnp.where(take, q, jnp.inf), jnp.where(take, js, n)), dimension=1, num_keys=2)
        return jnp.sort(key_j[:, :width], axis=1)

    lists = _chunked(rank, jnp.arange(n, dtype=jnp.int32), main.idx)
    return lists, near, main


# ----------------------------------------------------------------------------- the rows


def _assemble(lists, *, variant: str, columns: int):
    """(idx (N, columns) int32, first (N,) or None, width): the host's rows from :func:`_search`'s lists;
    ``width`` the fullest row (a row wider than ``columns`` is cut: the caller reports it)."""
    pairs, width = _pairs_of(lists, variant=variant)
    return (*_rows(pairs, variant=variant, columns=columns), width)


def _pairs_of(lists, *, variant: str):
    """(pairs, width): the stored pairs of :func:`_search`'s lists, each with its row and its rank in the
    row, and the fullest row's count: what sizes the columns, computed without them."""
    if variant == "reference":
        n = lists.shape[0]
        return lists, jnp.max(jnp.sum(lists < n, axis=1)).astype(jnp.int32)
    kept, first = lists
    n = kept.shape[0]
    iota = jnp.arange(n, dtype=jnp.int32)
    mine = kept[:, 1:]
    valid = (first == iota)[:, None] & (mine < n)  # only a location's first point keeps
    a = jnp.broadcast_to(iota[:, None], mine.shape)
    lo = jnp.where(valid, jnp.minimum(a, mine), n).ravel()
    hi = jnp.where(valid, jnp.maximum(a, mine), n).ravel()
    lo, hi = lax.sort((lo, hi), num_keys=2)
    new = jnp.concatenate([jnp.ones(1, bool), (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])]) & (lo < n)
    counts = jnp.zeros(n + 1, jnp.int32).at[lo].add(new.astype(jnp.int32))[:n]
    start = jnp.cumsum(counts) - counts
    rank = jnp.cumsum(new.astype(jnp.int32)) - 1 - start[jnp.minimum(lo, n - 1)]
    return (lo, hi, rank, new, first), jnp.max(counts, initial=0)


def _rows(pairs, *, variant: str, columns: int):
    """(idx (N, columns) int32, first (N,) or None): the pairs of :func:`_pairs_of` written into ``columns``
    columns (a row wider than them is cut: the caller reports it)."""
    if variant == "reference":
        n, w = pairs.shape
        idx = pairs[:, :columns] if w >= columns else jnp.pad(pairs, ((0, 0), (0, columns - w)), constant_values=n)
        return idx.astype(jnp.int32), None
    lo, hi, rank, new, first = pairs
    n = first.shape[0]
    put = new & (rank < columns)
    idx = jnp.full((n, columns), n, jnp.int32).at[jnp.where(put, lo, n), jnp.where(put, rank, 0)].set(
        hi.astype(jnp.int32), mode="drop")
    return idx, first.astype(jnp.int32)
