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

import jax.numpy as jnp

from hgjax import _stream, _validate, spatial
from hgjax.scores import _common

__all__ = ["DEFAULT_K", "neighbourhoods", "score", "soft_score", "variation"]

DEFAULT_K = 16


def variation(offsets, valid):
    """Surface variation l0 / (l0 + l1 + l2) of one neighbourhood.

    Args:
      offsets: (K, 3) the neighbourhood minus the point (which keeps the covariance well
        conditioned), padding rows masked by ``valid`` (K,).

    Returns:
      Scalar c in [0, 1/3]; 0 when all valid points coincide.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> flat = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
      >>> float(hgjax.scores.ea.variation(flat, jnp.ones(4, bool)))
      0.0
    """
    x = jnp.where(valid[:, None], offsets, 0)
    count = jnp.maximum(jnp.sum(valid), 1).astype(x.dtype)
    mean = jnp.sum(x, axis=0) / count
    y = jnp.where(valid[:, None], x - mean[None, :], 0)
    cov = y.T @ y
    l0 = jnp.maximum(jnp.linalg.eigvalsh(cov)[0], 0)
    trace = jnp.trace(cov)
    return jnp.where(trace > 0, l0 / jnp.where(trace > 0, trace, 1), 0.0)


def neighbourhoods(points, *, k: int = DEFAULT_K, dedupe: bool = True,
                   capacity: int | None = None) -> spatial.Neighbourhoods:
    """k-nearest neighbourhoods of EA and PCA-AC (host, not jittable).

    Args:
      points: (N, 3) float32 or float64, N >= k.
      k: neighbourhood size counting the point itself (default 16).
      dedupe: count exact duplicates once (default True; False for the paper's
        neighbourhoods, where k copies of a point make its covariance 0).
      capacity: columns of ``idx`` (>= k); default k.

    Returns:
      :class:`hgjax.Neighbourhoods` (no scale).

    Raises:
      TypeError, ValueError: invalid arguments, or N < k.

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import ea
      >>> ea.neighbourhoods(np.random.default_rng(0).random((100, 3))).idx.shape
      (100, 16)
    """
    k = _validate.check_int(k, "k", minimum=2)
    return spatial.knn(points, k, dedupe=dedupe, capacity=capacity)


def score(nb, *, chunk_size: int | None = None, progress: bool = False):
    """EA surface variation of every neighbourhood (Bazazian et al. 2015); higher is sharper.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) c = l0 / (l0 + l1 + l2) in [0, 1/3], in the dtype of ``nb.points``; 0 where
      the neighbourhood is a single repeated point.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((200, 3)), "ea")
      >>> c = hgjax.scores.ea.score(nb)
      >>> c.shape, bool(((c >= 0) & (c <= 1 / 3)).all())
      ((200,), True)
    """
    return _stream.map_neighbourhoods(variation, nb, chunk_size=chunk_size, progress=progress)


def soft_score(nb):
    """EA surface variation as one pure JAX program (its own smooth twin).

    An eigenvalue (not an eigenvector) has a finite derivative even where it is degenerate,
    and the division is guarded, so gradients are finite on every cloud.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.

    Returns:
      (N,) surface variation; higher is sharper.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "ea")
      >>> hgjax.scores.ea.soft_score(nb).shape
      (100,)
    """
    return _common.soft_map(variation, nb)
