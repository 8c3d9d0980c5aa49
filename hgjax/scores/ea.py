"""Eigenvalue analysis (EA) baseline: Bazazian, Casas, Ruiz-Hidalgo, "Fast and robust edge
extraction in unorganized point clouds", DICTA 2015.

For each point, the covariance C of its k nearest points (the point itself included) has
eigenvalues l0 <= l1 <= l2; the surface variation (Pauly et al.'s curvature estimate)

    c = l0 / (l0 + l1 + l2)

is 0 on a plane and grows towards 1/3 at sharp features and in isotropic clutter. EA keeps
the points with the largest c. A neighbourhood whose points all coincide has C = 0; its
variation is defined as 0 (no shape at all, hence not sharp), so no NaN ever appears.

l0 comes from cyclic Jacobi rotations on the six entries of the 3 x 3 covariance
(:func:`hgjax.scores.eigen.eigenvalues`, shared with LHF and MSS).
"""

from __future__ import annotations

import jax.numpy as jnp

from hgjax import _method, _stream, _validate
from hgjax.neighbours import nearest, spatial
from hgjax.scores import _common
from hgjax.scores.eigen import DEFAULT_K, eigenvalues

__all__ = ["neighbourhoods", "score", "soft_score", "variation"]

def variation(offsets, valid):
    """Surface variation l0 / (l0 + l1 + l2) of one neighbourhood.

    Args:
      offsets: (K, 3) the neighbourhood minus the point (which keeps the covariance well
        conditioned), padding rows masked by ``valid`` (K,).

    Returns:
      Scalar c in [0, 1/3]; 0 when all valid points coincide. Scale-free: the offsets are
      first scaled by an exact power of two (:func:`hgjax.scores._common.unit_scale`), so
      no square under- or overflows at any extent of the cloud.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> flat = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
      >>> float(hgjax.scores.ea.variation(flat, jnp.ones(4, bool)))
      0.0
    """
    _, cov = _common.centred_entries(_common.unit_scale(jnp.where(valid[:, None], offsets, 0)), valid)
    l0 = jnp.maximum(eigenvalues(cov)[0], 0)
    trace = cov[0] + cov[1] + cov[2]
    return jnp.where(trace > 0, l0 / jnp.where(trace > 0, trace, 1), 0.0)


def neighbourhoods(points, *, k: int = DEFAULT_K, dedupe: bool = True, capacity: int | None = None,
                   search: str = "host", cell_slots: int | None = None, cell_edge=None) -> spatial.Neighbourhoods:
    """k-nearest neighbourhoods of EA and PCA-AC (host; jittable with ``search="jax"``).

    Args:
      points: (N, 3) float32 or float64, N >= k.
      k: neighbourhood size counting the point itself (default 16).
      dedupe: count exact duplicates once (default True; False for the paper's
        neighbourhoods, where k copies of a point make its covariance 0).
      capacity: columns of ``idx`` (>= k); default k.
      search: ``"host"`` (SciPy's k-d tree; not jittable) or ``"jax"`` (the traced search:
        jit, vmap, grad; the same neighbour sets, :func:`hgjax.neighbours.nearest.build`).
      cell_slots, cell_edge: the traced search's candidates read per step (static) and first
        cell edge (traced, or None from the data): speed settings, never limits.

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
    return nearest.build(points, k, dedupe=dedupe, capacity=capacity, search=search, cell_slots=cell_slots,
                             cell_edge=cell_edge)


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
    """EA surface variation, pure JAX (its own smooth twin: :func:`score`'s kernel, streamed when
    called eagerly).

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
    return _stream.map_neighbourhoods(variation, nb)


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of EA for a tiled run of ``n`` points.

    Raises:
      TypeError, ValueError: invalid parameters, or fewer than k points.
    """
    return nearest.build_params(n, _validate.check_int(params.get("k", DEFAULT_K), "k", minimum=2), params), {}


def tile_kernel(params: dict):
    """(row kernel, narrow) the tiles stream for EA's scores: :func:`variation` on full-width rows."""
    del params  # EA's score takes no parameter
    return variation, False


METHOD = _method.Method(
    "ea", "knn", largest=True, needs_key=False,
    summary="eigenvalue analysis baseline: keep the largest surface variation l0 / (l0 + l1 + l2)",
    citation=_method.DICTA, build=neighbourhoods, score=score, soft_score=soft_score,
    tiling=_method.Tiling(params=tile_params, reach=nearest.reach, rows=nearest.tile_rows, kernel=tile_kernel))
