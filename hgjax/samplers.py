"""Geometry-agnostic samplers people compare against: uniform random, voxel grid, farthest point.

They play the role of Open3D's ``random_down_sample``, ``voxel_down_sample`` and
``farthest_point_down_sample``, but like every hgjax method they return exactly
ceil(ratio N) unique int64 indices into the caller's points, highest priority first.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.select import weighted_sample

__all__ = ["farthest_point_sample", "uniform_sample", "voxel_sample"]

VOXEL_LEVELS = 2**20  # the finest voxel grid tried has this many cells along the longest side
VOXEL_BISECTIONS = 24  # log-h interval 15 / 2**24: h to about 1e-6 relative


def check_key(key, method: str, alternative: str = "") -> jax.Array:
    """Return ``key`` after checking it is a ``jax.random`` key.

    Args:
      key: a typed key (``jax.random.key``) or a legacy uint32 (2,) key (``jax.random.PRNGKey``).
      method: the method name quoted in the error.
      alternative: extra advice appended to the error for a missing key.

    Raises:
      ValueError: if ``key`` is None.
      TypeError: if ``key`` is not a key.
    """
    if key is None:
        raise ValueError(f"method {method!r} draws random numbers and needs an explicit key:"
                         f" pass key=jax.random.key(0){alternative}")
    typed = isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    legacy = isinstance(key, (jax.Array, np.ndarray)) and key.dtype == np.uint32 and key.shape == (2,)
    if not ((typed and key.shape == ()) or legacy):
        raise TypeError(f"key must be a jax.random key such as jax.random.key(0); got"
                        f" {type(key).__name__} {getattr(key, 'dtype', '')}{getattr(key, 'shape', '')}")
    return key


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
    return weighted_sample(check_key(key, "uniform"), np.ones(pts.shape[0]), m)


def _voxels(p: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """(inverse (N,), counts (V,)) of the occupied voxels of edge ``size`` (origin at the min)."""
    cell = np.floor((p - p.min(axis=0)) / size).astype(np.int64)  # < 2**21 for size >= finest
    code = (cell[:, 0] << 42) | (cell[:, 1] << 21) | cell[:, 2]
    _, inverse, counts = np.unique(code, return_inverse=True, return_counts=True)
    return inverse.ravel(), counts


def voxel_sample(points, ratio: float) -> np.ndarray:
    """One point per occupied voxel of a grid sized to keep ceil(ratio N) points.

    The voxel edge h is found by bisection (on log h, at most 24 steps) between the
    extent / 2^20 grid and a single voxel, for the largest h whose grid has at least
    M = ceil(ratio N) occupied voxels (the count is not strictly monotone in h, so any
    crossing is accepted; bisection stops early when the count is exactly M). Each voxel
    is represented by its point closest to the centroid of the voxel's points (ties: lowest
    index). The representatives are ordered by voxel population, largest first (ties:
    lowest index), and the first M are returned, so a grid with more than M voxels drops its
    least populated voxels. When even the finest grid has fewer than M voxels (many
    duplicates), the remaining points follow in index order.

    Args:
      points: (N, 3) float32 or float64.
      ratio: fraction to keep, in (0, 1].

    Returns:
      (M,) int64 unique indices, M = ceil(ratio N), highest priority first.

    Raises:
      TypeError, ValueError: invalid points or ratio.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.array([[0., 0, 0], [0.1, 0, 0], [5, 0, 0], [5.1, 0, 0]])
      >>> sorted(hgjax.voxel_sample(pts, 0.5).tolist())
      [0, 2]
    """
    pts = _validate.check_points(points)
    n = pts.shape[0]
    m = _validate.n_keep(n, _validate.check_ratio(ratio))
    p = np.asarray(pts, dtype=np.float64)
    extent = float(np.ptp(p, axis=0).max()) or 1.0
    lo, hi = np.log(extent / VOXEL_LEVELS), np.log(2 * extent)  # counts: many, then 1
    inverse, counts = _voxels(p, np.exp(lo))
    for _ in range(VOXEL_BISECTIONS):
        if counts.size == m:
            break
        mid = (lo + hi) / 2
        trial = _voxels(p, np.exp(mid))
        if trial[1].size >= m:
            lo, (inverse, counts) = mid, trial
        else:
            hi = mid
    centroid = np.stack([np.bincount(inverse, p[:, a], counts.size) for a in range(3)], axis=1) / counts[:, None]
    dist = np.sum((p - centroid[inverse]) ** 2, axis=1)
    order = np.lexsort((np.arange(n), dist, inverse))  # by voxel, then distance, then index
    first = np.ones(n, dtype=bool)
    first[1:] = inverse[order[1:]] != inverse[order[:-1]]
    reps = order[first]  # one per voxel, voxels in code order
    reps = reps[np.lexsort((reps, -counts))]
    rest = np.setdiff1d(np.arange(n), reps)
    return np.concatenate([reps, rest])[:m].astype(np.int64)


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


def farthest_point_sample(points, ratio: float, *, start: int = 0) -> np.ndarray:
    """Farthest point sampling: each new point maximises its distance to those already kept.

    A jitted ``lax.fori_loop`` over one (N,) array of squared distances to the kept set:
    O(N M) time, O(N) memory. Ties go to the lowest index; once only duplicates of kept
    points remain (distance 0) they are taken in index order, so no point is picked twice.

    Args:
      points: (N, 3) float32 or float64.
      ratio: fraction to keep, in (0, 1]. M = ceil(ratio N) is static (a new M compiles).
      start: index of the first kept point (default 0, deterministic).

    Returns:
      (M,) int64 unique indices in selection order.

    Raises:
      TypeError, ValueError: invalid points, ratio or start.

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
    p = jnp.asarray(pts, dtype=_stream.working_dtype(pts.dtype))
    return np.asarray(_fps(p, m, jnp.int32(start))).astype(np.int64)
