"""Host-side spatial queries with SciPy's k-d tree, and the :class:`Neighbourhoods` they fill.

This is the only module that touches ``scipy.spatial.cKDTree``. Everything here runs on the
host and is not jittable; the kernels in :mod:`hgjax.scores` consume its padded index arrays
under ``jax.jit``.

Conventions (shared with every kernel):

* ``idx`` is int32 of shape (N, K); missing neighbours are padded with the sentinel ``N``
  (cKDTree's own convention), so a mask is ``idx < N``.
* k-nearest neighbourhoods list the point itself first, then its neighbours by increasing
  distance (equal distances by index in the spatially sorted frame, which is deterministic).
* Before querying, points are put in Morton (Z-curve) order, which makes the tree query
  several times faster on large clouds; results are always returned in the caller's order
  and do not depend on the order of the input points.
* Coordinates are moved to a local frame (the float64 centre of the bounding box subtracted)
  before any cast to the working dtype, so georeferenced clouds (UTM offsets of 1e5-1e7)
  keep their precision in float32. Every score is translation-invariant.
* With ``dedupe=True`` exact duplicates are one point for the queries: each copy gets the
  neighbourhood of its first occurrence, whose row lists no other copy. Exact duplicates
  carry no geometry, so a default score is the same with or without them.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Iterator

import jax
import numpy as np
from scipy.spatial import cKDTree

from hgjax import _validate

__all__ = [
    "Neighbourhoods",
    "PrecisionWarning",
    "SpatialIndex",
    "cube",
    "intrinsic_resolution",
    "knn",
    "local_frame",
    "spatial_order",
    "working_dtype",
]

_MORTON_BITS = 21  # 3 * 21 = 63 bits fit in uint64
RESOLUTION_SAMPLES = 1000
CUBE_GROUPS = 8  # cube queries bound each eighth of a batch (by half-width) separately


class PrecisionWarning(UserWarning):
    """float64 input computed in float32 because JAX's x64 mode is off."""


def working_dtype(dtype) -> np.dtype:
    """The dtype kernels run in: the caller's, or float32 for float64 input without x64.

    JAX keeps 64-bit types opt-in (``jax.config.update("jax_enable_x64", True)``). Without
    it, float64 input is computed in float32 and a :class:`PrecisionWarning` says so (never a
    silent cast). Coordinates are first moved to a local frame in float64
    (:func:`local_frame`), so the cast loses no more than the cloud's own extent allows.

    Args:
      dtype: the caller's float dtype.

    Returns:
      np.dtype float32 or float64.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.working_dtype(np.float32)
      dtype('float32')
    """
    dtype = np.dtype(dtype)
    if dtype == np.float64 and not jax.config.jax_enable_x64:
        warnings.warn("float64 points are computed in float32 because jax_enable_x64 is off;"
                      ' call jax.config.update("jax_enable_x64", True) for float64 precision',
                      PrecisionWarning, stacklevel=3)
        return np.dtype(np.float32)
    return dtype


def local_frame(points) -> tuple[np.ndarray, np.ndarray]:
    """The cloud in a local frame: coordinates minus the centre of its bounding box.

    The subtraction is done in float64 whatever the input dtype, before any cast, so a
    georeferenced cloud (x about 5e5, y about 4e6) keeps millimetre detail in float32.

    Args:
      points: (N, 3) float32 or float64 (validated).

    Returns:
      (local, origin): local (N, 3) float64 with ``local + origin == points`` up to
      rounding, and origin (3,) float64.

    Examples:
      >>> import numpy as np, hgjax
      >>> local, origin = hgjax.local_frame(np.array([[500000.0, 4e6, 0], [500002, 4e6, 1]]))
      >>> local.tolist(), origin.tolist()
      ([[-1.0, 0.0, -0.5], [1.0, 0.0, 0.5]], [500001.0, 4000000.0, 0.5])
    """
    p = np.asarray(points, dtype=np.float64)
    origin = (p.min(axis=0) + p.max(axis=0)) / 2
    return p - origin, origin


@functools.partial(jax.tree_util.register_dataclass, data_fields=["points", "idx", "scale", "first"], meta_fields=[])
@dataclasses.dataclass(frozen=True)
class Neighbourhoods:
    """Padded neighbourhoods of a cloud: the one currency between host and kernels.

    A registered JAX pytree: pass it to jitted functions, stack a batch of equal-shape ones
    for ``jax.vmap`` ((B, N, 3) points, (B, N, K) idx), differentiate with respect to its
    points. Masks are derived (``idx < N``), not stored. Build it on the host with
    :func:`hgjax.neighbourhoods` (per method) or :func:`knn` / :func:`cube`.

    Attributes:
      points: (N, 3) float coordinates in a local frame (see :func:`local_frame`).
      idx: (N, K) int32 neighbour indices into ``points``, padded with the sentinel N.
        K is static: a new K compiles a new kernel.
      scale: (N,) per-point length of the method (the voxel spacing d of HKC/HKF), or None.
      first: (N,) int32 index of the first point at each point's location, or None (every
        point its own location). Set by GFR's invariant graph, which links distinct
        locations once (the rows of later copies are empty) and weighs each by its number
        of points.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.Neighbourhoods(np.zeros((2, 3)), np.array([[0, 2], [1, 0]], np.int32))
      >>> nb.mask.tolist()
      [[True, False], [True, True]]
    """

    points: np.ndarray
    idx: np.ndarray
    scale: np.ndarray | None = None
    first: np.ndarray | None = None

    @property
    def mask(self):
        """(N, K) bool, True where ``idx`` names a real neighbour."""
        return self.idx < self.points.shape[-2]


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
    lo = p.min(axis=0)
    extent = float((p.max(axis=0) - lo).max())
    scale = (2**_MORTON_BITS - 1) / extent if extent > 0 else 0.0
    q = ((p - lo) * scale).astype(np.uint64)
    code = _spread_bits(q[:, 0]) << np.uint64(2) | _spread_bits(q[:, 1]) << np.uint64(1) | _spread_bits(q[:, 2])
    order = np.argsort(code, kind="stable")
    # Points sharing a Morton cell are rare; sort just those runs by their coordinates.
    sorted_code = code[order]
    tied = np.zeros(len(order), dtype=bool)
    tied[1:] = sorted_code[1:] == sorted_code[:-1]
    tied[:-1] |= tied[1:]
    if tied.any():
        sub = order[tied]
        order[tied] = sub[np.lexsort((p[sub, 2], p[sub, 1], p[sub, 0], code[sub]))]
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

    def __init__(self, points: np.ndarray, *, dedupe: bool = False):
        self.n_caller = int(points.shape[0])
        order = spatial_order(points)
        sorted_points = np.ascontiguousarray(points[order])
        row = np.arange(self.n_caller)
        first = row
        if dedupe and self.n_caller > 1:
            # spatial_order puts exact duplicates next to each other, the lowest index first.
            same = np.zeros(self.n_caller, dtype=bool)
            same[1:] = (sorted_points[1:] == sorted_points[:-1]).all(axis=1)
            if same.any():
                row = np.cumsum(~same) - 1
                first = np.flatnonzero(~same)
                sorted_points = sorted_points[first]
        self.n = int(sorted_points.shape[0])
        self.points = sorted_points
        self.order = order[first]  # sorted row -> caller index of its first copy
        self.row = np.empty(self.n_caller, dtype=np.int64)  # caller index -> sorted row
        self.row[order] = row
        self.tree = cKDTree(self.points, leafsize=16, balanced_tree=False)

    def to_caller(self, values: np.ndarray) -> np.ndarray:
        """Per-row ``values`` (n, ...) of the sorted frame as (N, ...) in the caller's order."""
        return values[self.row]

    def caller_idx(self, idx_sorted: np.ndarray) -> np.ndarray:
        """Sorted-frame neighbour rows (n, K) as caller-frame rows and indices (N, K), sentinel N."""
        ext = np.append(self.order, self.n_caller).astype(np.int32)
        return ext[np.where(idx_sorted < self.n, idx_sorted, self.n)][self.row]

    def knn(self, k: int, rows: slice | np.ndarray = slice(None)) -> np.ndarray:
        """The point itself and its k - 1 nearest neighbours, sorted frame.

        Args:
          k: neighbourhood size including the point itself.
          rows: which sorted-frame rows to query (default all).

        Returns:
          (R, k) int32 indices (sorted frame), column 0 the point itself.
        """
        row_ids = self.row_ids(rows)
        k_eff = min(k, self.n)
        _, idx = self.tree.query(self.points[row_ids], k=k_eff, workers=-1)
        idx = idx.reshape(len(row_ids), k_eff)
        if k_eff < k:  # only reachable through validation-free internal calls
            idx = np.concatenate([idx, np.full((len(row_ids), k - k_eff), self.n)], axis=1)
        # Exact duplicates tie at distance 0; make sure the point itself comes first.
        bad = np.flatnonzero(idx[:, 0] != row_ids)
        if bad.size:  # only rows with exact duplicates
            sub, me = idx[bad], row_ids[bad, None]
            is_self = sub == me
            sub = np.take_along_axis(sub, np.argsort(~is_self, axis=1, kind="stable"), axis=1)
            missing = ~is_self.any(axis=1)  # more than k exact duplicates: self was cut off
            sub[missing] = np.concatenate([me[missing], sub[missing, :-1]], axis=1)
            idx[bad] = sub
        return idx.astype(np.int32)

    def cube(self, half_width, rows: slice | np.ndarray = slice(None), *, capacity: int = 32,
             max_count: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """All points within the axis-aligned cube of ``half_width`` (Chebyshev distance < h).

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

        Returns:
          (idx, half): idx (R, W) int32 indices (sorted frame) by increasing Chebyshev
          distance, padded with n, W the fullest row's count; half (R,) the half-widths used.
        """
        row_ids = self.row_ids(rows)
        queries = self.points[row_ids]
        h = np.array(np.broadcast_to(np.asarray(half_width, dtype=np.float64), (len(row_ids),)))
        out = np.full((len(row_ids), 1), self.n, dtype=np.int32)
        todo, k = np.arange(len(row_ids)), min(capacity, self.n)
        while todo.size:
            if max_count is not None:
                k = min(k, max_count)
            dist, idx = self._cube_query(queries[todo], k, h[todo])
            full = dist[:, -1] < h[todo]
            if k == max_count:  # shrink the full cubes to exclude their max_count-th point
                h[todo[full]] = dist[full, -1]
                full[:] = False
            inside = dist < h[todo, None]  # a prefix of each row: sorted by distance
            done = ~full | (k == self.n)
            width = int(inside[done].sum(axis=1).max(initial=1))
            if width > out.shape[1]:
                out = np.pad(out, ((0, 0), (0, width - out.shape[1])), constant_values=self.n)
            out[todo[done], :width] = np.where(inside[done, :width], idx[done, :width], self.n)
            todo, k = todo[~done], min(2 * k, self.n)
        return out, h

    def _cube_query(self, queries: np.ndarray, k: int, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R, k) Chebyshev k-nearest distances and indices, each row searched within about its own h.

        cKDTree takes one distance bound per call; a batch's largest h lets every row of a cloud
        whose density varies (a scan: near and far from the sensor) search far past its own cube.
        Rows are grouped by h (spatial order kept inside a group) and each group is bounded by
        its largest h. Every row still gets all its points closer than its h: the same sets.
        """
        groups = CUBE_GROUPS if h.size >= CUBE_GROUPS * 128 and h.min() < h.max() else 1
        dist, idx = np.empty((h.size, k)), np.empty((h.size, k), dtype=np.intp)
        for g in np.array_split(np.argsort(h, kind="stable"), groups):
            g = np.sort(g)
            d, i = self.tree.query(queries[g], k=k, p=np.inf, distance_upper_bound=float(h[g].max()), workers=-1)
            dist[g], idx[g] = d.reshape(g.size, k), i.reshape(g.size, k)
        return dist, idx

    def ball(self, radius: float, rows: slice | np.ndarray = slice(None), *, max_nn: int,
             capacity: int = 16) -> tuple[np.ndarray, np.ndarray]:
        """The at most ``max_nn`` nearest points at Euclidean distance in (0, radius].

        The point itself and its exact duplicates (distance 0) are excluded. The query
        capacity starts at ``capacity`` and doubles for the rows that fill it, until every
        row holds all its points within ``radius`` or ``max_nn`` of them: rows with more
        than ``max_nn`` keep the nearest (this cap is part of the GFR graph's definition;
        equal distances at the cap are broken in the tree's order).

        Args:
          radius: inclusive Euclidean radius (``np.inf`` for no limit).
          rows: which sorted-frame rows to query (default all).
          max_nn: the most neighbours kept per row.
          capacity: initial number of columns queried.

        Returns:
          (idx, dist): (R, K) int32 indices (sorted frame) padded with N, and (R, K) float64
          distances padded with inf, both by increasing distance; K <= max_nn is the largest
          row count.
        """
        queries = self.points[rows]
        bound = np.nextafter(radius, np.inf)  # cKDTree's bound is strict; ours is inclusive
        k = min(capacity, self.n)
        dist = np.full((len(queries), min(k, max_nn)), np.inf)
        idx = np.full(dist.shape, self.n, dtype=np.int32)
        todo = np.arange(len(queries))
        while todo.size:
            d, i = self.tree.query(queries[todo], k=k, distance_upper_bound=bound, workers=-1)
            d, i = d.reshape(todo.size, k), i.reshape(todo.size, k)
            # Sorted by distance: the zero-distance points form a prefix, hits beyond the
            # radius a suffix, so the kept columns of a row are one contiguous run.
            zeros = (d == 0).sum(axis=1)
            count = np.minimum((i < self.n).sum(axis=1) - zeros, max_nn)
            done = (i[:, -1] == self.n) | (count == max_nn) | (k == self.n)
            width = min(k, max_nn)
            cols = np.minimum(zeros[done, None] + np.arange(width), k - 1)
            take = np.arange(width) < count[done, None]
            if width > dist.shape[1]:
                grow = ((0, 0), (0, width - dist.shape[1]))
                dist, idx = np.pad(dist, grow, constant_values=np.inf), np.pad(idx, grow, constant_values=self.n)
            dist[todo[done], :width] = np.where(take, np.take_along_axis(d[done], cols, axis=1), np.inf)
            idx[todo[done], :width] = np.where(take, np.take_along_axis(i[done], cols, axis=1), self.n)
            todo = todo[~done]
            k = min(2 * k, self.n)
        width = int((idx < self.n).sum(axis=1).max(initial=0))
        return idx[:, :width], dist[:, :width]

    def row_ids(self, rows: slice | np.ndarray) -> np.ndarray:
        """The sorted-frame row numbers that ``rows`` selects, as an int64 array."""
        if isinstance(rows, slice):
            return np.arange(*rows.indices(self.n))
        return np.asarray(rows, dtype=np.int64)

    def chunks(self, chunk_size: int) -> Iterator[slice]:
        """Consecutive sorted-frame row slices of at most ``chunk_size`` rows."""
        for start in range(0, self.n, chunk_size):
            yield slice(start, min(start + chunk_size, self.n))


QUERY_ROWS = 1 << 14  # rows per host query batch: bounds the query's temporary memory


def bucket(width: int) -> int:
    """Columns for a neighbourhood of ``width`` points: the next power of two, at least 8.

    Few distinct widths means few compiled kernels across clouds.
    """
    return max(8, 1 << max(0, int(width) - 1).bit_length())


def pad_queries(index: SpatialIndex, query, capacity, what: str) -> np.ndarray:
    """Run ``query(rows)`` over all sorted rows in batches; pad to ``capacity`` or a bucket.

    Raises:
      ValueError: when a fixed ``capacity`` is smaller than the fullest row.
    """
    parts = [query(rows) for rows in index.chunks(QUERY_ROWS)]
    width = max(p.shape[1] for p in parts)
    _validate.check_capacity(capacity, width, what)
    cols = bucket(width) if capacity is None else capacity
    return np.concatenate([np.pad(p, ((0, 0), (0, cols - p.shape[1])), constant_values=index.n) for p in parts])


def assemble(points: np.ndarray, index: SpatialIndex, idx_sorted: np.ndarray, scale_sorted=None) -> Neighbourhoods:
    """Neighbourhoods in the caller's order from sorted-frame query results.

    Args:
      points: (N, 3) the caller's validated points.
      index: the index the query ran on.
      idx_sorted: (n, K) sorted-frame neighbour rows, padded with n.
      scale_sorted: optional (n,) per-row length.

    Returns:
      :class:`Neighbourhoods` whose points are the caller's in a local frame, cast to the
      working dtype (see :func:`working_dtype`).
    """
    dtype = working_dtype(points.dtype)
    local = local_frame(points)[0].astype(dtype)
    scale = None if scale_sorted is None else index.to_caller(np.asarray(scale_sorted)).astype(dtype)
    return Neighbourhoods(local, index.caller_idx(idx_sorted), scale)


def knn(points, k: int, *, dedupe: bool = False, capacity: int | None = None) -> Neighbourhoods:
    """k-nearest neighbourhoods, the point itself first.

    Args:
      points: (N, 3) float32 or float64.
      k: neighbourhood size, counting the point itself (1 <= k <= N).
      dedupe: count exact duplicates once (each copy gets its location's neighbourhood).
      capacity: columns of ``idx`` (default k); must be >= k.

    Returns:
      Neighbourhoods with ``idx`` (N, K) int32 in the caller's order; ``idx[:, 0]`` is the
      point itself (with ``dedupe``, the first copy of its location), then neighbours by
      increasing distance. Rows are padded with N only when there are fewer than k distinct
      locations (``dedupe``) or K > k.

    Raises:
      TypeError, ValueError: for invalid points, k or capacity.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.knn(np.eye(3), 2)
      >>> nb.idx[:, 0].tolist()
      [0, 1, 2]
    """
    pts = _validate.check_points(points)
    k = _validate.check_int(k, "k", minimum=1)
    _validate.check_min_points(pts.shape[0], k, f"k={k} nearest neighbours")
    cap = k if capacity is None else _validate.check_int(capacity, "capacity", minimum=k)
    index = SpatialIndex(local_frame(pts)[0], dedupe=dedupe)
    return assemble(pts, index, pad_queries(index, lambda rows: index.knn(k, rows), cap, "k-nearest neighbourhood"))


def cube(points, half_width, *, dedupe: bool = False, capacity: int | None = None) -> Neighbourhoods:
    """Axis-aligned cube neighbourhoods (Chebyshev distance < half_width), the ROI of HKC/HKF.

    Args:
      points: (N, 3) float32 or float64.
      half_width: half the cube side, > 0: a scalar or one per point (N,).
      dedupe: count exact duplicates once.
      capacity: columns of ``idx``. Default: the fullest cube's count rounded up to a power
        of two (at least 8), so nothing is ever truncated.

    Returns:
      Neighbourhoods with ``idx`` (N, K) int32 in the caller's order, padded with N, each
      row by increasing Chebyshev distance (the point itself first).

    Raises:
      ValueError: for invalid input, or when a cube holds more than a fixed ``capacity``
        (the message names the capacity needed).

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.cube(np.array([[0., 0, 0], [1, 0, 0], [5, 0, 0]]), 1.5)
      >>> (nb.idx < 3).sum(axis=1).tolist()
      [2, 2, 1]
    """
    pts = _validate.check_points(points)
    half = _validate.check_positive_array(half_width, "half_width", pts.shape[0])
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    index = SpatialIndex(local_frame(pts)[0], dedupe=dedupe)
    half_sorted = np.broadcast_to(half, (pts.shape[0],))[index.order]
    idx = pad_queries(index, lambda rows: index.cube(half_sorted[rows], rows)[0], cap, "cube")
    return assemble(pts, index, idx)


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


def _nearest_sample(index: SpatialIndex) -> np.ndarray:
    """Nearest-other-point distances of all rows (n <= 1000) or of 1000 seeded rows."""
    if index.n <= RESOLUTION_SAMPLES:
        rows = np.arange(index.n)
    else:
        rows = np.sort(np.random.default_rng(0).choice(index.n, RESOLUTION_SAMPLES, replace=False))
    return index.tree.query(index.points[rows], k=2, workers=-1)[0][:, 1]


def resolution(index: SpatialIndex, *, robust: bool) -> float:
    """:func:`intrinsic_resolution` of an already built index (deduplicated when ``robust``)."""
    if index.n < 2:
        return 0.0
    nearest = _nearest_sample(index)
    return float(np.median(nearest) if robust else np.mean(nearest))


def irregularity(index: SpatialIndex) -> float:
    """Coefficient of variation std / mean of the nearest-neighbour distances (same sample).

    0 for a lattice (grid-like CAD exports, structured scans), about 0.1 p for a lattice with
    noise of p spacings, about 0.52 for uniformly random surface samples; 0.0 when undefined.
    Meant for a deduplicated index.
    """
    if index.n < 2:
        return 0.0
    nearest = _nearest_sample(index)
    mean = float(np.mean(nearest))
    return float(np.std(nearest) / mean) if mean > 0 else 0.0


def local_spacing(index: SpatialIndex, k: int = 16) -> np.ndarray:
    """(n,) per-row surface sample spacing 1 / sqrt(areal density), from the k nearest points.

    On a surface sampled with areal density rho, the disc holding a point's k nearest other
    points has area about pi r_k^2 = k / rho, so s = sqrt(pi r_k^2 / k) estimates the
    spacing 1 / sqrt(rho) whatever the sampling: it is the lattice spacing h of a grid-like
    cloud and 1 / sqrt(rho) of a random one (whose nearest-neighbour distance is only about
    half of it). r_k^2 is averaged over the row's k nearest points to smooth the estimate.
    Meant for a deduplicated index. Rows without k neighbours, or with r_k = 0, get the
    median of the rest (1.0 if no row has a value).
    """
    k = min(k, index.n - 1)
    if k < 1:
        return np.ones(index.n)
    rk2 = np.empty(index.n)
    nbrs = np.empty((index.n, k + 1), dtype=np.int32)
    for rows in index.chunks(QUERY_ROWS):
        dist, nbrs[rows] = index.tree.query(index.points[rows], k=k + 1, workers=-1)
        rk2[rows] = dist[:, -1] ** 2
    spacing = np.sqrt(np.pi / k * rk2[nbrs].mean(axis=1))
    ok = spacing > 0
    fill = float(np.median(spacing[ok])) if ok.any() else 1.0
    return np.where(ok, spacing, fill)
