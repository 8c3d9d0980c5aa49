"""PCA and agglomerative clustering (PCA-AC) baseline: Bazazian, Casas, Ruiz-Hidalgo, "Fast and
robust edge extraction in unorganized point clouds", DICTA 2015.

Every point gets the PCA surface variation c = l0 / (l0 + l1 + l2) of its k-neighbourhood
(as :mod:`hgjax.scores.ea`); the values are then grouped by agglomerative clustering with
Ward's linkage, and the clusters are numbered by increasing mean variation. The TIP 2022
paper keeps "the points with higher cluster numbers or larger surface variation" to reach
the resampling ratio: whole clusters from the highest number down, then, inside the last
cluster, the largest variation first (ties by index).

Why this is exact and scales to 1e6 points: on one-dimensional data, Ward's nearest pair of
clusters is always a pair of clusters adjacent in sorted order, so every cluster is an
interval of the sorted values and the whole dendrogram is a sequence of merges of adjacent
intervals, each labelling the boundary between them with its merge cost
n_a n_b / (n_a + n_b) (m_a - m_b)^2. Ward's linkage is reducible, so merging all reciprocal
nearest pairs (local minima of the adjacent costs) round after round, then finishing with a
heap, builds the same dendrogram as the textbook greedy algorithm in O(N log N) instead of
O(N^2) time and memory; it has no inversions, so cutting it into ``n_clusters`` clusters
removes the ``n_clusters - 1`` boundaries of highest cost. The tests check the partition
against ``scipy.cluster.hierarchy.linkage(method="ward")``.

Runs of equal values (98 % of a box surface's variations are exactly 0) merge at cost 0
before any other merge touches them, left to right (each step the leftmost zero-cost
pair): a run of ``_RUN_MIN`` or more values enters as one cluster whose total is that
left-to-right sum, so its sizes, totals and every later cost keep the same bits, without
one round or heap step per value.

A consequence worth knowing: because the clusters are intervals of the variation, the kept
indices equal EA's (the largest variations, ties by index), in the same order; the clustering
adds the cluster numbers, not a different ranking. :func:`hgjax.resample` scores both through
the same one-tile engine; only PCA-AC's selection needs every score at once, so it refuses tiles.
"""

from __future__ import annotations

import heapq

import numpy as np

from hgjax import _method, _validate
from hgjax.engine import select
from hgjax.neighbours import nearest
from hgjax.scores import ea

__all__ = ["DEFAULT_N_CLUSTERS", "keep", "ward_1d"]

DEFAULT_N_CLUSTERS = 2  # sharp versus smooth, the two classes of edge detection
_ROUND_MIN_SHARE = 64  # finish with the heap once a round merges fewer than 1/64 of clusters
_RUN_MIN = 64  # runs of at least this many equal values enter as one cluster


def _merge_rounds(size, total, end, heights):
    """Merge reciprocal-nearest adjacent pairs in vectorised rounds; return what is left."""
    while size.size > 1:
        gap = np.diff(total / size)
        joined = size[:-1] + size[1:]
        cost = size[:-1] * size[1:]
        cost /= joined
        cost *= gap * gap
        rising = cost[1:] < cost[:-1]
        merge = np.ones(cost.size, dtype=bool)  # cost[a] < cost[a - 1] and cost[a] <= cost[a + 1]
        merge[1:] = rising
        merge[:-1] &= ~rising
        at = np.flatnonzero(merge)
        if at.size * _ROUND_MIN_SHARE < size.size:
            break
        heights[end[at]] = cost[at]
        size[at] = joined[at]
        total[at] += total[at + 1]
        end[at] = end[at + 1]
        keep = np.ones(size.size, dtype=bool)
        keep[at + 1] = False
        size, total, end = size[keep], total[keep], end[keep]
    return size, total, end


def _merge_heap(size, total, end, heights):
    """Greedy Ward merging of adjacent clusters with a heap (lazy deletion)."""
    m = size.size
    size, total, end = size.tolist(), total.tolist(), end.tolist()
    right = list(range(1, m + 1))
    left = list(range(-1, m - 1))
    version = [0] * m

    def cost(a, b):
        return size[a] * size[b] / (size[a] + size[b]) * (total[b] / size[b] - total[a] / size[a]) ** 2

    heap = [(cost(a, a + 1), a, a + 1, 0, 0) for a in range(m - 1)]
    heapq.heapify(heap)
    while heap:
        c, a, b, va, vb = heapq.heappop(heap)
        if version[a] != va or version[b] != vb or right[a] != b:
            continue  # stale: a or b changed since this entry was pushed
        heights[end[a]] = c
        size[a] += size[b]
        total[a] += total[b]
        end[a] = end[b]
        version[a] += 1
        version[b] = -1
        right[a] = right[b]
        if right[a] < m:
            left[right[a]] = a
            heapq.heappush(heap, (cost(a, right[a]), a, right[a], version[a], version[right[a]]))
        if left[a] >= 0:
            heapq.heappush(heap, (cost(left[a], a), left[a], a, version[left[a]], version[a]))


def _equal_runs(x):
    """(size, total, end) of the initial clusters of sorted ``x``: one per value, runs of at
    least ``_RUN_MIN`` equal values merged (at cost 0) into one, summed left to right."""
    n = x.size
    new = np.ones(n, dtype=bool)
    new[1:] = x[1:] != x[:-1]
    starts = np.flatnonzero(new)
    lengths = np.diff(np.append(starts, n))
    long = lengths >= _RUN_MIN
    heads = np.flatnonzero(new | ~np.repeat(long, lengths))
    size = np.diff(np.append(heads, n))
    total = x[heads]
    at = np.searchsorted(heads, starts[long])
    for a, s, length in zip(at, starts[long], lengths[long]):
        total[a] = np.cumsum(x[s:s + length])[-1]  # the sequential sum of the cost-0 merges
    return size.astype(np.float64), total, heads + size - 1


def _check_n_clusters(n_clusters, n: int) -> int:
    """``n_clusters`` after checking it is an integer in [1, N] for ``n`` = N values (the default,
    DEFAULT_N_CLUSTERS, is also taken for fewer values); it is capped at N where it is used."""
    k = _validate.check_int(n_clusters, "n_clusters", minimum=1)
    if k > max(n, DEFAULT_N_CLUSTERS):
        raise ValueError(f"n_clusters must be in [1, N] = [1, {n}] for N = {n} points; got {k}")
    return k


def _checked(values, n_clusters) -> tuple[np.ndarray, int]:
    """(values as float64 (N,), n_clusters capped at N), or ValueError / TypeError naming the bad one."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or v.size == 0 or np.isnan(v).any():
        raise ValueError(f"values must be a non-empty array of shape (N,) without NaN; got shape {v.shape}"
                         f"{' holding NaN' if v.ndim == 1 and v.size else ''}")
    return v, min(_check_n_clusters(n_clusters, v.size), v.size)


def _ward_sorted(v: np.ndarray, n_clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, labels): the stable ascending order (N,) of ``v`` and the cluster number (N,) of each
    sorted value (non-decreasing: every cluster is an interval of the sorted values).

    Infinite values merge with their equals at cost 0 and with anything else at an infinite
    cost: the boundaries of the -inf and +inf runs are cut first, the finite values clustered
    between them."""
    order = np.argsort(v, kind="stable")
    ascending = v[order]
    lo, hi = np.searchsorted(ascending, -np.inf, "right"), np.searchsorted(ascending, np.inf, "left")
    heights = np.zeros(max(v.size - 1, 0))  # heights[j]: cost of the merge across j | j + 1
    if hi - lo > 1:  # the finite values ascending[lo:hi]; a view writes their heights in place
        rest = _merge_rounds(*_equal_runs(ascending[lo:hi]), heights[lo:hi - 1])
        _merge_heap(*rest, heights[lo:hi - 1])
    heights[[j for j in {lo - 1, hi - 1} if 0 <= j < heights.size]] = np.inf
    cut = np.zeros(heights.size, dtype=np.int64)
    if n_clusters > 1:
        cut[select.top_k(heights, n_clusters - 1)] = 1
    return order, np.concatenate([[0], np.cumsum(cut)])


def ward_1d(values, n_clusters: int) -> np.ndarray:
    """Ward agglomerative clustering of one-dimensional values, O(N log N).

    Args:
      values: (N,) floats without NaN; -inf and +inf values form clusters of their own
        (cut first: their merge cost with any finite value is infinite).
      n_clusters: number of clusters, in [1, N] (the default 2 also for N = 1, capped at N).

    Returns:
      (N,) int64 cluster numbers 0 .. n_clusters - 1, increasing with the cluster's values
      (each cluster is an interval of the sorted values). Among equal merge costs the
      leftmost boundary is cut first.

    Raises:
      ValueError, TypeError: bad values or n_clusters.

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores.pca_ac import ward_1d
      >>> ward_1d(np.array([0.0, 5.0, 0.1, 5.2, 9.0]), 3).tolist()
      [0, 1, 0, 1, 2]
    """
    order, sorted_labels = _ward_sorted(*_checked(values, n_clusters))
    labels = np.empty(order.size, dtype=np.int64)
    labels[order] = sorted_labels
    return labels


def keep(variation, m: int, *, n_clusters: int = DEFAULT_N_CLUSTERS) -> np.ndarray:
    """PCA-AC selection: the m points of the sharpest Ward clusters of the surface variation.

    Args:
      variation: (N,) surface variation (:func:`hgjax.scores.ea.score`), without NaN; +inf
        (-inf) values, as every method's :func:`hgjax.keep` takes them, are kept first (last).
      m: number of points to keep, 1 <= m <= N.
      n_clusters: number of Ward clusters, in [1, N] (default 2: sharp and smooth; capped at N).

    Returns:
      (m,) int64 indices: the highest cluster numbers first, then the largest variation,
      then the lowest index.

    Raises:
      TypeError, ValueError: bad variation, m or n_clusters.

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.scores.pca_ac.keep(np.array([0.0, 0.3, 0.01, 0.29]), 1).tolist()
      [1]
    """
    m = _validate.check_int(m, "m", minimum=1)
    v, n_clusters = _checked(variation, n_clusters)
    order, labels = _ward_sorted(v, n_clusters)
    # Blocks of equal (cluster number, variation) are contiguous in the ascending order, each in
    # index order: the blocks from the last to the first, each kept in index order, are the
    # points by highest cluster number, then largest variation, then lowest index.
    ascending = v[order]
    new = np.ones(v.size, dtype=bool)
    new[1:] = (labels[1:] != labels[:-1]) | (ascending[1:] != ascending[:-1])
    block = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], v.size) - 1
    at = np.arange(v.size)
    out = np.empty(v.size, dtype=np.int64)
    out[(v.size - 1 - ends[block]) + (at - starts[block])] = order
    return out[:m]


def _select(scores, m: int, *, key=None, n_clusters: int = DEFAULT_N_CLUSTERS) -> np.ndarray:
    del key  # deterministic
    return keep(scores, m, n_clusters=n_clusters)


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of a run of ``n`` points scored as one tile: EA's.

    Raises:
      TypeError, ValueError: invalid parameters (``n_clusters`` included, before any work),
        or fewer than k points.
    """
    _check_n_clusters(params.get("n_clusters", DEFAULT_N_CLUSTERS), n)
    return ea.tile_params(n, params)


def _untiled(params: dict) -> tuple[str, str]:
    return "", "PCA-AC clusters the scores of the whole cloud at once (Ward), so its selection cannot be cut into tiles"


METHOD = _method.Method(
    "pca_ac", "knn", largest=True, needs_key=False,
    summary="PCA + agglomerative clustering baseline: Ward clusters of the surface variation, sharpest first",
    citation=_method.DICTA, build=ea.neighbourhoods, score=ea.score, soft_score=ea.soft_score,
    select=_select,
    tiling=_method.Tiling(params=tile_params, reach=nearest.reach, rows=nearest.tile_rows, kernel=ea.tile_kernel,
                          whole_selection=True, refused=_untiled),
    ranks_as=(ea.METHOD.name, "PCA-AC's Ward clusters are intervals of EA's surface variation, on the same neighbours"))
