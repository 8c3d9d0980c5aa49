"""Geometry-agnostic samplers people compare against: uniform random, voxel grid, farthest point.

They play the role of Open3D's ``random_down_sample``, ``voxel_down_sample`` and
``farthest_point_down_sample``, but like every hgjax method they return exactly
ceil(ratio N) unique int64 indices into the caller's points, highest priority first.
"""

from __future__ import annotations

import functools
import importlib.util

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate, spatial
from hgjax.select import weighted_sample

__all__ = ["farthest_point_sample", "fps_backend", "uniform_sample", "voxel_sample"]

VOXEL_LEVELS = 2**20  # the finest voxel grid has at most this many cells along each axis
VOXEL_PROBE_POINTS = 2**13  # points of the strided subsample that estimates the voxel size
VOXEL_COUNT_PASSES = 3  # full-cloud counting passes of the count-targeted voxel search
VOXEL_SLACK = 1 / 64  # a grid with M to M (1 + slack) voxels ends the search
FPS_BACKENDS = ("auto", "fpsample", "jax")
_GOLDEN = np.uint64(11400714819323198485)  # 2^64 / golden ratio: Fibonacci hashing keeps the top bits


def uniform_sample(points, ratio: float, *, key) -> np.ndarray:
    """A uniformly random subset of ceil(ratio N) points, without replacement.

    Args:
      points: (N, 3) float32 or float64 (only its size is used, after validation).
      ratio: fraction to keep, in (0, 1].
      key: ``jax.random`` key; the same key gives the same subset.

    Returns:
      (M,) int64 unique indices in draw order, M = ceil(ratio N).

    Raises:
      TypeError, ValueError: invalid points, ratio or key (a missing key is an error).

    Examples:
      >>> import jax, numpy as np, hgjax
      >>> idx = hgjax.uniform_sample(np.zeros((10, 3)), 0.3, key=jax.random.key(0))
      >>> len(set(idx.tolist()))
      3
    """
    pts = _validate.check_points(points)
    m = _validate.n_keep(pts.shape[0], _validate.check_ratio(ratio))
    return weighted_sample(_validate.check_key(key, "uniform"), np.ones(pts.shape[0]), m)


def _voxel_codes(cols: np.ndarray, origin: np.ndarray, size: float) -> np.ndarray:
    """(N,) int64 code of each point's voxel of edge ``size``; ``cols`` is the (3, N) cloud."""
    cell = ((cols - origin[:, None]) / size).astype(np.int64)  # >= 0, so truncation is floor
    dims = cell.max(axis=1) + 1  # at most VOXEL_LEVELS + 1 each, so the code fits in int64
    return (cell[0] * dims[1] + cell[1]) * dims[2] + cell[2]


def _voxel_table(cols, origin, size, cells, count_only):
    """Occupied voxels by an open-addressing table of voxel codes, in passes over the points.

    Each point's code (``cells`` per axis, at least the grid's largest index plus one; the
    codes differ from _voxel_codes' but name the same voxels) and its voxel from the table
    (2N slots, Fibonacci hashing, linear probing), then populations and centroids, then
    each voxel's point nearest its centroid (ties: lowest index). Per-voxel arrays are
    sized V, which keeps the memory touched small. Returns (reps (V,), counts (V,), V) in
    order of first appearance; with ``count_only``, just V (reps and counts empty).
    Compiled by numba (:func:`_voxel_kernel`); the same voxels, populations and
    representatives as the sort of :func:`_voxel_representatives`.
    """
    n = cols.shape[1]
    bits = 1
    while (1 << bits) < 2 * n:
        bits += 1
    mask = (1 << bits) - 1
    keys = np.full(1 << bits, -1, np.int64)
    slot_voxel = np.empty(1 << bits, np.int32)
    voxel = np.empty(0 if count_only else n, np.int32)
    v = 0
    for i in range(n):
        code = np.int64(0)
        for k in range(3):
            code = code * cells + np.int64((cols[k, i] - origin[k]) / size)
        s = np.int64((np.uint64(code) * _GOLDEN) >> np.uint64(64 - bits))
        while keys[s] != code and keys[s] != -1:
            s = (s + 1) & mask
        if keys[s] == -1:
            keys[s] = code
            slot_voxel[s] = v
            v += 1
        if not count_only:
            voxel[i] = slot_voxel[s]
    if count_only:
        return np.empty(0, np.int64), np.empty(0, np.int64), v
    counts = np.zeros(v, np.int64)
    for i in range(n):
        counts[voxel[i]] += 1
    centre = np.zeros((v, 3))
    for i in range(n):
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
    return reps, counts, v


@functools.cache
def _voxel_kernel():
    """:func:`_voxel_table` compiled by numba (the ``voxel`` extra), or None without numba."""
    if importlib.util.find_spec("numba") is None:
        return None
    import numba

    return numba.njit(cache=True, nogil=True)(_voxel_table)


def _axis_bounds(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) minima and maxima of (3, N) ``cols``, one axis at a time (fast on a transposed view)."""
    return np.array([c.min() for c in cols]), np.array([c.max() for c in cols])


def _count_voxels(cols: np.ndarray, origin: np.ndarray, extent: float, size: float) -> int:
    """Number of occupied voxels of edge ``size`` (one table pass, or one sort of the codes)."""
    kernel = _voxel_kernel()
    if kernel is not None:
        return int(kernel(cols, origin, float(size), int(extent / size) + 1, True)[2])
    code = np.sort(_voxel_codes(cols, origin, size))
    return int(np.count_nonzero(code[1:] != code[:-1])) + 1


def _voxel_representatives(cols: np.ndarray, origin: np.ndarray, extent: float,
                           size: float) -> tuple[np.ndarray, np.ndarray]:
    """(reps (V,), counts (V,)): each occupied voxel's point nearest its centroid, and its population.

    With numba, one table pass (:func:`_voxel_table`); else one argsort of the voxel codes.
    Ties in distance go to the lowest index; the voxels' order is left to the caller.
    """
    kernel = _voxel_kernel()
    if kernel is not None:
        return kernel(cols, origin, float(size), int(extent / size) + 1, False)[:2]
    n = cols.shape[1]
    code = _voxel_codes(cols, origin, size)
    order = np.argsort(code, kind="stable")  # each voxel in index order: sums as the table adds them
    code = code[order]
    starts = np.flatnonzero(np.concatenate([[True], code[1:] != code[:-1]]))
    counts = np.diff(np.append(starts, n))
    dist = np.zeros(n)
    for c in cols:  # row by row: contiguous gathers and reductions
        x = c[order]
        x -= np.repeat(np.add.reduceat(x, starts) / counts, counts)
        dist += x * x
    nearest = dist == np.repeat(np.minimum.reduceat(dist, starts), counts)
    return np.minimum.reduceat(np.where(nearest, order, n), starts), counts


def _voxel_size_for(cols: np.ndarray, origin: np.ndarray, extent: float, m: int) -> float:
    """A voxel edge whose grid has at least ``m`` occupied voxels, and not many more.

    Occupied-voxel counts follow count ~ h^-D (D about 2 on surfaces). A strided subsample
    of about VOXEL_PROBE_POINTS points is counted at extent / 2^k, k = 0, 1, ..., while it
    still has at least 8 points per voxel (so its count is close to the full cloud's) and
    fewer than ``m`` voxels; the last two counts give D and a first guess of h. At most
    VOXEL_COUNT_PASSES counts of the full cloud then refine h by secant steps on log count
    against log h, aiming at m (1 + VOXEL_SLACK / 2) and stopping once a count lies in
    [m, m (1 + VOXEL_SLACK)]. The largest counted h with at least ``m`` voxels is returned;
    if none reached ``m``, the next secant guess is.
    """
    finest, coarsest = extent / VOXEL_LEVELS, 2 * extent
    sub = cols[:, :: max(1, cols.shape[1] // VOXEL_PROBE_POINTS)]
    h, count = coarsest, 1
    while True:
        finer = _count_voxels(sub, origin, extent, h / 2)
        if 8 * finer > sub.shape[1] or finer >= m or h / 2 < finest:
            break
        h, count = h / 2, finer
    slope = float(np.clip(np.log2(max(finer, 1) / count), 1.0, 3.0))
    aim = m * (1 + VOXEL_SLACK / 2)
    guess = float(np.clip(h * (count / aim) ** (1 / slope), finest, coarsest))
    tried: list[tuple[float, int]] = []
    for _ in range(VOXEL_COUNT_PASSES):
        tried.append((guess, _count_voxels(cols, origin, extent, guess)))
        if m <= tried[-1][1] <= m * (1 + VOXEL_SLACK):
            break
        if len(tried) > 1 and tried[-1][1] != tried[-2][1]:
            (h0, c0), (h1, c1) = tried[-2:]
            slope = float(np.clip(np.log(c1 / c0) / np.log(h0 / h1), 0.5, 3.0))
        guess = float(np.clip(guess * (tried[-1][1] / aim) ** (1 / slope), finest, coarsest))
    enough = [h for h, c in tried if c >= m]
    return max(enough) if enough else guess


def voxel_sample(points, ratio: float | None = None, *, voxel_size: float | None = None) -> np.ndarray:
    """One point per occupied voxel: Open3D's ``voxel_down_sample`` as indices.

    The grid has its origin at the cloud's minimum corner. Each occupied voxel is
    represented by its point nearest the centroid of the voxel's points (the point closest
    to what ``voxel_down_sample`` outputs; ties: lowest index). Representatives are ranked
    by voxel population, largest first (ties: lowest index).

    With ``voxel_size`` the grid is given: one pass, a hash table of voxel codes compiled
    by numba (the ``voxel`` extra), else an argsort of N voxel codes. Where two points are
    equally near a centroid up to rounding (locations duplicated alike), the two may pick
    different ones. With ``ratio`` alone the edge is searched for (see below) so that the
    grid has at least M = ceil(ratio N) voxels; the search counts voxels on a subsample and
    on the full cloud at most three times (about half a pass each), so it costs under three
    passes. The count is then made
    exact: the first M ranked representatives are returned, which drops the least populated
    voxels when the grid has more than M; when it has fewer (a cloud with many duplicate
    points, or a ``voxel_size`` too coarse), the remaining points follow in index order.
    ``ratio`` and ``voxel_size`` together give exactly M points from the given grid.

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
    # (3, N): the compiled table reads the caller's rows in place, the sort wants each axis contiguous.
    cols = np.asarray(pts, dtype=np.float64).T if _voxel_kernel() else np.array(pts.T, dtype=np.float64, order="C")
    origin, top = _axis_bounds(cols)
    extent = float((top - origin).max()) or 1.0
    if voxel_size is None:
        size = _voxel_size_for(cols, origin, extent, m)
    else:
        size = _validate.check_positive(voxel_size, "voxel_size")
        if extent / size > VOXEL_LEVELS:
            raise ValueError(f"voxel_size must be at least the cloud's extent / 2**20 = {extent / VOXEL_LEVELS:.3g}"
                             f" (at most 2**20 voxels along an axis); got {voxel_size!r}")
    reps, counts = _voxel_representatives(cols, origin, extent, size)
    ranked = reps[np.argsort((counts.max() - counts) * (n + 1) + reps)]  # population desc, then index (one key)
    if m is None or m <= ranked.size:
        return ranked[:m].astype(np.int64)
    return np.concatenate([ranked, np.setdiff1d(np.arange(n), reps)])[:m].astype(np.int64)


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


def _segment_sums_f32(v: np.ndarray, starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(S,) float32 sums of the consecutive segments of ``v``, each added left to right.

    A C loop's rounding: one ``np.cumsum`` per segment while segments are few and long,
    else one vector add per position over all segments still that long.
    """
    if starts.size <= sizes.max():
        return np.array([np.cumsum(v[a:a + s])[-1] for a, s in zip(starts, sizes)], dtype=np.float32)
    total = np.zeros(starts.size, dtype=np.float32)
    for k in range(int(sizes.max())):
        live = np.flatnonzero(sizes > k)
        total[live] += v[starts[live] + k]
    return total


def _kd_layout(q: np.ndarray) -> np.ndarray:
    """(U,) rows of (U, 3) float32 points ``q`` after fpsample's QuickFPS tree build.

    fpsample 1.0 builds its kd-tree by partitioning the points in place: each node splits
    its widest axis (the first on ties) at the float32 mean of the node's points, summed in
    their current order, by a Hoare scan (the i-th point at or above the mean among the
    node's first ``k`` rows trades places with the i-th point below it counted from the
    node's end, ``k`` the count below), down to single points. ``start_idx`` then reads a
    row of that partitioned array. Every node of a level is replayed at once.

    Returns:
      (U,) int64 ``layout``: ``layout[r]`` is the input row that the build leaves in row ``r``.
    """
    n = q.shape[0]
    layout = np.arange(n)
    starts = np.zeros(1, dtype=np.int64)
    while True:
        sizes = np.diff(np.append(starts, n))
        if sizes.max() == 1:
            return layout
        x = q[layout]
        span = np.maximum.reduceat(x, starts) - np.minimum.reduceat(x, starts)
        seg = np.repeat(np.arange(starts.size), sizes)
        v = x[np.arange(n), np.argmax(span, axis=1)[seg]]
        right = v >= (_segment_sums_f32(v, starts, sizes) / sizes.astype(np.float32))[seg]
        below = sizes - np.add.reduceat(right.astype(np.int64), starts)
        head = np.arange(n) - starts[seg] < below[seg]
        up = np.flatnonzero(head & right)
        down = np.flatnonzero(~head & ~right)
        down = down[np.lexsort((-down, seg[down]))]
        layout[up], layout[down] = layout[down], layout[up]
        n_left = np.clip(below, 1, np.maximum(sizes - 1, 1))
        starts = np.sort(np.concatenate([starts, (starts + n_left)[sizes > 1]]))


def _fps_fpsample(p: np.ndarray, m: int, start: int) -> np.ndarray:
    """Exact FPS by fpsample's bucket kd-tree (QuickFPS) on the distinct float32 points.

    Duplicates are resolved first: each distinct position is represented by its lowest
    index (``start`` for its own), and once all M' <= M distinct positions are taken the
    other points follow in index order, as on the JAX path. ``start_idx`` is the row that
    the tree build moves ``start`` to (``_kd_layout``). Should the start not come back
    first (a future fpsample building differently), fpsample's plain O(N M) FPS, which
    takes ``start_idx`` as given, serves instead.
    """
    import fpsample

    q = np.ascontiguousarray(p, dtype=np.float32)
    _, first, group = np.unique(q, axis=0, return_index=True, return_inverse=True)
    group = group.ravel()
    rep = first.copy()
    rep[group[start]] = start
    k = min(m, rep.size)
    distinct = q[rep]
    row = int(np.flatnonzero(_kd_layout(distinct) == group[start])[0])
    picked = fpsample.bucket_fps_kdtree_sampling(distinct, k, start_idx=row).astype(np.int64)
    if picked[0] != group[start]:
        picked = fpsample.fps_sampling(distinct, k, start_idx=int(group[start])).astype(np.int64)
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
        raise ImportError("backend='fpsample' needs the fpsample package: pip install 'hgjax[fps]'")
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
      broken by the tree, deterministically.
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
    local = spatial.local_frame(pts)[0]  # float64 origin removed before any float32 cast
    if fps_backend(backend) == "fpsample":
        return _fps_fpsample(local, m, start)
    p = jnp.asarray(local, dtype=spatial.working_dtype(pts.dtype))
    return np.asarray(_fps(p, m, jnp.int32(start))).astype(np.int64)
