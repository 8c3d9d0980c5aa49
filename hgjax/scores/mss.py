"""Multi-scale sharpness (MSS): surface variation at several scales plus the graph high-pass
read out along the local normal. Beyond the paper (issue 22).

One k-nearest query of K = max(``SCALES``) points (the point itself first, then by distance)
serves every prefix k <= K. For each scale k the covariance C_k of the k nearest points has
eigenvalues l0 <= l1 <= l2 and the eigenvector n_k of l0 (the local normal). Two signals:

* surface variation c_k = l0 / (l0 + l1 + l2) (Pauly, Keiser, Gross, "Multi-scale feature
  extraction on point-sampled surfaces", Eurographics 2003; EA's score at one k),
  at every scale of ``SCALES``;
* normal high-pass h_k = |n_k . (m_k - m_low)| / r_k at every scale of ``BAND_SCALES``:
  m_k is the mean of the k nearest points (the low-pass of the k-nearest graph), m_low that
  of the ``LOW`` nearest (a denoised copy of the point, moving the pass band below the noise),
  and r_k = sqrt(trace C_k) the neighbourhood's RMS radius. The graph high-pass p - m_k
  (GFR's (L P)_i with uniform weights; Chen et al., IEEE TSP 66(3), 2018) is tangential as
  well as normal on a plane sampled unevenly; its normal component is zero on any plane and
  grows with the dihedral angle at a crease, so it is the sharper edge signal.

The score is S = mean_k 3 c_k + mean_k h_k (each term about 0 on a plane and of order 1 at a
90-degree crease). Higher is sharper; resampling keeps the largest. Everything is built from
the covariance and distances of the neighbourhood, so S does not change under rotation,
translation, uniform scaling or a permutation of the points (up to rounding and the order of
tied neighbour distances).

The scales and the combination were chosen on synthetic box unions only (random and grid
sampling, isotropic noise 0 to 1 spacing, rotated): bench/edge_detectors.py reports them with
the labelled clouds, on which nothing was tuned.

Degenerate neighbourhoods: where all points coincide C_k = 0 and S = 0; collinear or coplanar
points give finite S. The normal's derivative (:func:`smallest_eigenpair`) is exact where
l0 is simple and finite where it is degenerate, so gradients with respect to the points are
finite on every cloud; the score is its own smooth twin, as EA's is.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hgjax import _registry, _stream, spatial
from hgjax.scores import _common, ea

__all__ = ["BAND_SCALES", "LOW", "SCALES", "neighbourhoods", "score", "sharpness", "smallest_eigenpair",
           "soft_score"]

SCALES = (8, 16, 32)  # surface variation scales; K = max(SCALES) neighbours per query
BAND_SCALES = (16, 32)  # scales of the normal high-pass
LOW = 4  # points averaged into the denoised copy of the point
GAP = 1e-6  # relative eigenvalue gap below which the normal's derivative leaves a term out


def _prefix(offsets, valid, k: int):
    """Mean (3,) and covariance (3, 3) of the first k rows (the k nearest points)."""
    count, mean, scatter = _common.centred_scatter(offsets[:k], valid[:k])
    return mean, scatter / count


@jax.custom_jvp
def smallest_eigenpair(cov):
    """Smallest eigenvalue l0 and a unit eigenvector n (3,) of it (sign arbitrary) of a
    symmetric 3 x 3 ``cov``, by one run of :mod:`hgjax.scores.ea` 's cyclic Jacobi.

    The derivatives are first-order perturbation theory: dl0 = n^T dC n (as
    :func:`hgjax.scores.ea.smallest_eigenvalue`) and dn = sum_j v_j (v_j^T dC n) / (l0 - l_j)
    over the other eigenpairs, with the terms of an eigenvalue within ``GAP`` x trace of l0
    left out: exact where l0 is simple, finite where it is degenerate (there n is one vector
    of its eigenspace, and the eigenspace, not n, is what varies smoothly).

    Args:
      cov: (3, 3) symmetric.

    Returns:
      (l0, n): scalar l0 and (3,) unit n, in the dtype of ``cov``.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import mss
      >>> l0, n = mss.smallest_eigenpair(jnp.diag(jnp.array([2.0, 0.5, 1.0])))
      >>> float(l0), n.tolist()
      (0.5, [0.0, 1.0, 0.0])
    """
    lam, vec = ea._jacobi(cov, vectors=True)
    i = jnp.argmin(lam)
    return lam[i], vec[:, i]


@smallest_eigenpair.defjvp
def _smallest_eigenpair_jvp(primals, tangents):
    (cov,), (dcov,) = primals, tangents
    lam, vec = ea._jacobi(cov, vectors=True)
    i = jnp.argmin(lam)
    normal = vec[:, i]
    tol = GAP * jnp.abs(jnp.trace(cov))
    dn = jnp.zeros_like(normal)
    for j in range(3):
        gap = lam[i] - lam[j]
        far = (j != i) & (jnp.abs(gap) > tol)
        coef = jnp.where(far, _common.matmul(vec[:, j], dcov, normal) / jnp.where(far, gap, 1), 0)
        dn = dn + coef * vec[:, j]
    return (lam[i], normal), (_common.matmul(normal, dcov, normal), dn)


def sharpness(offsets, valid):
    """MSS score of ONE neighbourhood: mean_k 3 c_k + mean_k h_k (module docstring).

    One covariance and one Jacobi run per scale serve both c_k and, at the band scales, h_k.

    Args:
      offsets: (K, 3) the k nearest points minus the point, nearest first (row 0 is the
        point itself), K >= max(SCALES); padding rows masked by ``valid`` (K,).
      valid: (K,) bool.

    Returns:
      Scalar S >= 0 in the dtype of ``offsets``; 0 when all valid points coincide.

    Examples:
      >>> import jax.numpy as jnp, numpy as np
      >>> from hgjax.scores import mss
      >>> g = np.stack(np.meshgrid(np.arange(-3, 3), np.arange(-3, 3), [0.0]), -1).reshape(-1, 3)
      >>> g = g[np.argsort((g ** 2).sum(1), kind="stable")]
      >>> float(mss.sharpness(jnp.asarray(g), jnp.ones(36, bool)))
      0.0
    """
    x = jnp.where(valid[:, None], offsets, 0)
    low_mean = _prefix(x, valid, LOW)[0]
    variation, high = 0.0, 0.0
    for k in SCALES:
        mean, cov = _prefix(x, valid, k)
        trace = jnp.trace(cov)
        if k in BAND_SCALES:
            l0, normal = smallest_eigenpair(cov)
            high = high + _common.safe_div(jnp.abs(_common.matmul(normal, mean - low_mean)), _common.safe_sqrt(trace), 0.0)
        else:
            l0 = ea.smallest_eigenvalue(cov)
        variation = variation + _common.safe_div(3 * jnp.maximum(l0, 0), trace, 0.0)
    return variation / len(SCALES) + high / len(BAND_SCALES)


def neighbourhoods(points, *, dedupe: bool = True, capacity: int | None = None) -> spatial.Neighbourhoods:
    """The max(SCALES) nearest points of every point (host, not jittable).

    Args:
      points: (N, 3) float32 or float64, N >= max(SCALES).
      dedupe: count exact duplicates once (default True).
      capacity: columns of ``idx`` (>= max(SCALES)); default max(SCALES).

    Returns:
      :class:`hgjax.Neighbourhoods` (no scale), the point itself first.

    Raises:
      TypeError, ValueError: invalid arguments, or N < max(SCALES).

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import mss
      >>> mss.neighbourhoods(np.random.default_rng(0).random((100, 3))).idx.shape
      (100, 32)
    """
    return spatial.knn(points, max(SCALES), dedupe=dedupe, capacity=capacity)


def score(nb, *, chunk_size: int | None = None, progress: bool = False):
    """MSS sharpness of every neighbourhood; higher is sharper.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) S >= 0 in the dtype of ``nb.points``.

    Examples:
      >>> import hgjax
      >>> cloud = hgjax.eval.box_union_cloud(seed=0, n_points=2000)
      >>> s = hgjax.score(hgjax.neighbourhoods(cloud.points, "mss"), "mss")
      >>> bool(s[cloud.edge_mask].mean() > 2 * s[~cloud.edge_mask].mean())
      True
    """
    return _stream.map_neighbourhoods(sharpness, nb, chunk_size=chunk_size, progress=progress)


def soft_score(nb):
    """MSS sharpness as one pure JAX program (its own smooth twin; finite gradients).

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.

    Returns:
      (N,) sharpness; higher is sharper.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "mss")
      >>> hgjax.scores.mss.soft_score(nb).shape
      (100,)
    """
    return _stream.pure_map(sharpness, nb.points, nb.idx)


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of MSS for a tiled run of ``n`` points.

    Raises:
      TypeError, ValueError: invalid ``dedupe``, or fewer than max(SCALES) points.
    """
    return ea.knn_params(n, max(SCALES), params), {}


METHOD = _registry.Method(
    "mss", "knn", largest=True, needs_key=False,
    summary="multi-scale sharpness: surface variation at 8/16/32 neighbours plus the normal graph high-pass",
    citation="Pauly, Keiser, Gross, Eurographics 2003; hgjax issue 22", build=neighbourhoods, score=score,
    soft_score=soft_score, params=_registry.stages(build=("capacity", "dedupe"), score=("chunk_size", "progress")),
    tile_params=tile_params, rows=ea.tile_rows, kernel=lambda params: (sharpness, False))
