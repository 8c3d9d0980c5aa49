"""Host-side spatial queries with a k-d tree, and the :class:`Neighbourhoods` they fill.

The tree itself (:class:`hgjax.neighbours.kdtree.Tree`: pykdtree where installed, SciPy's cKDTree
otherwise, the same distances) is queried only here. Everything here runs on the
host and is not jittable; the kernels in :mod:`hgjax.scores` consume its padded index arrays
under ``jax.jit``. The container itself (:class:`Neighbourhoods`, :func:`stack_neighbourhoods`,
:func:`record`) lives in :mod:`hgjax.neighbours.container`, re-exported here.

Conventions (shared with every kernel):

* ``idx`` is int32 of shape (N, K); missing neighbours are padded with the sentinel ``N``
  (the k-d tree's own convention), so a mask is ``idx < N``.
* k-nearest neighbourhoods list the point itself first, then its neighbours by increasing
  distance (equal distances by index in the spatially sorted frame, which is deterministic).
* Before querying, points are put in Morton (Z-curve) order, which makes the tree query
  several times faster on large clouds; results are always returned in the caller's order
  and do not depend on the order of the input points.
* Coordinates are moved to a local frame (the float64 centre of the bounding box subtracted)
  before any cast to the working dtype, so georeferenced clouds (UTM offsets of 1e5-1e7)
  keep their precision in float32. Every score is translation-invariant. The frame and the
  rules of that cast (:func:`working_dtype`, :class:`PrecisionWarning`) live in
  :mod:`hgjax.neighbours.precision`, re-exported here; this module measures the spacing they judge
  (:func:`index_spacing`, :func:`pair_spacing`).
* With ``dedupe=True`` exact duplicates are one point for the queries: each copy gets the
  neighbourhood of its first occurrence, whose row lists no other copy. Exact duplicates
  carry no geometry, so a default score is the same with or without them.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import functools
import os

import numpy as np

from hgjax import _validate
from hgjax.neighbours import kdtree
from hgjax.neighbours.container import Neighbourhoods, record, stack_neighbourhoods
from hgjax.neighbours.precision import (  # noqa: F401  (re-exported: the callers' spatial.frame_origin, ...)
    PRECISION_SHARE,
    PrecisionWarning,
    axis_bounds,
    finest_spacing,
    float32_rounding,
    frame_extent,
    frame_origin,
    local_frame,
    split_frame,
    working_dtype,
)

__all__ = [
    "Neighbourhoods",
    "PrecisionWarning",
    "SpatialIndex",
    "intrinsic_resolution",
    "local_frame",
    "split_frame",
    "spatial_order",
    "stack_neighbourhoods",
    "working_dtype",
]

_MORTON_BITS = 21  # 3 * 21 = 63 bits fit in uint64
MORTON_SPLIT = 1 << 16  # points from which spatial_order computes its codes in two threads
RESOLUTION_SAMPLES = 1000
CUBE_GROUPS = 8  # cube queries bound each eighth of a batch (by half-width) separately


def index_spacing(index: "SpatialIndex") -> float:
    """:func:`finest_spacing` of the seeded sample of a whole-cloud index (rows of global ids 0..N-1)."""
    return finest_spacing(nearest_distances(index, index.row[sample_ids(index.n_caller)])[0])


def pair_spacing(local: np.ndarray, idx: np.ndarray, first: np.ndarray | None = None) -> float:
    """:func:`finest_spacing` of the seeded sample from a graph's pairs instead of an index.

    Args:
      local: (N, 3) float64 local coordinates.
      idx: (N, K) neighbour rows padded with N; row i and the rows listing i together hold
        each point's nearest distinct point (GFR's graph).
      first: optional (N,) first point of each point's location (only those have pairs).
    """
    n = local.shape[0]
    wanted = sample_ids(n)
    sampled = np.zeros(n + 1, dtype=bool)
    sampled[wanted if first is None else np.asarray(first)[wanted]] = True
    real = idx < n
    rows, cols = np.nonzero(real & (sampled[:n, None] | sampled[idx]))  # the padding n is not sampled
    gap = local[rows] - local[idx[rows, cols]]
    return finest_spacing(np.sqrt(np.einsum("ij,ij->i", gap, gap)))


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between the low 21 bits of ``v`` (uint64) for Morton codes."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def spatial_order(points: np.ndarray) -> np.ndarray:
    """Permutation that puts ``points`` in Morton (Z-curve) order.

    Ties (points in the same Morton cell) are broken by the coordinates themselves, so the
    sorted cloud is the same whatever the order of the input, up to exact duplicates.

    Args:
      points: (N, 3) float array.

    Returns:
      (N,) int64 permutation ``perm`` such that ``points[perm]`` is spatially ordered.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.spatial_order(np.array([[1.0, 1, 1], [0, 0, 0], [1, 0, 0]])).tolist()
      [1, 2, 0]
    """
    p = np.asarray(points, dtype=np.float64)
    lo, hi = axis_bounds(p)
    extent = float((hi - lo).max())
    scale = (2**_MORTON_BITS - 1) / extent if extent > 0 else 0.0
    code = np.empty(p.shape[0], dtype=np.uint64)

    def codes(part: slice) -> None:
        q = ((p[part] - lo) * scale).astype(np.uint64)
        code[part] = _spread_bits(q[:, 0]) << np.uint64(2) | _spread_bits(q[:, 1]) << np.uint64(1) | _spread_bits(q[:, 2])

    if p.shape[0] < MORTON_SPLIT:
        codes(slice(None))
    else:  # two threads (NumPy releases the GIL): the sort runs before the tree, on otherwise idle cores
        half = p.shape[0] // 2
        with concurrent.futures.ThreadPoolExecutor(1) as other:
            done = other.submit(codes, slice(half, None))
            codes(slice(0, half))
            done.result()
    # Points sharing a Morton cell are rare: only those runs are sorted by their coordinates.
    return lex_order(code, p[:, 0], p[:, 1], p[:, 2])


def lex_order(key: np.ndarray, *then: np.ndarray) -> np.ndarray:
    """The (R,) permutation that sorts by ``key`` (R,), then each of ``then`` (R,), then index.

    Equal to ``np.lexsort((*reversed(then), key))``, but by one vectorised (unstable) sort of
    ``key`` and a lexsort of only the runs of equal keys: far faster when ties are few.
    """
    order = np.argsort(key)
    sorted_key = key[order]
    tied = np.zeros(order.size, dtype=bool)
    tied[1:] = sorted_key[1:] == sorted_key[:-1]
    tied[:-1] |= tied[1:]
    if tied.any():
        sub = np.sort(order[tied])  # index order: the stable lexsort then breaks full ties by index
        order[tied] = sub[np.lexsort(tuple(t[sub] for t in reversed(then)) + (key[sub],))]
    return order


class SpatialIndex:
    """A Morton-sorted copy of a cloud and the k-d tree over it (host only).

    Queries return indices in the sorted frame; :meth:`to_caller` and :meth:`caller_idx` map
    results back to the caller's points. Build it once and reuse it for several queries.

    Args:
      points: (N, 3) float array (validated by the caller).
      dedupe: treat exact duplicates as one point: the index holds each distinct location
        once (``n`` rows), and every copy maps to the row of its location.
    """

    def __init__(self, points: np.ndarray, *, dedupe: bool = False, gid: np.ndarray | None = None):
        self.n_caller = int(points.shape[0])
        order = spatial_order(points)
        sorted_points = np.take(points, order, axis=0)  # (np.take: a fancy index of rows is slower)
        row = np.arange(self.n_caller)
        first = row
        if dedupe and self.n_caller > 1:
            # spatial_order puts exact duplicates next to each other, the lowest index first.
            same = np.zeros(self.n_caller, dtype=bool)
            same[1:] = functools.reduce(np.logical_and, (sorted_points[1:, a] == sorted_points[:-1, a]
                                                         for a in range(3)))
            if same.any():
                row = np.cumsum(~same) - 1
                first = np.flatnonzero(~same)
                sorted_points = np.take(sorted_points, first, axis=0)
        self.n = int(sorted_points.shape[0])
        self.points = sorted_points
        # The tree builds in a background thread (the build releases the GIL) while the maps
        # below and the caller's preparations run; :attr:`tree` waits for it.
        pool = concurrent.futures.ThreadPoolExecutor(1)
        self._tree = pool.submit(kdtree.Tree, sorted_points)
        pool.shutdown(wait=False)
        self.order = order[first]  # sorted row -> caller index of its first copy
        self.row = np.empty(self.n_caller, dtype=np.int64)  # caller index -> sorted row
        self.row[order] = row
        gid = np.arange(self.n_caller, dtype=np.int64) if gid is None else np.asarray(gid, dtype=np.int64)
        # global id of each sorted row (its first copy), and a last entry for the padding n
        self.gid = np.append(gid[self.order], np.iinfo(np.int64).max)
        # above every global id (negative ids: none, and :meth:`_ranked` takes its lexsort)
        self.gid_span = int(gid.max(initial=-1)) + 1 if gid.min(initial=0) >= 0 else 2**62

    @property
    def tree(self) -> kdtree.Tree:
        """The k-d tree over :attr:`points` (waits for its build)."""
        if isinstance(self._tree, concurrent.futures.Future):
            self._tree = self._tree.result()
        return self._tree

    def __getstate__(self) -> dict:
        return dict(self.__dict__, _tree=self.tree)

    def to_caller(self, values: np.ndarray) -> np.ndarray:
        """Per-row ``values`` (n, ...) of the sorted frame as (N, ...) in the caller's order."""
        return values[self.row]

    def caller_idx(self, idx_sorted: np.ndarray) -> np.ndarray:
        """Sorted-frame neighbour rows (n, K), padded with n, as caller-frame rows and indices (N, K), sentinel N."""
        return caller_rows(self, [idx_sorted], idx_sorted.shape[1], [slice(None)])

    def _ranked(self, row_ids: np.ndarray, dist: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each row's hits (R, q) by (distance, global id), the point itself first (distance -1)."""
        dist = np.where(idx == row_ids[:, None], -1.0, dist)
        gid = self.gid[np.minimum(idx, self.n)]  # the padding's is the largest int64
        # The query's rows are sorted by distance: each hit's key is (the rank of its distance in
        # the row, its global id), one integer, sorted once (faster than a two-key lexsort). A row
        # that lists the point itself after another point at distance 0 is not sorted: lexsort.
        span = self.gid_span + 1  # global ids, then the padding
        if dist.shape[1] * span < 2**62:
            key = np.zeros(dist.shape, np.int64)
            np.cumsum(dist[:, 1:] != dist[:, :-1], axis=1, out=key[:, 1:])
            key *= span
            key += np.minimum(gid, self.gid_span)
            order = np.argsort(key, axis=1, kind="stable")
            unsorted = np.flatnonzero((dist[:, 1:] < dist[:, :-1]).any(axis=1))
        else:
            order, unsorted = np.zeros(dist.shape, np.intp), np.arange(dist.shape[0])
        if unsorted.size:
            order[unsorted] = np.lexsort((gid[unsorted], dist[unsorted]), axis=1)
        return np.take_along_axis(dist, order, axis=1), np.take_along_axis(idx, order, axis=1)

    def _unordered(self, dist: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(R,) whether a row of hits (R, q) sorted by distance has equal distances not in global-id order."""
        gid = self.gid[np.minimum(idx, self.n)]
        return ((dist[:, 1:] == dist[:, :-1]) & (gid[:, 1:] < gid[:, :-1])).any(axis=1)

    def neighbours(self, k: int, rows: slice | np.ndarray = slice(None), *,
            query: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The point itself and its k - 1 nearest neighbours by (distance, global id), sorted frame.

        Equal distances are ordered by the neighbours' global ids (``gid``), including at the
        k-th place (rows whose k-th and (k+1)-th distances tie are queried again until the
        whole tie is seen), so the neighbourhood never depends on how the tree was built or
        on which other points share the index.

        Args:
          k: neighbourhood size including the point itself.
          rows: which sorted-frame rows to query (default all).
          query: these rows' :meth:`nearest` result with at least min(k + 1, n) columns, to
            reuse instead of a new tree query (same result).

        Returns:
          (idx, reach): idx (R, k) int32 indices (sorted frame), column 0 the point itself,
          padded with n when the index holds fewer than k points; reach (R,) float64 the
          distance of the k-th point (every point at most this far is in the index's reach),
          inf when the index holds fewer than k points (a tile too small for the neighbourhood).
        """
        row_ids = self.row_ids(rows)
        r = len(row_ids)
        k_eff = min(k, self.n)
        q = min(k_eff + 1, self.n)
        last = k_eff - 1
        dist, idx = self.nearest(row_ids, q) if query is None else (query[0][:, :q], query[1][:, :q])
        # Rows whose order needs fixing: equal distances inside the first k_eff, or at the cut. A
        # row is read as queried where it lists the point itself first (distance 0, ranked -1).
        odd = np.flatnonzero(idx[:, 0] != row_ids)
        tied = (dist[:, 2:k_eff] == dist[:, 1:last]).any(axis=1)
        tied[tied] = self._unordered(dist[tied, 1:k_eff], idx[tied, 1:k_eff])  # ties not yet by global id
        cut = (dist[:, last] == dist[:, k_eff]) if q > k_eff and last else np.zeros(r, bool)
        if odd.size:  # another point at distance 0 listed first, or the point itself beyond the query
            mine = idx[odd] == row_ids[odd, None]
            d = np.sort(np.where(mine, -1.0, dist[odd]), axis=1)  # as ranked: the point itself first
            tied[odd] = True
            cut[odd] = ~mine.any(axis=1) | ((d[:, last] == d[:, k_eff]) if q > k_eff else False)
        out, reach = idx[:, :k_eff].astype(np.int32), np.maximum(dist[:, last], 0.0)
        fix = np.flatnonzero(tied & ~cut)
        if fix.size:
            d, i = self._ranked(row_ids[fix], dist[fix], idx[fix])
            out[fix], reach[fix] = i[:, :k_eff], np.maximum(d[:, last], 0.0)
        todo, width = np.flatnonzero(cut), q
        while todo.size:
            width = min(2 * width, self.n)
            d, i = self.tree.query(self.points[row_ids[todo]], width)
            d, i = self._ranked(row_ids[todo], d.reshape(todo.size, width), i.reshape(todo.size, width))
            done = (d[:, -1] > d[:, last]) | (width == self.n)
            out[todo[done]], reach[todo[done]] = i[done, :k_eff], np.maximum(d[done, last], 0.0)
            todo = todo[~done]
        if k_eff < k:  # the k-th point lies beyond the index, however far: no radius holds the neighbourhood
            out = np.concatenate([out, np.full((r, k - k_eff), self.n, dtype=np.int32)], axis=1)
            reach = np.full(r, np.inf)
        return out, reach

    def nearest(self, rows: slice | np.ndarray, k: int, bound: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """The raw tree query of ``rows``: (R, k) distances and indices (sorted frame), k <= n.

        Sorted by distance, equal distances in the tree's order; :meth:`neighbours` and :meth:`cube`
        turn it into their exact neighbourhoods, so one query can serve both. With ``bound``,
        only points nearer than it: the missing ones at distance inf and index n (GFR's balls).
        """
        row_ids = self.row_ids(rows)
        return self.tree.query(self.points[row_ids], k, bound)

    def cube(self, half_width, rows: slice | np.ndarray = slice(None), *, capacity: int = 32,
             max_count: int | None = None, norm: float = np.inf,
             query: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """All points within the axis-aligned cube of ``half_width`` (Chebyshev distance < h),
        or with ``norm=2`` within the ball of that radius (Euclidean distance < h).

        Rows that fill the query are queried again with twice the columns, until every row
        holds all its points: nothing is ever truncated. With ``max_count``, a row whose cube
        holds more points gets a smaller cube instead: its half-width becomes the Chebyshev
        distance of its ``max_count``-th nearest point, so it holds fewer than
        ``max_count`` points, all of them (the cube shrinks; no point inside is dropped).

        Args:
          half_width: half the cube side, a scalar or one per queried row (R,).
          rows: which sorted-frame rows to query (default all).
          capacity: initial number of columns queried.
          max_count: the most points a cube may hold (shrinking it), or None.
          norm: the Minkowski norm of the distance, ``np.inf`` (cube) or 2 (ball).
          query: with ``norm=2``, these rows' :meth:`nearest` result, used as the first
            round instead of a new query (``capacity`` is then its number of columns).

        Returns:
          (idx, half): idx (R, W) int32 indices (sorted frame) by (distance, global id),
          padded with n, W the fullest row's count; half (R,) the half-widths (radii) used.
        """
        row_ids = self.row_ids(rows)
        queries = self.points[row_ids]
        h = np.array(np.broadcast_to(np.asarray(half_width, dtype=np.float64), (len(row_ids),)))
        out = np.full((len(row_ids), 1), self.n, dtype=np.int32)
        todo = np.arange(len(row_ids))
        k = min(capacity if query is None else query[0].shape[1], self.n)
        while todo.size:
            if max_count is not None:
                k = min(k, max_count)
            if query is None:
                dist, idx = self._cube_query(queries[todo], k, h[todo], norm)
            else:
                dist, idx, query = query[0][:, :k], query[1][:, :k], None
            full = dist[:, -1] < h[todo]
            if k == max_count:  # shrink the full cubes to exclude their max_count-th point
                h[todo[full]] = dist[full, -1]
                full[:] = False
            inside = dist < h[todo, None]  # a prefix of each row: sorted by distance
            done = ~full | (k == self.n)
            count = inside.sum(axis=1)
            width = int(count[done].max(initial=1))
            if width > out.shape[1]:
                out = np.pad(out, ((0, 0), (0, width - out.shape[1])), constant_values=self.n)
            keep = inside[:, :width] & done[:, None]
            if todo.size == len(row_ids):  # every row in this round: write in place, no row selection
                np.copyto(out[:, :width], idx[:, :width], casting="unsafe", where=keep)
            else:
                out[todo[done], :width] = np.where(keep[done], idx[done, :width], self.n)
            # Equal distances inside the cube (first any tie in the row, then kept ties out of
            # global-id order) are ordered by global id, the point itself first.
            tied = (dist[:, 1:width] == dist[:, :width - 1]).any(axis=1)
            tied[tied] = (self._unordered(np.where(keep[tied], dist[tied, :width], np.nan), idx[tied, :width])
                          | (idx[tied, 0] != row_ids[todo[tied]]))  # kept ties not yet by global id, or not itself first
            if tied.any():
                d, i = dist[tied, :width], idx[tied, :width]  # the cube's points are a prefix of the row
                ranked = self._ranked(row_ids[todo[tied]], np.where(inside[tied, :width], d, np.inf), i)[1]
                out[todo[tied], :width] = np.where(keep[tied], ranked, self.n)
            todo, k = todo[~done], min(2 * k, self.n)
        return out, h

    def _cube_query(self, queries: np.ndarray, k: int, h: np.ndarray, norm: float) -> tuple[np.ndarray, np.ndarray]:
        """(R, k) k-nearest distances (Minkowski ``norm``) and indices, each row searched within about its own h.

        The tree takes one distance bound per call; a batch's largest h lets every row of a cloud
        whose density varies (a scan: near and far from the sensor) search far past its own cube.
        Rows are grouped by h (spatial order kept inside a group) and each group is bounded by
        its largest h. Every row still gets all its points closer than its h: the same sets.
        """
        groups = CUBE_GROUPS if h.size >= CUBE_GROUPS * 128 and h.min() < h.max() else 1
        dist, idx = np.empty((h.size, k)), np.empty((h.size, k), dtype=np.intp)
        for g in np.array_split(np.argsort(h, kind="stable"), groups):
            g = np.sort(g)
            dist[g], idx[g] = self.tree.query(queries[g], k, float(h[g].max()), p=norm)
        return dist, idx

    def row_ids(self, rows: slice | np.ndarray) -> np.ndarray:
        """The sorted-frame row numbers that ``rows`` selects, as an int64 array."""
        if isinstance(rows, slice):
            return np.arange(*rows.indices(self.n))
        return np.asarray(rows, dtype=np.int64)


QUERY_ROWS = 1 << 14  # rows per host query batch: bounds the query's temporary memory
QUERIES_AHEAD = 2  # batches queried ahead of the one being consumed (each (QUERY_ROWS, k + 1) twice)


def bucket(width: int) -> int:
    """Columns for a neighbourhood of ``width`` points: the next power of two, at least 8.

    Few distinct widths means few compiled kernels across clouds.
    """
    return max(8, 1 << max(0, int(width) - 1).bit_length())


def batches(n_rows: int):
    """Slices of ``range(n_rows)`` of QUERY_ROWS rows each, in order."""
    return [slice(start, min(start + QUERY_ROWS, n_rows)) for start in range(0, n_rows, QUERY_ROWS)]


def caller_rows(index: SpatialIndex, parts, capacity: int | None = None, where: list | None = None, *,
                what: str = "neighbourhood") -> np.ndarray:
    """(N, K) int32 neighbour rows in the caller's frame from sorted-frame ``parts``.

    Each part (R_i, W_i), padded with n, holds the sorted-frame rows ``where[i]`` (default the
    :func:`batches` of all n rows): its indices become the caller's (the sentinel n becomes N) and
    are written to the caller rows of its points, the rest of those rows N; each exact copy of a
    location (``dedupe``) then takes its first copy's row. One write per element: no sorted-frame
    copy of the whole array. ``parts`` may be a generator: each part is written as it arrives, by
    one thread per core (NumPy's scattered writes release the GIL; parts write disjoint rows, so
    the result is the same bits), while the next part is being found.

    Args:
      index: the index the parts' rows belong to.
      parts: iterable of (R_i, W_i) int sorted-frame rows.
      capacity: the columns K, or None for the :func:`bucket` of the widest part (the array
        is widened when a wider part arrives).
      where: the sorted-frame rows of each part, or None for :func:`batches` of all n rows.
      what: the neighbourhood's name in a capacity error.

    Raises:
      ValueError: when a fixed ``capacity`` is smaller than the widest part (named, once every
        part has been read).
    """
    ext = np.append(index.order, index.n_caller).astype(np.int32)
    out, widest, pending = None, 1, []

    def write(rows, part, p):
        dest = index.order[part]
        rows[dest, :p.shape[1]] = np.take(ext, p)
        rows[dest, p.shape[1]:] = index.n_caller

    with concurrent.futures.ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        for part, p in zip(batches(index.n) if where is None else where, parts):
            widest = max(widest, p.shape[1])
            width = bucket(widest) if capacity is None else capacity
            if widest > width:
                continue  # read on, to name the widest row
            if out is None or out.shape[1] < width:
                for done in pending:
                    done.result()
                pending, out = [], _widened(out, width, index.n_caller)
            pending.append(pool.submit(write, out, part, p))
        for done in pending:
            done.result()
    _validate.check_capacity(capacity, widest, what)
    if index.n < index.n_caller:
        first = index.order[index.row]  # each point's first copy
        copies = np.flatnonzero(first != np.arange(index.n_caller))
        out[copies] = out[first[copies]]
    return out


def _widened(rows: np.ndarray | None, width: int, n: int) -> np.ndarray:
    """A new (n, width) int32 array holding ``rows`` (n, W <= width) in its first columns and ``n`` in the rest."""
    out = np.empty((n, width), dtype=np.int32)
    if rows is not None:
        out[:, :rows.shape[1]] = rows
        out[:, rows.shape[1]:] = n
    return out


def assemble(points: np.ndarray, index: SpatialIndex, idx: np.ndarray, scale_sorted=None, *,
             params: dict | None = None) -> Neighbourhoods:
    """Neighbourhoods in the caller's order from caller rows (:func:`caller_rows`) built on ``index``.

    Args:
      points: (N, 3) the caller's validated points.
      index: the index the query ran on.
      idx: (N, K) int32 caller rows, padded with N.
      scale_sorted: optional (n,) per-row length in the sorted frame.
      params: the build parameters to record (see :attr:`Neighbourhoods.params`).

    Returns:
      :class:`Neighbourhoods` whose points are the caller's in a local frame, cast to the
      working dtype (see :func:`working_dtype`; a cast that loses the cloud's finest spacing,
      read from ``index``, warns).
    """
    local = local_frame(points)[0]
    dtype = working_dtype(points.dtype, extent=frame_extent(local), spacing=lambda: index_spacing(index))
    hi, lo = split_frame(local, dtype)
    scale = None if scale_sorted is None else index.to_caller(np.asarray(scale_sorted)).astype(dtype)
    return Neighbourhoods(hi, idx, scale, params=record(params or {}), points_lo=lo)


def intrinsic_resolution(points, *, robust: bool = False) -> float:
    """Intrinsic resolution: the typical distance from a point to its nearest other point.

    ``robust=False`` is REFERENCE.md's definition: the MEAN distance to the nearest other
    point (an exact duplicate counts, at distance 0). ``robust=True``: the MEDIAN distance to
    the nearest DISTINCT point, so exact duplicates and a few far outliers do not move it.
    Both use all points when there are at most 1000 (distinct) points, else 1000 drawn with a
    fixed seed from the spatially sorted cloud: deterministic and independent of the order.

    Args:
      points: (N, 3) float32 or float64, N >= 2.
      robust: the duplicate- and outlier-robust variant.

    Returns:
      The resolution as a Python float; 0.0 when there is no (distinct) neighbour, e.g.
      when all points are equal.

    Raises:
      TypeError, ValueError: for invalid points, or N < 2.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.intrinsic_resolution(np.array([[0., 0, 0], [1, 0, 0], [3, 0, 0]]))
      1.3333333333333333
      >>> hgjax.intrinsic_resolution(np.array([[0., 0, 0], [0, 0, 0], [1, 0, 0], [9, 0, 0]]), robust=True)
      1.0
    """
    pts = _validate.check_points(points)
    _validate.check_min_points(pts.shape[0], 2, "an intrinsic resolution")
    return resolution(SpatialIndex(local_frame(pts)[0], dedupe=robust), robust=robust)


SAMPLE_K = 8  # locations (the point first) of each sampled point's neighbourhood in SampleStats


def sample_ids(n: int) -> np.ndarray:
    """The global ids whose nearest distances set a cloud's resolution and irregularity.

    All ids when n <= 1000, else 1000 drawn without replacement with seed 0: a documented
    seeded sample that depends on n only, so every tile of a tiled run agrees on it.
    """
    if n <= RESOLUTION_SAMPLES:
        return np.arange(n, dtype=np.int64)
    return np.sort(np.random.default_rng(0).choice(n, RESOLUTION_SAMPLES, replace=False)).astype(np.int64)


def nearest_distances(index: SpatialIndex, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances from sorted ``rows`` (R,) to their nearest distinct point and nearest other point.

    Returns:
      (distinct, other): (R,) float64 each; ``other`` is 0 where the row's location holds
      another point (an exact duplicate); inf where no such point exists.
    """
    rows = np.asarray(rows, dtype=np.int64)
    distinct, other = np.full(rows.size, np.inf), np.full(rows.size, np.inf)
    todo, width = np.arange(rows.size), 1
    while todo.size and width < index.n:
        width = min(2 * width, index.n)
        d = index.tree.query(index.points[rows[todo]], width)[0]
        if width == 2:
            other[todo] = d[:, 1]
        positive = np.isfinite(d) & (d > 0)
        hit = positive.any(axis=1)
        distinct[todo[hit]] = d[hit, positive[hit].argmax(axis=1)]
        todo = todo[~hit]
    if index.n < index.n_caller:  # deduplicated: a location with several points is at distance 0
        other = np.where(np.bincount(index.row, minlength=index.n)[rows] > 1, 0.0, distinct)
    return distinct, other


def sample_offsets(index: SpatialIndex, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``SAMPLE_K`` nearest locations of sorted-frame ``rows`` (R,) minus the row's own (:meth:`SpatialIndex.neighbours`).

    Returns:
      (offsets, valid, reach): offsets (R, SAMPLE_K, 3) float64, row 0 the point itself (0),
      zero where ``valid`` (R, SAMPLE_K) is False (fewer locations in the index); reach (R,)
      as :meth:`SpatialIndex.neighbours`.
    """
    rows = np.asarray(rows, dtype=np.int64)
    idx, reach = index.neighbours(SAMPLE_K, rows)
    idx = np.pad(idx, ((0, 0), (0, SAMPLE_K - idx.shape[1])), constant_values=index.n)
    valid = idx < index.n
    near = np.take(index.points, np.where(valid, idx, 0), axis=0) - np.take(index.points, rows, axis=0)[:, None, :]
    return np.where(valid[..., None], near, 0.0), valid, reach


@dataclasses.dataclass(frozen=True)
class SampleStats:
    """Nearest distances and neighbourhoods of the sampled points (:func:`sample_ids`), in global-id order.

    The only whole-cloud statistics the methods use: a tiled run gathers them from the tiles
    that own the sampled points, so every tile resolves the same parameters.

    Attributes:
      distinct: (S,) distance to the nearest distinct point (inf where there is none).
      other: (S,) distance to the nearest other point (0 for a duplicated location).
      offsets: (S, SAMPLE_K, 3) the ``SAMPLE_K`` nearest locations minus the point
        (:func:`sample_offsets`), masked by ``valid`` (S, SAMPLE_K).
    """

    distinct: np.ndarray
    other: np.ndarray
    offsets: np.ndarray
    valid: np.ndarray

    def resolution(self, *, robust: bool) -> float:
        """Median nearest-distinct distance (``robust``) or mean nearest-other distance; 0.0 if none."""
        values = self.distinct if robust else self.other
        values = values[np.isfinite(values)]
        if values.size == 0:
            return 0.0
        return float(np.median(values) if robust else np.mean(values))

    def irregularity(self) -> float:
        """std / mean of the nearest-distinct distances: 0 on a lattice, about 0.52 on random samples."""
        values = self.distinct[np.isfinite(self.distinct)]
        mean = float(np.mean(values)) if values.size else 0.0
        return float(np.std(values) / mean) if mean > 0 else 0.0


def sample_stats(index: SpatialIndex) -> SampleStats:
    """:class:`SampleStats` of a whole cloud whose index rows were built from global ids 0..N-1."""
    rows = index.row[sample_ids(index.n_caller)]
    return SampleStats(*nearest_distances(index, rows), *sample_offsets(index, rows)[:2])


def resolution(index: SpatialIndex, *, robust: bool) -> float:
    """:func:`intrinsic_resolution` of an already built whole-cloud index."""
    return sample_stats(index).resolution(robust=robust)


def local_spacing(index: SpatialIndex, rows: np.ndarray, k: int = 16, *,
                  query: tuple[np.ndarray, np.ndarray] | None = None,
                  rk: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-row surface sample spacing 1 / sqrt(areal density), from the k nearest points.

    On a surface sampled with areal density rho, the disc holding a point's k nearest other
    points has area about pi r_k^2 = k / rho, so s = sqrt(pi r_k^2 / k) estimates the
    spacing 1 / sqrt(rho) whatever the sampling: it is the lattice spacing h of a grid-like
    cloud and 1 / sqrt(rho) of a random one (whose nearest-neighbour distance is only about
    half of it). r_k^2 is averaged over the row's k nearest points (ties by global id) to
    smooth the estimate. Meant for a deduplicated index. Rows with r_k = 0 (fewer than k + 1
    distinct points in all) get 1.0.

    Args:
      index: the (deduplicated) index.
      rows: (R,) sorted-frame rows.
      k: number of nearest other points.
      query: the rows' :meth:`SpatialIndex.nearest` result with at least k + 1 columns,
        reused instead of a new query (same result).
      rk: (n,) float64 r_k of the index's rows, NaN where not yet known: read, and filled in
        place with the r_k this call finds, so that batches of rows share their neighbours'.

    Returns:
      (spacing, reach): (R,) spacing, and (R,) the distance within which every point the
      estimate used lies (the row's own k-th distance plus that of its farthest neighbour).
    """
    rows = np.asarray(rows, dtype=np.int64)
    k = min(k, index.n - 1)
    if k < 1:
        return np.ones(rows.size), np.zeros(rows.size)
    nbrs, reach = chunked_knn(index, k + 1, rows) if query is None else index.neighbours(k + 1, rows, query=query)
    rk = np.full(index.n, np.nan) if rk is None else rk
    rk[rows] = reach
    extra = np.unique(nbrs[np.isnan(rk[nbrs])])
    if extra.size:
        rk[extra] = chunked_knn(index, k + 1, extra)[1]
    return spacing_of(rk[nbrs], reach)


def spacing_of(rk_near: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(spacing, reach) of :func:`local_spacing` from each row's r_k of its k + 1 nearest points ``rk_near``
    (R, k + 1), itself first, and the row's own k-th distance ``reach`` (R,)."""
    k = rk_near.shape[1] - 1
    spacing = np.sqrt(np.pi / k * (rk_near ** 2).mean(axis=1))
    return np.where(spacing > 0, spacing, 1.0), reach + rk_near.max(axis=1)


def knn_batches(index: SpatialIndex, k: int, rows: np.ndarray):
    """:meth:`SpatialIndex.neighbours` of sorted-frame ``rows`` (R,), batch by batch (:func:`batches`).

    The tree queries of the next QUERIES_AHEAD batches are queued in a background thread
    (the query releases the GIL) while this one is ranked and consumed, so each query starts
    as soon as the one before it ends, whether or not the host work on the earlier batches
    is done. Results are those of :meth:`SpatialIndex.neighbours` on each batch.

    Yields:
      (part, idx, reach): part a slice of ``rows``; idx (r, k) int32 and reach (r,) as
      :meth:`SpatialIndex.neighbours`.
    """
    rows = np.asarray(rows, dtype=np.int64)
    parts = batches(rows.size)
    width = min(k + 1, index.n)  # the columns neighbours reads
    with concurrent.futures.ThreadPoolExecutor(1) as ahead:
        pending = collections.deque(ahead.submit(index.nearest, rows[part], width)
                                    for part in parts[:QUERIES_AHEAD])
        for i, part in enumerate(parts):
            query = pending.popleft().result()
            if i + QUERIES_AHEAD < len(parts):
                pending.append(ahead.submit(index.nearest, rows[parts[i + QUERIES_AHEAD]], width))
            yield (part, *index.neighbours(k, rows[part], query=query))


def chunked_knn(index: SpatialIndex, k: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`SpatialIndex.neighbours` of ``rows`` in batches of QUERY_ROWS (bounds the query's memory)."""
    parts = list(knn_batches(index, k, rows))
    if not parts:
        return np.zeros((0, k), np.int32), np.zeros(0)
    return np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
