"""Eigenvalue analysis (EA) baseline: Bazazian, Casas, Ruiz-Hidalgo, "Fast and robust edge
extraction in unorganized point clouds", DICTA 2015.

For each point, the covariance C of its k nearest points (the point itself included) has
eigenvalues l0 <= l1 <= l2; the surface variation (Pauly et al.'s curvature estimate)

    c = l0 / (l0 + l1 + l2)

is 0 on a plane and grows towards 1/3 at sharp features and in isotropic clutter. EA keeps
the points with the largest c. A neighbourhood whose points all coincide has C = 0; its
variation is defined as 0 (no shape at all, hence not sharp), so no NaN ever appears.

l0 comes from cyclic Jacobi rotations on the six entries of the 3 x 3 covariance
(:func:`eigenvalues`, also LHF's): element-wise arithmetic that XLA fuses over the whole
batch, where a batched LAPACK ``eigvalsh`` makes one call per matrix and iterates longer on
near-planar neighbourhoods.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hgjax import _registry, _stream, _validate, spatial
from hgjax.scores import _common

__all__ = ["DEFAULT_K", "eigenvalues", "neighbourhoods", "score", "smallest_eigenvalue", "soft_score", "variation"]

DEFAULT_K = 16
# Cyclic Jacobi converges quadratically: on the stress spectra of tests/test_baselines.py
# three sweeps miss rounding level in float64 and four reach it; the fifth is margin.
JACOBI_SWEEPS = 5


def _jacobi(cov, *, vectors: bool):
    """:func:`_rotations` of the six entries of a symmetric 3 x 3 ``cov``: (eigenvalues (3,), vectors or None)."""
    lam, vec = _rotations(tuple(cov[pq] for pq in _common.PAIRS), vectors=vectors)
    return jnp.stack(lam), vec


def _rotations(entries, *, vectors: bool):
    """Eigenvalues (three scalars, in no particular order) and, with ``vectors``, eigenvectors
    (3, 3) as columns of the symmetric 3 x 3 with ``entries`` (six scalars in
    ``_common.PAIRS`` order), by JACOBI_SWEEPS cyclic sweeps of rotations.

    Each rotation zeroes a[p, q] with t = tan(angle) in the form that never divides by
    a[p, q] (Golub and Van Loan, Alg. 8.5.1); t = 0 when the pair is already diagonal. The
    sweeps run as a loop over one sweep, not written out: XLA CPU would otherwise fuse the
    computation of the entries into every rotation and recompute it there (LHF's kernel
    runs 1.8x slower written out).
    """
    def sweep(_, carry):
        a, v = dict(zip(_common.PAIRS, carry[0])), [list(row) for row in carry[1]]
        for p, q in ((0, 1), (0, 2), (1, 2)):
            r = 3 - p - q
            rp, rq = (min(r, p), max(r, p)), (min(r, q), max(r, q))
            app, aqq, apq = a[p, p], a[q, q], a[p, q]
            d = aqq - app
            denom = jnp.abs(d) + jnp.sqrt(d * d + 4 * apq * apq)
            t = 2 * apq * jnp.where(d >= 0, 1, -1) / jnp.where(denom > 0, denom, 1)
            c = 1 / jnp.sqrt(1 + t * t)
            s = t * c
            a[p, p], a[q, q], a[p, q] = app - t * apq, aqq + t * apq, jnp.zeros_like(apq)
            a[rp], a[rq] = c * a[rp] - s * a[rq], s * a[rp] + c * a[rq]
            for row in v:
                row[p], row[q] = c * row[p] - s * row[q], s * row[p] + c * row[q]
        return tuple(a[pq] for pq in _common.PAIRS), tuple(tuple(row) for row in v)

    dtype = jnp.result_type(*entries)
    eye = tuple(tuple(jnp.asarray(float(i == j), dtype) for j in range(3)) for i in range(3)) if vectors else ()
    a, v = jax.lax.fori_loop(0, JACOBI_SWEEPS, sweep, (tuple(entries), eye))
    return a[:3], (jnp.stack([jnp.stack(row) for row in v]) if vectors else None)


def _ascending(a, b, c):
    """Three scalars sorted ascending by min / max (a sort inside a custom_jvp breaks its batching)."""
    mid = jnp.maximum(jnp.minimum(a, b), jnp.minimum(jnp.maximum(a, b), c))
    return jnp.minimum(jnp.minimum(a, b), c), mid, jnp.maximum(jnp.maximum(a, b), c)


@jax.custom_jvp
def eigenvalues(entries):
    """Ascending eigenvalues of a symmetric 3 x 3 matrix given by its six entries, by cyclic Jacobi.

    As accurate as LAPACK's ``eigvalsh`` (|error| <= a few eps x trace). The derivative of
    each is v_k^T dC v_k with v_k its eigenvector: finite everywhere; where eigenvalues are
    equal, the derivative along one vector of their eigenspace.

    Args:
      entries: six scalars C[0, 0], C[1, 1], C[2, 2], C[0, 1], C[0, 2], C[1, 2] (``_common.PAIRS``).

    Returns:
      Three scalars l0 <= l1 <= l2, in the dtype of ``entries``.

    Examples:
      >>> from hgjax.scores import ea
      >>> [round(float(x), 6) for x in ea.eigenvalues((2.0, 2.0, 0.5, 1.0, 0.0, 0.0))]
      [0.5, 1.0, 3.0]
    """
    return _ascending(*_rotations(entries, vectors=False)[0])


@eigenvalues.defjvp
def _eigenvalues_jvp(primals, tangents):
    (entries,), (d,) = primals, tangents
    lam, vec = _rotations(entries, vectors=True)
    order = jnp.argsort(jnp.stack(lam))
    dlam = []
    for k in range(3):
        v = vec[:, order[k]]
        dlam.append(v[0] * v[0] * d[0] + v[1] * v[1] * d[1] + v[2] * v[2] * d[2]
                    + 2 * (v[0] * v[1] * d[3] + v[0] * v[2] * d[4] + v[1] * v[2] * d[5]))
    return _ascending(*lam), tuple(dlam)


def symmetric_entries(cov):
    """The six entries (``_common.PAIRS`` order) of the symmetric part of a 3 x 3 ``cov``."""
    return (cov[0, 0], cov[1, 1], cov[2, 2], (cov[0, 1] + cov[1, 0]) / 2, (cov[0, 2] + cov[2, 0]) / 2,
            (cov[1, 2] + cov[2, 1]) / 2)


def smallest_eigenvalue(cov):
    """Smallest eigenvalue l0 of a symmetric 3 x 3 matrix, by cyclic Jacobi (:func:`eigenvalues`).

    The derivative is v0^T dC v0 with v0 the eigenvector of l0: finite everywhere; where l0
    is degenerate, v0 is one vector of its eigenspace.

    Args:
      cov: (3, 3) symmetric.

    Returns:
      Scalar l0, in the dtype of ``cov``.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import ea
      >>> round(float(ea.smallest_eigenvalue(jnp.array([[2.0, 1, 0], [1, 2, 0], [0, 0, 3]]))), 6)
      1.0
    """
    return eigenvalues(symmetric_entries(cov))[0]


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


def knn_params(n: int, k: int, params: dict) -> dict:
    """Build parameters ``{"k", "dedupe"}`` of a k-nearest method for ``n`` points.

    Raises:
      TypeError, ValueError: invalid ``dedupe``, or fewer than k points.
    """
    build = {"k": k, "dedupe": _validate.check_bool(params.get("dedupe", True), "dedupe")}
    _validate.check_min_points(n, k, f"k={k} nearest neighbours")
    return build


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of EA for a tiled run of ``n`` points.

    Raises:
      TypeError, ValueError: invalid parameters, or fewer than k points.
    """
    return knn_params(n, _validate.check_int(params.get("k", DEFAULT_K), "k", minimum=2), params), {}


def tile_rows(index, rows, build: dict, dtype):
    """(part, idx, (), reach) per batch: the k-nearest neighbourhoods of ``rows`` (:func:`hgjax.spatial.knn_batches`)."""
    del dtype  # no per-row arguments
    for part, idx, reach in spatial.knn_batches(index, build["k"], rows):
        yield part, idx, (), reach


def tile_kernel(params: dict):
    """(row kernel, narrow) the tiles stream for EA's scores: :func:`variation` on full-width rows."""
    del params  # EA's score takes no parameter
    return variation, False


KNN_PARAMS = _registry.stages(build=("capacity", "dedupe", "k"), score=("chunk_size", "progress"))

METHOD = _registry.Method(
    "ea", "knn", largest=True, needs_key=False,
    summary="eigenvalue analysis baseline: keep the largest surface variation l0 / (l0 + l1 + l2)",
    citation=_registry.DICTA, build=neighbourhoods, score=score, soft_score=soft_score, params=KNN_PARAMS,
    tile_params=tile_params, rows=tile_rows, kernel=tile_kernel)
