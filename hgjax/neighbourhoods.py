"""Neighbourhoods built on the host with SciPy's k-d tree.

This is the only module that touches ``scipy.spatial.cKDTree``. Everything here runs on the
host and is not jittable; the kernels in :mod:`hgjax.scores` consume its padded index arrays
under ``jax.jit``.

Conventions (shared with every kernel):

* ``idx`` is int32 of shape (N, K); missing neighbours are padded with the sentinel ``N``
  (cKDTree's own convention), so a mask is ``idx < N``.
* k-nearest neighbourhoods list the point itself first, then its neighbours by increasing
  distance (ties in the order the tree returns them, which is deterministic).
* Before querying, points are put in Morton (Z-curve) order, which makes the tree query
  several times faster on large clouds; results are always returned in the caller's order
  and do not depend on the order of the input points.
"""

from __future__ import annotations

from typing import Iterator, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from hgjax import _validate

__all__ = [
    "Neighbourhoods",
    "SpatialIndex",
    "cube",
    "intrinsic_resolution",
    "knn",
    "spatial_order",
]

_MORTON_BITS = 21  # 3 * 21 = 63 bits fit in uint64
RESOLUTION_SAMPLES = 1000


class Neighbourhoods(NamedTuple):
    """Padded neighbourhoods of a cloud, a JAX pytree (NamedTuple).

    Attributes:
      points: (N, 3) float coordinates.
      idx: (N, K) int32 neighbour indices into ``points``, padded with the sentinel N.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.Neighbourhoods(np.zeros((2, 3)), np.array([[0, 2], [1, 0]], np.int32))
      >>> nb.mask.tolist()
      [[True, False], [True, True]]
    """

    points: np.ndarray
    idx: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(N, K) bool, True where ``idx`` names a real neighbour."""
        return self.idx < self.points.shape[0]


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

    Queries return indices in the sorted frame; :meth:`to_caller` maps per-point results back.
    Build it once and reuse it for several queries on the same cloud.

    Args:
      points: (N, 3) float array (validated by the caller).
    """

    def __init__(self, points: np.ndarray):
        self.n = int(points.shape[0])
        self.order = spatial_order(points)
        self.points = np.ascontiguousarray(points[self.order])
        self.tree = cKDTree(self.points, leafsize=16, balanced_tree=False, compact_nodes=False)

    def to_caller(self, values: np.ndarray) -> np.ndarray:
        """Reorder per-point ``values`` (N, ...) from the sorted frame to the caller's order."""
        out = np.empty_like(values)
        out[self.order] = values
        return out

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

    def cube(self, half_width: float, rows: slice | np.ndarray = slice(None), *, capacity: int = 32,
             max_capacity: int = 4096) -> np.ndarray:
        """All points within the axis-aligned cube of ``half_width`` (Chebyshev distance).

        The capacity starts at ``capacity`` and doubles for the rows that fill it, until
        every row fits: nothing is ever truncated.

        Args:
          half_width: half the cube side (points at Chebyshev distance <= half_width).
          rows: which sorted-frame rows to query (default all).
          capacity: initial number of columns.
          max_capacity: the most columns allowed before raising.

        Returns:
          (R, K) int32 indices (sorted frame), padded with N; K is a power of two >=
          ``capacity``, large enough for the fullest row.

        Raises:
          ValueError: if some cube holds more than ``max_capacity`` points.
        """
        queries = self.points[rows]
        k = capacity
        while True:
            _, idx = self.tree.query(queries, k=k, p=np.inf, distance_upper_bound=half_width,
                                     workers=-1)
            idx = idx.reshape(len(queries), k)
            if k >= self.n or not (idx[:, -1] < self.n).any():
                return np.where(idx < self.n, idx, self.n).astype(np.int32)
            if k >= max_capacity:
                full = int((idx[:, -1] < self.n).sum())
                raise ValueError(
                    f"{full} cube neighbourhood(s) of half-width {half_width:.6g} hold more than"
                    f" max_capacity={max_capacity} points; the cloud is much denser there than its"
                    " intrinsic resolution suggests (duplicates?). Pass a larger max_capacity or a"
                    " smaller d_factor / resolution."
                )
            k = min(2 * k, max_capacity)

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


def _to_caller_frame(index: SpatialIndex, idx_sorted: np.ndarray) -> np.ndarray:
    """Map sorted-frame neighbour rows to caller-frame rows and caller-frame indices."""
    ext = np.append(index.order, index.n).astype(np.int32)  # the sentinel maps to itself
    return index.to_caller(ext[idx_sorted])


def knn(points, k: int) -> Neighbourhoods:
    """k-nearest neighbourhoods, the point itself first.

    Args:
      points: (N, 3) float32 or float64.
      k: neighbourhood size, counting the point itself (1 <= k <= N).

    Returns:
      Neighbourhoods with ``idx`` (N, k) int32 in the caller's order; ``idx[:, 0]`` is the
      point itself, then neighbours by increasing distance. No padding is needed.

    Raises:
      TypeError, ValueError: for invalid points or k (see :mod:`hgjax._validate`).

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.knn(np.eye(3), 2)
      >>> nb.idx[:, 0].tolist()
      [0, 1, 2]
    """
    pts = _validate.check_points(points)
    k = _validate.check_int(k, "k", minimum=1)
    _validate.check_min_points(pts.shape[0], k, f"k={k} nearest neighbours")
    index = SpatialIndex(pts)
    return Neighbourhoods(pts, _to_caller_frame(index, index.knn(k)))


def cube(points, half_width: float, *, capacity: int = 32, max_capacity: int = 4096) -> Neighbourhoods:
    """Axis-aligned cube neighbourhoods (Chebyshev distance <= half_width), the ROI of HKC/HKF.

    Args:
      points: (N, 3) float32 or float64.
      half_width: half the cube side, > 0.
      capacity: initial number of columns; grown (doubled) until no row overflows.
      max_capacity: raise instead of growing past this.

    Returns:
      Neighbourhoods with ``idx`` (N, K) int32 in the caller's order, padded with N. Each
      row contains the point itself (in no particular column).

    Raises:
      ValueError: for invalid input or when a cube holds more than ``max_capacity`` points.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.cube(np.array([[0., 0, 0], [1, 0, 0], [5, 0, 0]]), 1.5, capacity=1)
      >>> (nb.idx < 3).sum(axis=1).tolist()
      [2, 2, 1]
    """
    pts = _validate.check_points(points)
    half_width = _validate.check_positive(half_width, "half_width")
    capacity = _validate.check_int(capacity, "capacity", minimum=1)
    index = SpatialIndex(pts)
    return Neighbourhoods(pts, _to_caller_frame(index, index.cube(half_width, capacity=capacity,
                                                                 max_capacity=max_capacity)))


def intrinsic_resolution(points) -> float:
    """Intrinsic resolution: mean distance from a point to its nearest other point.

    Averaged over all points when N <= 1000, else over 1000 points drawn with a fixed seed
    from the spatially sorted cloud, so the value is deterministic and does not depend on
    the order of the input points (REFERENCE.md, "Intrinsic resolution").

    Args:
      points: (N, 3) float32 or float64, N >= 2.

    Returns:
      The resolution as a Python float. It is 0.0 when every sampled point has an exact
      duplicate (for example when all points are equal).

    Raises:
      TypeError, ValueError: for invalid points, or N < 2.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.intrinsic_resolution(np.array([[0., 0, 0], [1, 0, 0], [3, 0, 0]]))
      1.3333333333333333
    """
    pts = _validate.check_points(points)
    _validate.check_min_points(pts.shape[0], 2, "an intrinsic resolution")
    return _resolution(SpatialIndex(pts))


def _resolution(index: SpatialIndex) -> float:
    """intrinsic_resolution on an already built index (sorted frame, seeded subset)."""
    if index.n <= RESOLUTION_SAMPLES:
        rows = np.arange(index.n)
    else:
        rows = np.sort(np.random.default_rng(0).choice(index.n, RESOLUTION_SAMPLES, replace=False))
    dist, _ = index.tree.query(index.points[rows], k=2, workers=-1)
    return float(np.mean(dist[:, 1]))
