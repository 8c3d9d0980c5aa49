"""GFR's radius graph on the host (Chen et al., IEEE TSP 66(3), 2018): the neighbourhood layer's graph query.

Which pairs of points the graph of :mod:`hgjax.scores.gfr` links, built from the tree queries
of a :class:`hgjax.neighbours.spatial.SpatialIndex` (every query of the library goes through it); the
weights and the high-pass on the graph are the method's own (:mod:`hgjax.scores.gfr`, whose
docstring states both graphs' rules: the authors' ``"reference"`` rules on float32 squared
distances, and the scale-invariant default).

The traced search builds the same graph in JAX: :mod:`hgjax.neighbours.traced_graph`.
"""

from __future__ import annotations

import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbours import backend, cells, spatial

__all__ = ["BALL_MARGIN", "MAX_NN", "RADIUS_FACTOR", "graph", "graph_params", "index_location_rows", "location_rows",
           "reference_ball", "squared_radius", "traced_columns"]

MAX_NN = 100
RADIUS_FACTOR = 10.0
SKIP_SQ_DIST = 1e-10  # reference: points with a neighbour this close (squared) do not set minNN
PAIR_BUDGET = 1 << 22  # candidate pairs examined per chunk of rows (bounds the host memory)
SURE_GAP = 1e-9  # beyond this relative gap to 0 and r the tree's distance^2 (within ulps of q) decides 0 < q < r
BALL_MARGIN = 2.0 ** -18  # the reference ball's squared radius over r: beyond float32 q's rounding (< 2^-21)


def columns(p: np.ndarray, pad: bool = False) -> tuple:
    """The x, y and z columns of ``p`` (N, 3) in its dtype, each contiguous (N,), or (N + 1,) with
    NaN at N (no point) if ``pad``."""
    nan = np.full(1, np.nan, p.dtype)
    return tuple(np.append(p[:, axis], nan) if pad else np.ascontiguousarray(p[:, axis]) for axis in range(3))


def sq_dist(coords: tuple, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Squared distances ||p_i - p_j||^2 in the dtype of the :func:`columns` ``coords``, summed x, y, z
    in order, in the shape of ``j`` (``i`` broadcast to it); NaN where a padded column's N is read."""
    q = None
    for x in coords:  # one column at a time: a gather of (P,) values, not of (P, 3) rows
        d = np.take(x, j)
        d -= np.take(x, i)
        d *= d
        q = d if q is None else np.add(q, d, out=q)
    return q


def squared_radius(radius_factor: float, stats: spatial.SampleStats) -> float:
    """The invariant graph's squared radius (radius_factor x resolution)^2.

    The resolution is the median distance to the nearest distinct point over the seeded
    sample of :func:`hgjax.neighbours.spatial.sample_ids` (all points up to 1000): exact duplicates
    and far outliers do not move it, and a tiled run resolves the same value.
    """
    return (radius_factor * stats.resolution(robust=True)) ** 2


def _reference_radius(p32: np.ndarray, index: spatial.SpatialIndex) -> float:
    """The squared radius r = min(10 minNN, 2 maxNN) of REFERENCE.md's rule 1 (0 if no point counts).

    ``p32`` (N, 3) float32 in the caller's order, ``index`` built on it.
    """
    n = p32.shape[0]
    k = min(3, n)
    hits = index.nearest(slice(None), k)[1]
    rows = np.repeat(np.arange(n), k)
    q = sq_dist(columns(p32[index.order]), rows, hits.ravel()).reshape(n, k)
    nearest = np.where(hits != np.arange(n)[:, None], q, np.inf).min(axis=1)
    nearest = nearest[np.isfinite(nearest) & (nearest > SKIP_SQ_DIST)].astype(np.float64)
    if nearest.size == 0:
        return 0.0
    min_nn, max_nn = np.sqrt(nearest.min()), np.sqrt(nearest.max())
    if min_nn == max_nn:
        max_nn = 5 * min_nn
    return float(min(10 * min_nn, 2 * max_nn))


def traced_columns(points, nb) -> int:
    """The columns a traced build of ``points`` reads where its host rows ``nb`` hold fewer: the reference
    variant's ball (:func:`reference_ball`); 1 for the others (their rows are what the traced search reads)."""
    return reference_ball(points) if dict(nb.params).get("variant") == "reference" else 1


def reference_ball(points) -> int:
    """The fullest ball of the reference graph's traced search (:func:`hgjax.neighbours.traced_graph.build`): the points within the
    reference radius of each point, itself included, counted by the host's k-d tree (the columns
    that search needs, counted before it runs; a hair wider than its ball: never too few).

    Args:
      points: (N, 3) float32 or float64, already validated.

    Returns:
      The largest count, at least 1.
    """
    p32 = spatial.local_frame(np.asarray(points))[0].astype(np.float32)
    index = spatial.SpatialIndex(p32.astype(np.float64))
    r = _reference_radius(p32, index)
    if r <= 0:
        return 1
    idx, _ = index.cube(np.sqrt(r * (1 + 2 * BALL_MARGIN)) * (1 + SURE_GAP), norm=2)
    return max(1, int((idx < index.n).sum(axis=1).max()))


def _pairs(p: np.ndarray, index: spatial.SpatialIndex, r: float, max_nn: int):
    """Stored pairs (row, col), row < col, sorted, of the reference radius graph (squared radius r).

    Each row i ranks its candidates j > i (0 < q_ij < r, q in the dtype of ``p``) by
    (q_ij, j) and keeps the first ``max_nn``. ``index`` is built on ``p`` (global ids i, j).
    A bounded k-nearest query per row (k = 2 max_nn + 9 first: about half of a row's hits have
    j > i) decides the row when it holds the whole ball, or when its ``max_nn``-th candidate
    lies closer than every point beyond the query (by more than q's rounding); the other rows
    ask again with twice the columns. A dense ball (the authors' radius can hold thousands of
    points) is enumerated whole only for the rows with fewer than ``max_nn`` candidates j > i.
    """
    n, m = p.shape[0], index.n
    bound = np.sqrt(r) * (1 + 1e-5)  # q is rounded (float32 for the reference); exact test below
    coords = columns(p, pad=True)  # row n: no point
    gid = np.minimum(index.gid, n)  # global ids; the tree's "no hit" m -> n
    first_k = min(2 * max_nn + 9, m)
    rows, cols = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for batch in np.array_split(np.arange(m), max(1, m * first_k // PAIR_BUDGET)):
        queue = [(np.arange(batch.size), first_k)]
        while queue:
            todo, k = queue.pop()
            dist, j = index.nearest(batch[todo], k, bound)
            dist, g = dist.reshape(todo.size, k), gid[j.reshape(todo.size, k)]
            own = gid[batch[todo]]
            q = sq_dist(coords, own[:, None], g)  # NaN where no hit
            q = np.where((g > own[:, None]) & (q > 0) & (q < r), q, np.inf)
            done = (g[:, -1] == n) | (k >= m)  # the query holds every point within the bound
            capped = np.flatnonzero(~done & (np.isfinite(q).sum(axis=1) >= max_nn))
            if capped.size:  # decided when no point beyond the query can rank before the cut
                cut = np.partition(q[capped], max_nn - 1, axis=1)[:, max_nn - 1]
                done[capped] = cut < (dist[capped, -1] * (1 - 1e-5)) ** 2
            q, g, own = q[done], g[done], own[done]
            order = np.lexsort((g, q), axis=1)[:, :max_nn]
            q, g = np.take_along_axis(q, order, axis=1), np.take_along_axis(g, order, axis=1)
            keep = np.isfinite(q)
            rows.append(np.repeat(own, keep.sum(axis=1)))
            cols.append(g[keep])
            if not done.all():
                queue.append((todo[~done], min(2 * k, m)))
    return split_keys(np.concatenate(rows) * n + np.concatenate(cols), n)


def split_keys(key: np.ndarray, n: int):
    """Sorted distinct pairs (key // n, key % n) of int64 pair keys (a sort: faster than np.unique's hash)."""
    key = np.sort(key)
    key = key[np.concatenate([[True], key[1:] != key[:-1]])] if key.size else key
    return key // n, key % n


def location_rows(index: spatial.SpatialIndex, r: float, max_nn: int, want: np.ndarray):
    """The stored partners of the rows ``want`` of a deduplicated index, a chunk of rows at a time.

    Each location a keeps its ``max_nn`` nearest other locations b with 0 < q_ab < r
    (squared distances in float64), ranked by (q_ab, gid_b) (``index.gid``); the pair {a, b}
    is stored when either end keeps the other. Every location that can keep a wanted one (those
    in the wanted rows' bounding box grown by sqrt(r)) asks one bounded k-nearest query
    (:func:`_kept`), which yields what it keeps; a wanted row's partners are what it keeps and
    the rows that keep it, found by reading the kept lists the other way (only a capped row can
    leave out a row that keeps it). No row asks for its whole ball: on a dense scan, balls hold
    several times ``max_nn`` points.

    Args:
      index: a deduplicated :class:`hgjax.neighbours.spatial.SpatialIndex`.
      r: squared radius.
      max_nn: the most partners a location ranks.
      want: (n,) bool, the rows whose partners are returned.

    Yields:
      (own, sym): own (C,) wanted rows, ascending, sym (C, W) int32 their partners (what the
      row keeps in the order of its query, then the rows that keep it by row), padded with n,
      W a power of two or 1.5 times one, chosen per group of rows (:func:`by_width`); the
      chunks' own together are ``flatnonzero(want)``, each in one chunk.
    """
    m = index.n
    if r <= 0 or not want.any():  # no pair: every wanted row alone (if any)
        yield np.flatnonzero(want), np.full((int(want.sum()), 1), m, dtype=np.int32)
        return
    cut_q, cut_g = np.full(m, np.inf), np.zeros(m, np.int64)
    coords = columns(index.points, pad=True)  # row n: no point
    bound = np.sqrt(r) * (1 + 1e-5)  # a tree distance beyond every q < r (the exact test: _in_ball)
    near = np.flatnonzero(_near_box(index.points, want, bound))
    batches = np.array_split(near, max(1, near.size * min(max_nn + 9, m) // PAIR_BUDGET))
    kept = [_kept(index, coords, batch, r, bound, max_nn, cut_q, cut_g) for batch in batches]
    ask = want & np.isfinite(cut_q)  # the wanted rows that are capped
    back = [_kept_back(coords, index.gid, *part, ask, cut_q, cut_g) for part in kept]
    back_row, back_col = (np.concatenate(x) for x in zip(*back))
    by_row = np.argsort(back_row, kind="stable")
    back_row, back_col = back_row[by_row], back_col[by_row]
    for at, batch in enumerate(batches):
        own, counts, cols = kept[at]
        kept[at] = None
        lo, hi = np.searchsorted(back_row, [batch[0], batch[-1] + 1]) if batch.size else (0, 0)
        if hi > lo or not want[own].all() or (own[1:] < own[:-1]).any():
            own, counts, cols = _merged(batch, want, own, counts, cols, back_row[lo:hi], back_col[lo:hi])
        yield from by_width(own, counts, cols, m)


def index_location_rows(index: spatial.SpatialIndex, r: float, max_nn: int, want: np.ndarray):
    """:func:`location_rows` by the traced search: the same partners of the rows ``want`` (in another
    order within a row, which no sum over a row reads), a tiled run's build.

    What every location keeps is one capped k-nearest search over the whole index
    (:func:`hgjax.neighbours.backend.index_search` of :func:`hgjax.neighbours.cells.traced_knn` with
    ``metric="l2sq"`` and ``radius`` r: the host's q and (q, gid) order bit for bit); a wanted row's
    partners are what it keeps and the rows that keep it.

    Yields:
      (own, sym) as :func:`location_rows`: each row's partners ascending.
    """
    m = index.n
    kept = backend.index_search(index, cells.traced_knn, min(max_nn + 1, m), radius=r, metric="l2sq").idx[:, 1:]
    a = np.broadcast_to(np.arange(m)[:, None], kept.shape)[kept < m]
    b = kept[kept < m].astype(np.int64)
    rows, cols = np.concatenate([a, b]), np.concatenate([b, a])
    mine = want[rows]
    rows, cols = split_keys(rows[mine] * m + cols[mine], m)
    own = np.flatnonzero(want)
    yield from by_width(own, np.bincount(rows, minlength=m)[own], cols.astype(np.int32), m)


def _merged(batch: np.ndarray, want: np.ndarray, own: np.ndarray, counts: np.ndarray, cols: np.ndarray,
            back_row: np.ndarray, back_col: np.ndarray):
    """The wanted rows of ``batch`` with each one's partners: what it keeps, then the rows that keep it.

    Args:
      batch: (B,) ascending rows; want: (n,) bool.
      own, counts, cols: :func:`_kept`'s rows (every row of ``batch``, in any order), their counts and
        kept partners.
      back_row, back_col: (E,) the pairs of :func:`_kept_back` whose row is in ``batch``, ascending rows.

    Returns:
      (own (R,) ascending, counts (R,), cols (P,) int32), each row's partners moved to their place
      in one scatter.
    """
    pos, back_pos = np.searchsorted(batch, own), np.searchsorted(batch, back_row)
    n_back = np.bincount(back_pos, minlength=batch.size)
    total = n_back.copy()
    total[pos] += counts
    keep = want[batch]
    total[~keep] = 0
    start = np.cumsum(total) - total
    to = np.repeat(start[pos] - (np.cumsum(counts) - counts), counts) + np.arange(cols.size)
    back_to = (start + total - n_back)[back_pos] + np.arange(back_row.size) - (np.cumsum(n_back) - n_back)[back_pos]
    if not keep.all():
        mine, back_mine = np.repeat(keep[pos], counts), keep[back_pos]
        to, cols, back_to, back_col = to[mine], cols[mine], back_to[back_mine], back_col[back_mine]
    out = np.empty(int(total.sum()), np.int32)
    out[to], out[back_to] = cols, back_col
    return batch[keep], total[keep], out


def _kept(index: spatial.SpatialIndex, coords: tuple, batch: np.ndarray, r: float, bound: float, max_nn: int,
          cut_q: np.ndarray, cut_g: np.ndarray):
    """What the rows ``batch`` keep, and the cuts of the capped ones (written into ``cut_q``, ``cut_g``).

    A bounded k-nearest query per row (k = max_nn + 9), asked again for the rows whose
    query came back full while more may lie within r (:func:`_grown` columns), until the row's
    whole ball is seen or, for a capped row, its cut (the (q, gid) of its ``max_nn``-th
    partner) is certain: no tie with it beyond the query.

    Args:
      coords: the index's x, y and z (n + 1,) each, NaN at n.
      bound: the tree distance the queries are bounded by, a hair above sqrt(r).

    Returns:
      (own (C,), counts (C,), cols (P,) int32): the rows of ``batch`` in the order they were
      decided, and each one's kept partners in the order of its query.
    """
    m, gid = index.n, index.gid
    own, counts, cols = [], [], []
    queue = [(np.arange(batch.size), min(max_nn + 9, m))]
    while queue:
        todo, k = queue.pop()
        rows = batch[todo]
        dist, j, valid, n_valid, seen = _bounded_query(index, coords, rows, k, bound, r)
        done = seen.copy()
        capped = np.flatnonzero(n_valid >= max_nn)
        if capped.size:
            cq, cg, keep, reach = _cut(coords, gid, rows[capped], dist[capped], j[capped], valid[capped], max_nn)
            # the cut is certain unless a tie with it may lie beyond a full query
            sure = seen[capped] | (dist[capped, -1] > reach)
            at = capped[sure]
            cut_q[rows[at]], cut_g[rows[at]] = cq[sure], cg[sure]
            done[at] = True
            valid[at] = keep[sure]
            n_valid[at] = max_nn
        own.append(rows[done])
        counts.append(n_valid[done])
        cols.append(j[valid if done.all() else valid & done[:, None]].astype(np.int32))
        queue += _grown(todo[~done], k, bound, dist[~done, -1], m)
    return np.concatenate(own), np.concatenate(counts), np.concatenate(cols)


def _kept_back(coords: tuple, gid: np.ndarray, own: np.ndarray, counts: np.ndarray, cols: np.ndarray,
               ask: np.ndarray, cut_q: np.ndarray, cut_g: np.ndarray):
    """(b (E,), a (E,)): the pairs where row a keeps row b, b is one of the rows ``ask`` (n,) bool
    (wanted and capped) and b does not keep a (a ranks after b's cut).

    A pair a keeps has q_ab <= cut_a, and b leaves a out only when q_ab >= cut_b: only the pairs
    with cut_b <= cut_a (inf for an uncapped a) are measured.
    """
    if not ask.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    asked = np.take(ask, cols)
    if 4 * np.count_nonzero(asked) > cols.size:  # most pairs (a dense scan): every pair's row repeated
        line = np.repeat(np.arange(own.size, dtype=np.int32), counts)
        pick = np.flatnonzero(asked & (np.take(cut_q, cols) <= cut_q[own][line]))
        line = line[pick]
    else:  # few: their rows by a binary search
        pick = np.flatnonzero(asked)
        line = np.searchsorted(np.cumsum(counts), pick, side="right")
        close = np.take(cut_q, cols[pick]) <= cut_q[own[line]]
        pick, line = pick[close], line[close]
    a, b = own[line], cols[pick].astype(np.int64)
    one = ~_ranks_before(sq_dist(coords, a, b), gid[a], cut_q[b], cut_g[b])
    return b[one], a[one]


def _near_box(u: np.ndarray, want: np.ndarray, reach: float) -> np.ndarray:
    """(n,) bool: the points of ``u`` (n, 3) in the bounding box of the ``want`` rows grown by ``reach``
    (every point within ``reach`` of a wanted one; all points when every row is wanted)."""
    if want.all():
        return want
    w = u[want]
    return ((u >= w.min(axis=0, initial=np.inf) - reach) & (u <= w.max(axis=0, initial=-np.inf) + reach)).all(axis=1)


def by_width(own: np.ndarray, counts: np.ndarray, flat: np.ndarray, n: int):
    """The rows ``own`` (R,) holding ``counts`` (R,) values each of ``flat``, in order, grouped by kernel width.

    Yields:
      (own_w (R_w,), (R_w, w) their values padded with n) for each width w of
      :func:`hgjax._stream.narrow_widths` (half steps): rows as narrow as their contents.
    """
    width = _stream.narrow_widths(counts, half_steps=True)
    starts = np.cumsum(counts) - counts
    for w in np.unique(width):
        rows = np.flatnonzero(width == w)
        c = counts[rows]
        take = flat if rows.size == own.size else flat[np.repeat(starts[rows] - (np.cumsum(c) - c), c)
                                                       + np.arange(c.sum())]
        yield own[rows], dense(c, take, n, int(w))


def _ranks_before(q, g, cut_q, cut_g):
    """Whether the pairs (q, g) rank at or before the cuts (cut_q, cut_g): by q, then by global id."""
    return (q < cut_q) | ((q == cut_q) & (g <= cut_g))


def dense(counts: np.ndarray, flat: np.ndarray, n: int, width: int) -> np.ndarray:
    """(R, width) rows of ``flat`` (R rows of ``counts`` <= width values, in order), padded with n."""
    out = np.full((counts.size, width), n, dtype=np.int32)
    out[np.arange(width) < counts[:, None]] = flat  # row-major: each row's first counts values, in order
    return out


def _in_ball(coords: tuple, rows: np.ndarray, dist: np.ndarray, j: np.ndarray, r: float):
    """(valid (R, k) bool, n_valid (R,)): which of a bounded k-nearest query's hits have 0 < q < r.

    q = ||u_row - u_j||^2 exactly in float64 (``coords``: the index's :func:`columns`). The tree's distances ``dist`` (R, k), ascending
    in each row (inf after the last hit), are within a few ulps of sqrt(q), so they decide
    every hit except the row itself (its first hit, q = 0) and those within SURE_GAP r of
    q = 0 or of q = r, where the exact q does. The hits below sqrt(r (1 + SURE_GAP)) are a
    prefix of each row; the unsure ones lie at its two ends.
    """
    lo, hi = np.sqrt(SURE_GAP * r), np.sqrt(r * (1 - SURE_GAP))
    n_near = np.sum(dist < np.sqrt(r * (1 + SURE_GAP)), axis=1)
    own = (j[:, 0] == rows) & (n_near > 0)  # the row itself first (q = 0; the index holds no duplicate)
    unsure = []
    for low in (True, False):  # walk in from the prefix's start (q near 0) and from its end (q near r)
        at = own.astype(np.int64) if low else n_near - 1
        left = np.flatnonzero(at < n_near)
        while left.size:
            d = dist[left, at[left]]
            left = left[(d <= lo) if low else (d >= hi)]
            unsure.append(left * dist.shape[1] + at[left])
            at[left] += 1 if low else -1
            left = left[(at[left] < n_near[left]) & (at[left] >= 0)]
    unsure = np.unique(np.concatenate(unsure))  # a hit can be near both ends when r is tiny
    valid = np.arange(dist.shape[1]) < n_near[:, None]
    valid[:, 0] &= ~own
    q = sq_dist(coords, rows[unsure // dist.shape[1]], j.ravel()[unsure])
    valid.ravel()[unsure] = (q > 0) & (q < r)
    return valid, n_near - own - np.bincount(unsure[~valid.ravel()[unsure]] // dist.shape[1], minlength=rows.size)


def _bounded_query(index: spatial.SpatialIndex, coords: tuple, rows: np.ndarray, k: int, reach: float, r: float):
    """(dist, j (R, k), valid (R, k), n_valid (R,), seen (R,)): the k nearest points within ``reach``
    of the ``rows``, which of them have 0 < q < r (:func:`_in_ball`), and whether the query holds
    every point within ``reach`` (it came back short of k, or k is every point)."""
    m = index.n
    dist, j = index.nearest(rows, k, reach)
    dist, j = dist.reshape(rows.size, k), j.reshape(rows.size, k)
    valid, n_valid = _in_ball(coords, rows, dist, j, r)
    return dist, j, valid, n_valid, ~((j[:, -1] < m) & (k < m))


def _cut(coords: tuple, gid: np.ndarray, rows: np.ndarray, dist: np.ndarray, j: np.ndarray, valid: np.ndarray,
         max_nn: int) -> tuple:
    """The cuts of capped rows: each row's ``max_nn``-th valid hit in (q, gid) order, and its hits up to it.

    The hits of a bounded query come in ascending tree distance, within a few ulps of sqrt(q),
    so the max_nn-th valid hit in (q, gid) order lies within ulps of the tree distance d of
    the max_nn-th valid column. A hit beyond SURE_GAP (relative) of d lies on its side of the
    cut whatever the rounding: only the hits within that gap (a run of columns, most often
    one) are measured exactly and ranked by (q, gid).

    Args:
      coords: the index's :func:`columns` (padded); gid: (n + 1,) global ids.
      rows: (C,) capped rows; dist, j, valid: (C, k) their hits (:func:`_bounded_query`),
        at least ``max_nn`` valid in each row.

    Returns:
      (cut_q (C,), cut_g (C,), keep (C, k) bool: the ``max_nn`` hits ranked at or before the
      cut, reach (C,): a tree distance beyond which every point ranks after the cut).
    """
    c, k = dist.shape
    line = np.arange(c)
    # the max_nn-th valid column: column max_nn where the row itself comes first and every hit after it is valid
    at = np.full(c, max_nn)
    holes = np.flatnonzero(valid[:, 0] | ~valid[:, 1:max_nn + 1].all(axis=1))
    at[holes] = np.argmax(np.cumsum(valid[holes], axis=1) >= max_nn, axis=1)
    d = dist[line, at]
    reach = d * (1 + SURE_GAP)
    keep = valid & (dist < (d * (1 - SURE_GAP))[:, None])
    near = valid & ~keep & (dist <= reach[:, None])
    first = np.argmax(near, axis=1)
    span = first[:, None] + np.arange(int((k - np.argmax(near[:, ::-1], axis=1) - first).max()))
    cols = np.minimum(span, k - 1)
    inside = np.take_along_axis(near, cols, axis=1) & (span < k)
    hit = np.take_along_axis(j, cols, axis=1)
    q = np.where(inside, sq_dist(coords, rows[:, None], hit), np.inf)
    g = np.where(inside, gid[hit], np.iinfo(np.int64).max)
    at = np.take_along_axis(np.lexsort((g, q), axis=1), (max_nn - 1 - keep.sum(axis=1))[:, None], axis=1)[:, 0]
    cut_q, cut_g = q[line, at], g[line, at]
    won = inside & _ranks_before(q, g, cut_q[:, None], cut_g[:, None])
    keep[np.nonzero(won)[0], cols[won]] = True
    return cut_q, cut_g, keep, reach


def _grown(todo: np.ndarray, k: int, bound: float, last: np.ndarray, m: int) -> list:
    """[(rows, columns)]: the ``todo`` rows whose bounded k-nearest query came back full, grouped
    by the columns to ask next: the points a ball of radius ``bound`` would hold on a surface
    sampled as densely as their first k, k (bound / last)^2 with ``last`` (R,) their k-th
    distance, times 5/4, rounded up to a power of two (at least 2 k, at most ``m``): one more
    query for most rows of a dense ball, however full."""
    if todo.size == 0:
        return []
    grown = np.minimum(np.ceil(1.25 * k * (bound / last) ** 2), m)
    grown = np.minimum(np.maximum(2 * k, 1 << np.frexp(grown - 1)[1].astype(np.int64)), m)
    return [(todo[grown == g], int(g)) for g in np.unique(grown)]


def graph_params(variant: str, radius_factor: float | None, max_nn: int) -> tuple[str, float | None, int]:
    """Validated (variant, radius_factor, max_nn) of :func:`graph` (the invariant factor defaulted).

    Raises:
      TypeError, ValueError: unknown variant, invalid radius_factor or max_nn, or
        radius_factor given with the reference variant.
    """
    variant = _validate.check_variant(variant)
    max_nn = _validate.check_int(max_nn, "max_nn", minimum=1)
    if variant == "reference":
        if radius_factor is not None:
            raise ValueError("radius_factor applies to variant='invariant' only; the reference radius is"
                             " min(10 minNN, 2 maxNN)")
    else:
        radius_factor = RADIUS_FACTOR if radius_factor is None else _validate.check_positive(
            radius_factor, "radius_factor")
    return variant, radius_factor, max_nn


def graph(points, *, variant: str = "invariant", radius_factor: float | None = None,
          max_nn: int = MAX_NN, columns=None) -> tuple[np.ndarray, np.ndarray | None]:
    """The GFR graph W0 as padded neighbour rows (host, SciPy; not jittable).

    Args:
      points: (N, 3) float32 or float64, already validated (e.g. by
        ``hgjax._validate.check_points``).
      variant: ``"invariant"`` (default): Euclidean radius ``radius_factor`` x resolution
        (median distance to the nearest distinct point over a seeded sample, see
        :func:`squared_radius`), a pair stored when either end
        ranks the other among its ``max_nn`` nearest distinct locations. ``"reference"``: the authors' rules,
        squared radius min(10 minNN, 2 maxNN) on float32 squared distances, a pair stored
        in its smaller index's row among that row's ``max_nn`` nearest partners of higher
        index (module docstring).
      radius_factor: the invariant radius in resolutions (default ``RADIUS_FACTOR`` = 10,
        chosen on the edge benchmark, bench/results/archive/gfr_radius.md). Only for ``"invariant"``.
      max_nn: the most partners a point ranks (reference: 100).
      columns: ``columns(width) -> K``, the columns of ``idx`` for the largest row count
        ``width`` (at least ``width``; it may raise), so that the rows are written once at
        the width the caller keeps; default ``max(1, width)``.

    Returns:
      idx: (N, K) int32, caller's order. Row i lists the partners j > i of its stored
      pairs (i, j), ascending, padded with the sentinel N. Invariant graph: only the first
      point of each location has pairs.
      first: (N,) int32 index of the first point at each point's location (invariant graph
      of a cloud with exact duplicates), else None.

    Raises:
      TypeError, ValueError: unknown variant, invalid radius_factor or max_nn, or
        radius_factor given with the reference variant.

    Examples:
      >>> import numpy as np
      >>> from hgjax.neighbours.radius_graph import graph
      >>> pts = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [10, 0, 0]])
      >>> idx, first = graph(pts, radius_factor=2.5)  # resolution 1 (median of 1, 1, 1, 8): radius 2.5
      >>> idx.tolist(), first
      ([[1, 2], [2, 4], [4, 4], [4, 4]], None)
    """
    variant, radius_factor, max_nn = graph_params(variant, radius_factor, max_nn)
    columns = columns or (lambda width: max(1, width))
    pts = np.asarray(points)
    n = pts.shape[0]
    if variant == "reference":
        p = pts.astype(np.float32)
        index = spatial.SpatialIndex(p.astype(np.float64))
        r = _reference_radius(p, index)
        rows, cols = _pairs(p, index, r, max_nn) if r > 0 else (np.zeros(0, np.int64),) * 2
        counts = np.bincount(rows, minlength=n)
        idx = np.full((n, columns(int(counts.max(initial=0)))), n, dtype=np.int32)
        idx[rows, np.arange(rows.size) - (np.cumsum(counts) - counts)[rows]] = cols
        return idx, None
    index = spatial.SpatialIndex(pts.astype(np.float64), dedupe=True)
    r = squared_radius(radius_factor, spatial.sample_stats(index))
    caller = np.append(index.order, n).astype(np.int32)  # the first point of each location; padding n
    parts = []
    for own, sym in location_rows(index, r, max_nn, np.ones(index.n, bool)):
        # every pair is in both ends' rows: the row of its lower caller index lists it, ascending
        i, j = caller[own], caller[sym]
        j = np.sort(np.where(j > i[:, None], j, n), axis=1)
        parts.append((i, j[:, :int((j < n).sum(axis=1).max(initial=0))]))
    idx = np.full((n, columns(max([0, *(j.shape[1] for _, j in parts)]))), n, dtype=np.int32)
    for i, j in parts:
        idx[i, :j.shape[1]] = j
    return idx, (index.order[index.row].astype(np.int32) if index.n < n else None)
