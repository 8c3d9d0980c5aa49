"""Small symmetric 3 x 3 eigenproblems shared by the covariance methods (EA, PCA-AC, LHF, MSS, HKC's frame).

Cyclic Jacobi rotations on the six entries of a symmetric 3 x 3 (Golub and Van Loan,
Alg. 8.5.1): element-wise arithmetic that XLA fuses over the whole batch, where a batched
LAPACK ``eigvalsh`` makes one call per matrix and iterates longer on near-planar
neighbourhoods. Also the default neighbourhood size of the k-nearest methods.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from hgjax.scores import _common

__all__ = ["DEFAULT_K", "JACOBI_SWEEPS", "eigenvalues", "jacobi", "rotations", "smallest_eigenvalue",
           "symmetric_entries"]

DEFAULT_K = 16
# Cyclic Jacobi converges quadratically: on the stress spectra of tests/test_baselines.py
# three sweeps miss rounding level in float64 and four reach it; the fifth is margin.
JACOBI_SWEEPS = 5


def jacobi(cov, *, vectors: bool):
    """:func:`rotations` of the six entries of a symmetric 3 x 3 ``cov``: (eigenvalues (3,), vectors or None)."""
    lam, vec = rotations(tuple(cov[pq] for pq in _common.PAIRS), vectors=vectors)
    return jnp.stack(lam), vec


def rotations(entries, *, vectors: bool):
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
      >>> from hgjax.scores import eigen
      >>> [round(float(x), 6) for x in eigen.eigenvalues((2.0, 2.0, 0.5, 1.0, 0.0, 0.0))]
      [0.5, 1.0, 3.0]
    """
    return _ascending(*rotations(entries, vectors=False)[0])


@eigenvalues.defjvp
def _eigenvalues_jvp(primals, tangents):
    (entries,), (d,) = primals, tangents
    lam, vec = rotations(entries, vectors=True)
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
      >>> from hgjax.scores import eigen
      >>> round(float(eigen.smallest_eigenvalue(jnp.array([[2.0, 1, 0], [1, 2, 0], [0, 0, 3]]))), 6)
      1.0
    """
    return eigenvalues(symmetric_entries(cov))[0]
