"""Geometry-agnostic samplers people compare against: uniform random, voxel grid, farthest point.

They play the role of Open3D's ``random_down_sample``, ``voxel_down_sample`` and
``farthest_point_down_sample``, but like every hgjax method they return exactly
ceil(ratio N) unique int64 indices into the caller's points, highest priority first.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import types

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _method, _validate
from hgjax.neighbours import spatial
from hgjax.engine.select import ascending_bits, keyed_top

__all__ = ["farthest_point_sample", "fps_backend", "uniform_sample", "voxel_sample"]

VOXEL_LEVELS = 2**20  # the finest voxel grid has at most this many cells along each axis
VOXEL_PROBE_POINTS = 2**13  # points of the strided subsample that estimates the voxel size
VOXEL_ASSIGN_PASSES = 2  # full-cloud passes that assign voxels in the count-targeted search, after one counting pass
VOXEL_SLACK = 1 / 32  # a grid with M to M (1 + slack) voxels ends the search
FPS_BACKENDS = ("auto", "fpsample", "jax")


def uniform_sample(points, ratio: float, *, key) -> np.ndarray:
    """A uniformly random subset of ceil(ratio N) points, without replacement.

    Args:
      points: (N, 3) float32 or float64 (only its size is used, after validation).
      ratio: fraction to keep, in (0, 1].
      key: ``jax.random`` key; the same key gives the same subset.

    Returns:
      (M,) int64 unique indices in draw order, M = ceil(ratio N): the points with the
      largest draws, each point's draw made from the key and its index alone
      (:func:`hgjax.engine.select.point_bits`), so a point's fate does not depend on N or on tiles.

    Raises:
      TypeError, ValueError: invalid points, ratio or key (a missing key is an error).

    Examples:
      >>> import jax, numpy as np, hgjax
      >>> idx = hgjax.uniform_sample(np.zeros((10, 3)), 0.3, key=jax.random.key(0))
      >>> len(set(idx.tolist()))
      3
    """
    return uniform_ids(_validate.check_points(points).shape[0], ratio, key=key)


def uniform_ids(n: int, ratio: float, *, key) -> np.ndarray:
    """:func:`uniform_sample` of a cloud of ``n`` points, from its size alone (a survey's count).

    Raises:
      TypeError, ValueError: invalid ratio or key.
    """
    m = _validate.n_keep(n, _validate.check_ratio(ratio))
    return keyed_top(_validate.check_key(key, "uniform"), n, m)


def _voxel_cells(cols: np.ndarray, origin: np.ndarray, size: float) -> np.ndarray:
    """(3, N) int64 cell of each point in the grid of edge ``size``; ``cols`` is the (3, N) cloud."""
    return ((cols - origin[:, None]) / size).astype(np.int64)  # >= 0, so truncation is floor


def _voxel_probe(keys, code, bits):
    """Slot of ``code`` in the table ``keys`` (2^bits slots, -1 empty): its own, or the empty one to fill.

    The start is the top bits of MurmurHash3's 64-bit finalizer, a full mix rather than one
    multiplication: the codes form lattices (cells^2, cells, 1), and a multiplicative hash
    clusters them for some grid sizes, halving the table's speed. Then linear probing.
    """
    x = np.uint64(code)
    x ^= x >> np.uint64(33)
    x *= np.uint64(0xFF51AFD7ED558CCD)
    x ^= x >> np.uint64(33)
    x *= np.uint64(0xC4CEB9FE1A85EC53)
    x ^= x >> np.uint64(33)
    s = np.int64(x >> np.uint64(64 - bits))
    while keys[s] != code and keys[s] != -1:
        s = (s + 1) & (keys.size - 1)
    return s


def _voxel_table(cols, origin, size, cells, assign, coarse):
    """Occupied voxels of edge ``size`` (and 2 ``size``) by open-addressing tables of voxel codes.

    One pass over the points: each point's cell (``cells`` per axis, at least the largest
    index plus one), its code looked up in a table of 2N slots (:func:`_voxel_probe`).
    With ``coarse`` the cell shifted right by one, which is the cell in the grid of edge
    2 ``size`` (the grids nest: doubling the edge scales exactly), goes in a second table.
    Returns (V, V2, voxel (N,) int32): the occupied voxels, those of the coarse grid (-1
    without ``coarse``) and, with ``assign``, each point's voxel numbered in order of first
    appearance (else empty). Compiled by numba (:func:`_voxel_kernels`); the same
    counts and voxels as the sorts of :func:`_count_voxels` and :func:`_voxel_grid`.
    """
    n = cols.shape[1]
    bits = 1
    while (1 << bits) < 2 * n:
        bits += 1
    keys = np.full(1 << bits, -1, np.int64)
    keys2 = np.full(1 << bits if coarse else 0, -1, np.int64)
    slot_voxel = np.empty(1 << bits if assign else 0, np.int32)
    voxel = np.empty(n if assign else 0, np.int32)
    dim2 = ((cells - 1) >> 1) + 1
    v = v2 = 0
    for i in range(n):
        c0 = np.int64((cols[0, i] - origin[0]) / size)
        c1 = np.int64((cols[1, i] - origin[1]) / size)
        c2 = np.int64((cols[2, i] - origin[2]) / size)
        code = (c0 * cells + c1) * cells + c2
        s = _voxel_probe(keys, code, bits)
        if keys[s] == -1:
            keys[s] = code
            if assign:
                slot_voxel[s] = v
            v += 1
        if assign:
            voxel[i] = slot_voxel[s]
        if coarse:
            code = ((c0 >> 1) * dim2 + (c1 >> 1)) * dim2 + (c2 >> 1)
            s = _voxel_probe(keys2, code, bits)
            if keys2[s] == -1:
                keys2[s] = code
                v2 += 1
    return v, v2 if coarse else -1, voxel


def _voxel_nearest(cols, voxel, v):
    """(reps (V,), counts (V,)): each voxel's point nearest its centroid (ties: lowest index), and its population.

    Populations, centroids (summed in index order), then distances, each a pass over the
    points into arrays of V. Compiled by numba (:func:`_voxel_kernels`).
    """
    n = cols.shape[1]
    counts = np.zeros(v, np.int64)
    centre = np.zeros((v, 3))
    for i in range(n):
        counts[voxel[i]] += 1
        for k in range(3):
            centre[voxel[i], k] += cols[k, i]
    for g in range(v):
        for k in range(3):
            centre[g, k] /= counts[g]
    best = np.full(v, np.inf)
    reps = np.zeros(v, np.int64)
    for i in range(n):
        g = voxel[i]
        dist = 0.0
        for k in range(3):
            d = cols[k, i] - centre[g, k]
            dist += d * d
        if dist < best[g]:
            best[g] = dist
            reps[g] = i
    return reps, counts


@functools.cache
def _voxel_kernels():
    """(:func:`_voxel_table`, :func:`_voxel_nearest`) compiled by numba (the ``voxel`` extra), or None."""
    if importlib.util.find_spec("numba") is None:
        return None
    import numba

    jit = numba.njit(cache=True, nogil=True)
    scope = {**globals(), "_voxel_probe": numba.njit(inline="always")(_voxel_probe)}  # compiled callee
    return jit(types.FunctionType(_voxel_table.__code__, scope)), jit(_voxel_nearest)


def _axis_bounds(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) minima and maxima of (3, N) ``cols``, one axis at a time (fast on a transposed view)."""
    return np.array([c.min() for c in cols]), np.array([c.max() for c in cols])


def _count_voxels(cols: np.ndarray, origin: np.ndarray, extent: float, size: float,
                  coarse: bool = False) -> tuple[int, int]:
    """(V, V2): occupied voxels of edge ``size`` and, with ``coarse``, of edge 2 ``size`` (else -1).

    One table pass (:func:`_voxel_table`), or one sort of the voxel codes per grid.
    """
    kernels = _voxel_kernels()
    if kernels is not None:
        v, v2, _ = kernels[0](cols, origin, float(size), int(extent / size) + 1, False, coarse)
        return int(v), int(v2)
    cell = _voxel_cells(cols, origin, size)
    return np.unique(_pack(cell)).size, np.unique(_pack(cell >> 1)).size if coarse else -1


def _pack(cell: np.ndarray) -> np.ndarray:
    """(N,) int64 code of each (3, N) cell, distinct for distinct cells."""
    dims = cell.max(axis=1) + 1  # at most VOXEL_LEVELS + 1 each, so the code fits in int64
    return (cell[0] * dims[1] + cell[1]) * dims[2] + cell[2]


def _voxel_grid(cols: np.ndarray, origin: np.ndarray, extent: float, size: float) -> tuple[np.ndarray, int]:
    """(voxel (N,), V): each point's voxel of edge ``size``, numbered 0..V-1 (one table pass, or one sort)."""
    kernels = _voxel_kernels()
    if kernels is not None:
        v, _, voxel = kernels[0](cols, origin, float(size), int(extent / size) + 1, True, False)
        return voxel, int(v)
    codes, voxel = np.unique(_pack(_voxel_cells(cols, origin, size)), return_inverse=True)
    return voxel, codes.size


def _voxel_representatives(cols: np.ndarray, voxel: np.ndarray, v: int) -> tuple[np.ndarray, np.ndarray]:
    """(reps (V,), counts (V,)): each voxel's point nearest its centroid (ties: lowest index), and its population.

    ``cols`` (3, N) are the points minus the grid's origin, so that the centroid sums neither
    overflow nor lose the cloud's offset (a cloud near the largest float64 along an axis).
    """
    kernels = _voxel_kernels()
    if kernels is not None:
        return kernels[1](cols, voxel, v)
    counts = np.bincount(voxel, minlength=v)
    dist = np.zeros(cols.shape[1])
    for c in cols:  # bincount adds in index order, as the compiled loop does
        d = c - (np.bincount(voxel, c, minlength=v) / counts)[voxel]
        dist += d * d
    order = np.lexsort((dist, voxel))  # stable: equal distances keep index order
    return order[np.cumsum(counts) - counts], counts


def _next_size(tried: dict[float, int], aim: float, n: int, finest: float, coarsest: float, slope: float) -> float:
    """Edge expected to give ``aim`` voxels, from counted (edge: count) pairs.

    The model: 1/count - 1/N ~ h^slope (count ~ h^-slope on coarse grids, saturating at N
    points on fine ones). Interpolates it, in logs, between the counted edges bracketing
    ``aim``, or extrapolates from the two nearest (with ``slope`` if only one was counted).
    """
    y = {x: np.log(max(1 / c - 1 / n, 1e-300)) for x, c in tried.items()}
    target = np.log(max(1 / aim - 1 / n, 1e-300))
    h = sorted(tried)  # counts fall, y grows, as h grows
    above = [x for x in h if tried[x] >= aim]
    a = above[-1] if above else h[0]
    b = next((x for x in h if x > a), None) if above else (h[1] if len(h) > 1 else None)
    if b is None and len(h) > 1:
        a, b = h[-2], h[-1]
    if b is not None and y[a] != y[b]:
        slope = float(np.clip((y[b] - y[a]) / np.log(b / a), 0.5, 4.0))
    near = min((a, b) if b is not None else (a,), key=lambda x: abs(y[x] - target))
    return float(np.clip(near * np.exp((target - y[near]) / slope), finest, coarsest))


def _voxel_search(cols: np.ndarray, origin: np.ndarray, extent: float, m: int) -> tuple[float, np.ndarray, int]:
    """(h, voxel (N,), V): a voxel edge whose grid has at least ``m`` occupied voxels, not many more.

    Occupied-voxel counts follow count ~ h^-D on coarse grids (D about 2 on surfaces) and
    saturate at N points on fine ones (:func:`_next_size`). A strided subsample of about
    VOXEL_PROBE_POINTS points is counted at extent / 2^k, k = 0, 1, ..., while it still has
    at least 8 points per voxel and fewer than ``m`` voxels; the last two counts give D and
    a first guess g of h. One pass over the full cloud then counts the nested grids g and
    2g: a subsample misses the sparse voxels of a real scan, so g tends to be fine and the
    two bracket the target. Up to VOXEL_ASSIGN_PASSES passes then assign the points to the
    voxels of the edge interpolated from all counts so far, aiming at m (1 + VOXEL_SLACK / 2)
    and stopping once a grid has m to m (1 + VOXEL_SLACK) voxels. The assigned grid with the
    fewest voxels, at least ``m``, is returned; if none has ``m``, one more pass assigns the
    coarsest counted edge that has, or failing that the next guess.
    """
    finest, coarsest = extent / VOXEL_LEVELS, 2 * extent
    sub = np.ascontiguousarray(cols[:, :: max(1, cols.shape[1] // VOXEL_PROBE_POINTS)])
    h, count = coarsest, 1
    while True:
        finer = _count_voxels(sub, origin, extent, h / 2)[0]
        if 8 * finer > sub.shape[1] or finer >= m or h / 2 < finest:
            break
        h, count = h / 2, finer
    slope = float(np.clip(np.log2(max(finer, 1) / count), 1.0, 3.0))
    aim = m * (1 + VOXEL_SLACK / 2)
    guess = max(h * (count / aim) ** (1 / slope), finest)
    tried = dict(zip((guess, 2 * guess), _count_voxels(cols, origin, extent, guess, coarse=True)))
    best = None
    for _ in range(VOXEL_ASSIGN_PASSES):
        guess = _next_size(tried, aim, cols.shape[1], finest, coarsest, slope)
        voxel, v = _voxel_grid(cols, origin, extent, guess)
        tried[guess] = v
        if v >= m and (best is None or v < best[2]):
            best = guess, voxel, v
        if m <= v <= m * (1 + VOXEL_SLACK):
            break
    if best is None:
        enough = [x for x, c in tried.items() if c >= m]
        guess = max(enough) if enough else _next_size(tried, aim, cols.shape[1], finest, coarsest, slope)
        best = guess, *_voxel_grid(cols, origin, extent, guess)
    return best


def voxel_sample(points, ratio: float | None = None, *, voxel_size: float | None = None) -> np.ndarray:
    """One point per occupied voxel: Open3D's ``voxel_down_sample`` as indices.

    The grid has its origin at the cloud's minimum corner. Each occupied voxel is
    represented by its point nearest the centroid of the voxel's points (the point closest
    to what ``voxel_down_sample`` outputs; ties: lowest index). Representatives are ranked
    by voxel population, largest first (ties: lowest index).

    With ``voxel_size`` the grid is given: one pass assigns the points to voxels by a hash
    table of voxel codes compiled by numba (the ``voxel`` extra), else by a sort of N voxel
    codes (the same voxels and representatives), and one finds the representatives. With
    ``ratio`` alone the edge is searched for (:func:`_voxel_search`) so that the grid has at
    least M = ceil(ratio N) voxels: a subsample, one pass counting two nested grids, then
    usually one assigning pass, whose voxels are kept. The count is then made exact: the
    first M ranked representatives are returned, which drops the least populated voxels when
    the grid has more than M; when it has fewer (a cloud with many duplicate points, or a
    ``voxel_size`` too coarse), the remaining points follow in index order. ``ratio`` and
    ``voxel_size`` together give exactly M points from the given grid.

    Args:
      points: (N, 3) float32 or float64; never modified.
      ratio: fraction to keep, in (0, 1]; None (only with ``voxel_size``) keeps one point
        per occupied voxel.
      voxel_size: voxel edge, in the points' units, > 0 and at least the cloud's largest
        extent / 2^20; None (default) searches for it from ``ratio``.

    Returns:
      (M,) int64 unique indices, highest priority first: M = ceil(ratio N) when ``ratio``
      is given, else the number of occupied voxels.

    Raises:
      TypeError, ValueError: invalid points, ratio or voxel_size, or neither of the last two.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.array([[0., 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5, 0, 0], [5.1, 0, 0]])
      >>> hgjax.voxel_sample(pts, voxel_size=1.0).tolist()  # the fuller voxel first
      [1, 3]
      >>> len(hgjax.voxel_sample(pts, 0.4))
      2
    """
    pts = _validate.check_points(points)
    n = pts.shape[0]
    if ratio is None and voxel_size is None:
        raise ValueError("voxel_sample needs ratio or voxel_size; got neither")
    m = None if ratio is None else _validate.n_keep(n, _validate.check_ratio(ratio))
    grid = voxel_grid(pts, m, voxel_size)
    cols = np.asarray(pts, dtype=np.float64).T
    voxel, v = (grid.voxel, grid.count) if grid.voxel is not None else _voxel_grid(cols, grid.origin, grid.extent,
                                                                                      grid.size)
    reps, counts = _voxel_representatives((np.asarray(pts, dtype=np.float64) - grid.origin).T, voxel, v)
    ranked = reps[np.argsort((counts.max() - counts) * (n + 1) + reps)]  # population desc, then index (one key)
    if m is None or m <= ranked.size:
        return ranked[:m].astype(np.int64)
    return np.concatenate([ranked, np.setdiff1d(np.arange(n), reps)])[:m].astype(np.int64)


@dataclasses.dataclass(frozen=True)
class VoxelGrid:
    """The voxel grid of a cloud: edge ``size`` from ``origin`` (its minimum corner), and its extent.

    ``voxel`` (N,) and ``count`` hold the search's assignment of the whole cloud when it made one.
    """

    origin: np.ndarray
    extent: float
    size: float
    voxel: np.ndarray | None = None
    count: int = 0


def voxel_grid(pts: np.ndarray, m: int | None, voxel_size) -> VoxelGrid:
    """The grid :func:`voxel_sample` uses: ``voxel_size`` (checked), or the count-targeted search for m voxels."""
    cols = np.asarray(pts, dtype=np.float64).T  # (3, N): the compiled passes read the caller's rows in place
    origin, top = _axis_bounds(cols)
    extent = _validate.check_extent(origin, top, np.float64) or 1.0  # squared distances in float64 on the host
    if voxel_size is None:
        size, voxel, v = _voxel_search(cols, origin, extent, m)
        return VoxelGrid(origin, extent, size, voxel, v)
    size = _validate.check_positive(voxel_size, "voxel_size")
    if extent / size > VOXEL_LEVELS:
        raise ValueError(f"voxel_size must be at least the cloud's extent / 2**20 = {extent / VOXEL_LEVELS:.3g}"
                         f" (at most 2**20 voxels along an axis); got {voxel_size!r}")
    return VoxelGrid(origin, extent, size)


def voxel_tile(cols: np.ndarray, grid: VoxelGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voxels of the points ``cols`` (3, n) (ascending global ids) in ``grid``.

    Returns:
      (reps, counts, first): per voxel, its point nearest the centroid, its population and
      its first (lowest-id) point, as indices into the n points.
    """
    voxel, v = _voxel_grid(cols, grid.origin, grid.extent, grid.size)
    reps, counts = _voxel_representatives((cols.T - grid.origin).T, voxel, v)
    order = np.argsort(voxel, kind="stable")
    return reps, counts, order[np.cumsum(counts) - counts]


@functools.partial(jax.jit, static_argnums=(1,))
def _fps(points, m: int, start):
    n = points.shape[0]

    def step(i, state):
        min_d, chosen, last = state
        d = jnp.sum((points - points[last][None, :]) ** 2, axis=1)
        min_d = jnp.minimum(min_d, d).at[last].set(-1)  # chosen points never win again
        nxt = jnp.argmax(min_d).astype(jnp.int32)
        return min_d, chosen.at[i].set(nxt), nxt

    min_d = jnp.full((n,), jnp.inf, dtype=points.dtype)
    chosen = jnp.zeros((m,), jnp.int32).at[0].set(start)
    _, chosen, _ = jax.lax.fori_loop(1, m, step, (min_d, chosen, start))
    return chosen


def _kd_row(q: np.ndarray, target: int) -> int:
    """The row of (U, 3) float32 points ``q`` where fpsample's QuickFPS tree build leaves row ``target``.

    fpsample 1.0 builds its kd-tree by partitioning the points in place: each node splits
    its widest axis (the first on ties) at the float32 mean of the node's points, summed
    left to right in their current order, by a Hoare scan (the i-th point at or above the
    mean among the node's first ``k`` rows trades places with the i-th point below it
    counted from the node's end, ``k`` the count below), down to single points.
    ``start_idx`` then reads a row of that partitioned array. Only the nodes that hold
    ``target`` are replayed: about 2 U points in all, the first node read in place, and
    ``target``'s place followed through the trades rather than searched for.
    """
    axes = np.ascontiguousarray(q.T)
    node, at, offset = np.arange(q.shape[0]), int(target), 0  # node[at] == target
    x = axes  # (3, S): the node's points in their current order
    while node.size > 1:
        v = x[int(np.argmax(x.max(axis=1) - x.min(axis=1)))]
        right = v >= np.cumsum(v)[-1] / np.float32(node.size)  # cumsum: the sequential float32 sum
        below = node.size - int(np.count_nonzero(right))
        up = np.flatnonzero(right[:below])  # ascending
        down = below + np.flatnonzero(~right[below:])  # ascending; the i-th of up trades with the i-th from the end
        if at < below and right[at]:
            at = int(down[down.size - 1 - np.searchsorted(up, at)])
        elif at >= below and not right[at]:
            at = int(up[up.size - 1 - np.searchsorted(down, at)])
        node[up], node[down[::-1]] = node[down[::-1]], node[up]
        n_left = min(max(below, 1), node.size - 1)
        if at < n_left:
            node = node[:n_left]
        else:
            node, offset, at = node[n_left:], offset + n_left, at - n_left
        x = axes[:, node]
    return offset


def _distinct_rows(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(q, axis=0, return_index=True, return_inverse=True)[1:]`` of (N, 3) float32 ``q``.

    The same rows in the same (lexicographic) order, -0.0 equal to 0.0: (x, y) packed into
    order-preserving uint64 keys, sorted, then z and the index inside the (rare) runs of equal
    (x, y) (:func:`hgjax.neighbours.spatial.lex_order`).
    """
    bits = ascending_bits(q).astype(np.uint64)
    xy = bits[:, 0] << np.uint64(32) | bits[:, 1]
    order = spatial.lex_order(xy, bits[:, 2])
    xy, z = xy[order], bits[order, 2]  # in sorted order: one gather each
    new = np.ones(order.size, dtype=bool)
    new[1:] = (xy[1:] != xy[:-1]) | (z[1:] != z[:-1])
    group = np.empty(order.size, dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    return order[new], group


def _first_repeat(picked: np.ndarray) -> int:
    """The position of the first entry of ``picked`` (K,) equal to an earlier one, or K if none."""
    order = np.argsort(picked, kind="stable")
    later = order[1:][picked[order[1:]] == picked[order[:-1]]]  # every copy after the first of its value
    return int(later.min(initial=picked.size))


def _fps_fpsample(p: np.ndarray, m: int, start: int) -> np.ndarray | None:
    """Exact FPS by fpsample's bucket kd-tree (QuickFPS) on the distinct float32 points.

    Duplicates are resolved first: each distinct position is represented by its lowest
    index (``start`` for its own), in index order (without duplicates, fpsample sees the
    points as given), and once all M' <= M distinct positions are taken the other points
    follow in index order, as on the JAX path. ``start_idx`` is the row that the tree build
    moves ``start`` to (``_kd_row``). Should the start not come back first (a future
    fpsample building differently), fpsample's plain O(N M) FPS, which takes ``start_idx``
    as given, serves instead. Once every distinct point left is at float32 squared distance
    0 from the kept ones (a far outlier shrinks the rest below float32's range of squares),
    fpsample repeats a point; and where the float32 cast makes distinct points of ``p`` one,
    their order would be the tree's: None is returned in both cases, and the caller runs the
    JAX loop.
    """
    import fpsample

    q = np.ascontiguousarray(p, dtype=np.float32)
    first, group = _distinct_rows(q)
    unique = first.size == q.shape[0]
    if not unique and (p != p[first[group]]).any():  # distinct points made one by float32: the exact JAX loop instead
        return None
    rep = np.arange(q.shape[0]) if unique else np.sort(first)
    at = int(np.searchsorted(rep, first[group[start]]))
    rep[at] = start
    k = min(m, rep.size)
    distinct = q if unique else q[rep]
    picked = fpsample.bucket_fps_kdtree_sampling(distinct, k, start_idx=_kd_row(distinct, at)).astype(np.int64)
    if picked[0] != at:
        picked = fpsample.fps_sampling(distinct, k, start_idx=at).astype(np.int64)
    if _first_repeat(picked) < k:  # float32 squares underflowed: the exact JAX loop instead
        return None
    chosen = rep[picked]
    if m == k:
        return chosen
    return np.concatenate([chosen, np.setdiff1d(np.arange(q.shape[0]), rep)])[:m]


def fps_backend(backend: str) -> str:
    """The FPS implementation ``backend`` resolves to: ``"fpsample"`` or ``"jax"``.

    ``"auto"`` is fpsample on JAX's CPU backend when the package is installed (the ``fps``
    extra), else the jitted JAX loop (accelerators, or no fpsample).

    Args:
      backend: ``"auto"``, ``"fpsample"`` or ``"jax"``.

    Returns:
      ``"fpsample"`` or ``"jax"``.

    Raises:
      ValueError: unknown backend.
      ImportError: ``"fpsample"`` asked for but not installed.

    Examples:
      >>> import hgjax
      >>> hgjax.fps_backend("jax")
      'jax'
    """
    backend = _validate.check_choice(backend, "backend", FPS_BACKENDS)
    installed = importlib.util.find_spec("fpsample") is not None
    if backend == "fpsample" and not installed:
        raise ImportError(f"backend='fpsample' needs the fpsample package: {_validate.install_hint('fps')}")
    if backend == "auto":
        return "fpsample" if installed and jax.default_backend() == "cpu" else "jax"
    return backend


def farthest_point_sample(points, ratio: float, *, start: int = 0, backend: str = "auto") -> np.ndarray:
    """Farthest point sampling: each new point maximises its distance to those already kept.

    Two exact implementations of the same order (the index sequence agrees wherever no two
    candidates are at equal distance):

    * ``"fpsample"``: the bucket kd-tree FPS (QuickFPS, ``fpsample.bucket_fps_kdtree_sampling``;
      exact, unlike fpsample's NPDU variants) on the distinct points, in float32 whatever
      the input dtype. Far faster than O(N M) on the host; ties between distinct points are
      broken by the tree, deterministically. Where float32 squared distances underflow (a
      far outlier shrinks the other points' spacing below them, x64 on), or the float32 cast
      makes distinct points one, the JAX loop runs.
    * ``"jax"``: a jitted ``lax.fori_loop`` over one (N,) array of squared distances to the
      kept set, in the working dtype (float64 for float64 input with x64): O(N M) time,
      O(N) memory, and M is static (a new M compiles). Ties go to the lowest index.

    ``backend="auto"`` (default) picks fpsample on JAX's CPU backend when it is installed,
    else JAX (see :func:`fps_backend`). On both, a set of coincident points is entered by
    its lowest index, and once only duplicates of kept points remain (distance 0) they are
    taken in index order, so no point is picked twice.

    Args:
      points: (N, 3) float32 or float64; never modified.
      ratio: fraction to keep, in (0, 1].
      start: index of the first kept point (default 0, deterministic).
      backend: ``"auto"``, ``"fpsample"`` or ``"jax"``.

    Returns:
      (M,) int64 unique indices in selection order, M = ceil(ratio N).

    Raises:
      TypeError, ValueError: invalid points, ratio, start or backend.
      ImportError: ``backend="fpsample"`` without fpsample installed.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.array([[0., 0, 0], [1, 0, 0], [4, 0, 0], [2, 0, 0]])
      >>> hgjax.farthest_point_sample(pts, 0.75).tolist()
      [0, 2, 3]
    """
    pts = _validate.check_points(points)
    n = pts.shape[0]
    m = _validate.n_keep(n, _validate.check_ratio(ratio))
    start = _validate.check_int(start, "start", minimum=0)
    if start >= n:
        raise ValueError(f"start must be < N = {n}; got {start}")
    local = spatial.local_frame(pts)[0]  # float64 origin removed before any float32 cast; a new array
    extent = max(local.max(), -local.min())  # max |local| without an (N, 3) temporary
    if extent > 0:  # an exact power of two: squared distances neither under- nor overflow
        np.ldexp(local, -np.frexp(extent)[1], out=local)
    chosen = _fps_fpsample(local, m, start) if fps_backend(backend) == "fpsample" else None
    if chosen is not None:  # None: fpsample's float32 squares underflowed, the JAX loop serves
        return chosen
    dtype = spatial.working_dtype(pts.dtype, extent=spatial.frame_extent(local),  # judged in the scaled frame
                                  spacing=lambda: spatial.index_spacing(spatial.SpatialIndex(local)))
    p = jnp.asarray(local, dtype=dtype)
    return np.asarray(_fps(p, m, jnp.int32(start))).astype(np.int64)


def _fps_untiled(params: dict) -> tuple[str, str]:
    return "", "each farthest-point pick needs the farthest point of the whole cloud, so FPS cannot be cut into tiles"


def _voxel_plan(pts: np.ndarray, m: int | None, *, voxel_size=None) -> VoxelGrid:
    """``voxel`` in tiles: :func:`hgjax.voxel_sample`'s grid, searched once on the whole cloud (or given).

    Each tile assigns its core points and a halo of one voxel edge, so every voxel with a core
    point is whole (:func:`_voxel_part`); the global ranking is by (population, id), exactly as
    in one process.
    """
    if m is None and voxel_size is None:
        raise ValueError("voxel_sample needs ratio or voxel_size; got neither")
    return dataclasses.replace(voxel_grid(pts, m, voxel_size), voxel=None)


def _voxel_halo(grid: VoxelGrid) -> float:
    return 1.01 * grid.size


def _voxel_part(points: np.ndarray, core: np.ndarray, grid: VoxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """(populations, rows) of the voxels a tile owns, each by its representative: a voxel belongs to
    the tile that owns its lowest-id point, which gives its representative (the point nearest the
    centroid, summed in id order) and population."""
    rep, counts, first = voxel_tile(points.T, grid)
    owned = core[first]
    return counts[owned].astype(np.float64), rep[owned]


SAMPLERS = (
    _method.Sampler("uniform", needs_key=True, summary="uniformly random subset (needs key)",
                      citation="random down-sampling", sample=uniform_sample, ids=uniform_ids),
    _method.Sampler("voxel", needs_key=False, summary="one point per voxel of a grid sized to reach the count",
                      citation="voxel-grid down-sampling", sample=voxel_sample,
                      tiles=_method.SampleTiles(plan=_voxel_plan, halo=_voxel_halo, part=_voxel_part)),
    _method.Sampler("fps", needs_key=False, summary="farthest point sampling from point 0",
                      citation="Eldar, Lindenbaum, Porat, Zeevi, IEEE TIP 6(9), 1997", sample=farthest_point_sample, untiled=_fps_untiled),
)
