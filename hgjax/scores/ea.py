"""Eigenvalue analysis (EA) baseline: Bazazian, Casas, Ruiz-Hidalgo, "Fast and robust edge
extraction in unorganized point clouds", DICTA 2015.

For each point, the covariance C of its k nearest points (the point itself included) has
eigenvalues l0 <= l1 <= l2; the surface variation (Pauly et al.'s curvature estimate)

    c = l0 / (l0 + l1 + l2)

is 0 on a plane and grows towards 1/3 at sharp features and in isotropic clutter. EA keeps
the points with the largest c. A neighbourhood whose points all coincide has C = 0; its
variation is defined as 0 (no shape at all, hence not sharp), so no NaN ever appears.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbourhoods import SpatialIndex
from hgjax.scores import _common

__all__ = ["DEFAULT_K", "ea", "ea_neighbourhood", "surface_variation"]

DEFAULT_K = 16


def ea_neighbourhood(centre, nbrs, valid):
    """Surface variation l0 / (l0 + l1 + l2) of one neighbourhood.

    Args:
      centre: (3,) the point (its offsets keep the covariance well conditioned).
      nbrs: (K, 3) the neighbourhood, padding rows masked by ``valid`` (K,).

    Returns:
      Scalar c in [0, 1/3]; 0 when all valid points coincide.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> flat = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
      >>> float(hgjax.scores.ea_neighbourhood(jnp.zeros(3), flat, jnp.ones(4, bool)))
      0.0
    """
    x = jnp.where(valid[:, None], nbrs - centre[None, :], 0)
    count = jnp.sum(valid).astype(x.dtype)
    mean = jnp.sum(x, axis=0) / count
    y = jnp.where(valid[:, None], x - mean[None, :], 0)
    cov = y.T @ y
    l0 = jnp.maximum(jnp.linalg.eigvalsh(cov)[0], 0)
    return _common.safe_div(l0, jnp.trace(cov), 0.0)


_chunk_kernel = jax.jit(_common.map_neighbourhoods(ea_neighbourhood))


def surface_variation(index: SpatialIndex, k: int, chunk_size, progress: bool) -> np.ndarray:
    """(N,) surface variation of the k-nearest neighbourhoods of ``index``, sorted frame."""
    chunk = _common.chunk_size_or_auto(chunk_size, index.n, 8 * k * 12)
    return _stream.stream(_chunk_kernel, index, lambda rows: index.knn(k, rows), chunk_size=chunk,
                          progress=progress)


def ea(points, *, k: int = DEFAULT_K, chunk_size: int | None = None, progress: bool = False) -> np.ndarray:
    """EA surface variation per point (Bazazian et al. 2015); higher is sharper.

    Args:
      points: (N, 3) float32 or float64, N >= k.
      k: neighbourhood size counting the point itself (default 16). Static: a new value
        compiles a new kernel.
      chunk_size: points per streamed chunk (default: automatic). Does not change results.
      progress: show a progress bar on stderr for long runs.

    Returns:
      (N,) c = l0 / (l0 + l1 + l2) in [0, 1/3], in the dtype of ``points``; 0 where the
      neighbourhood is a single repeated point.

    Raises:
      TypeError, ValueError: invalid points, k < 2 or N < k.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((200, 3))
      >>> c = hgjax.scores.ea(pts)
      >>> c.shape, bool(((c >= 0) & (c <= 1 / 3)).all())
      ((200,), True)
    """
    pts = _validate.check_points(points)
    k = _validate.check_int(k, "k", minimum=2)
    _validate.check_min_points(pts.shape[0], k, f"k={k} nearest neighbours")
    index = SpatialIndex(pts)
    return _common.finish(index, surface_variation(index, k, chunk_size, progress), pts.dtype)
