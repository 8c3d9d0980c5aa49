"""Hypergraph spectrum estimation from stationarity, and the hypergraph Fourier transform.

Following the paper (Deng, Zhang, Ding, IEEE TIP 2022, Sec. III-A, Eqs. (6)-(9)), a local
signal x of shape (n, 3) is treated as three observations of a weak-sense stationary
hypergraph signal: after centring, the correlation R = x_c x_c^T (n, n) shares its
eigenvectors with the hypergraph spectrum basis V, and its eigenvalues (normalised to
[0, 1]) order the spectrum from high frequency (small) to low frequency (large).

Every function here is pure ``jax.numpy`` and works on one signal; ``jax.vmap`` batches it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "band_energies",
    "band_threshold",
    "centre",
    "correlation",
    "estimate_spectrum",
    "hgft",
    "host_eigh",
    "ihgft",
    "normalise_eigenvalues",
]


def centre(x: jax.Array, *, axis: str = "row") -> jax.Array:
    """Zero-mean version of a signal x (n, 3).

    Args:
      x: (n, 3) signal.
      axis: ``"row"`` subtracts from every row the mean of its three entries (what the
        reference implementation calls "normalize"); ``"column"`` subtracts the column means.

    Returns:
      (n, 3) centred signal.
    """
    if axis == "row":
        return x - jnp.mean(x, axis=1, keepdims=True)
    if axis == "column":
        return x - jnp.mean(x, axis=0, keepdims=True)
    raise ValueError(f"unknown axis {axis!r}; expected one of ['column', 'row']")


def correlation(x: jax.Array, *, axis: str = "row") -> jax.Array:
    """R = x_c x_c^T (n, n), the stationarity estimate of the spectrum (paper Eq. (7))."""
    xc = centre(x, axis=axis)
    return jnp.matmul(xc, xc.T, precision=jax.lax.Precision.HIGHEST)


def normalise_eigenvalues(lam: jax.Array) -> jax.Array:
    """|lam| / max |lam|, and all zeros (not NaN) when every eigenvalue is 0."""
    a = jnp.abs(lam)
    top = jnp.max(a)
    return jnp.where(top > 0, a / jnp.where(top > 0, top, 1), jnp.zeros_like(a))


def band_threshold(lam: jax.Array) -> jax.Array:
    """t = argmax(diff(lam)) + 1 for ascending lam: the first t components are high frequency.

    The threshold sits at the largest jump between successive eigenvalues (the paper's
    "sharp rise of successive eigenvalues", Sec. III-B). Ties pick the first jump.
    """
    return jnp.argmax(jnp.diff(lam)) + 1


def estimate_spectrum(x: jax.Array, *, axis: str = "row") -> tuple[jax.Array, jax.Array]:
    """Hypergraph spectrum of a signal x (n, 3): normalised eigenvalues and basis.

    Args:
      x: (n, 3) signal.
      axis: centring, see :func:`centre`.

    Returns:
      (lam, V): lam (n,) ascending in [0, 1]; V (n, n) with eigenvectors as columns, computed
      by NumPy's ``eigh`` (:func:`host_eigh`; inside degenerate eigenspaces the basis is
      whatever that eigensolver returns, as REFERENCE.md's reference code).
    """
    lam, v = host_eigh(correlation(x, axis=axis))
    return normalise_eigenvalues(lam), v


def host_eigh(r: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``numpy.linalg.eigh`` of symmetric matrices (..., n, n) through a host callback.

    jaxlib 0.10's CPU LAPACK eigh can hang when two batched calls share one XLA program
    (bench/results/archive/eigh_deadlock.md); NumPy's, called from the host, cannot. Works under jit and
    vmap (one batched call per vmapped block); not differentiable, which the eigh-based
    scores (LHF reference, the proof solver) do not need.

    Args:
      r: (..., n, n) symmetric matrices.

    Returns:
      (lam, V): (..., n) ascending eigenvalues and (..., n, n) eigenvectors as columns, in
      the dtype of ``r``.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.spectrum import host_eigh
      >>> lam, v = host_eigh(jnp.diag(jnp.array([3.0, 1.0])))
      >>> lam.tolist()
      [1.0, 3.0]
    """
    shapes = (jax.ShapeDtypeStruct(r.shape[:-1], r.dtype), jax.ShapeDtypeStruct(r.shape, r.dtype))

    def host(m):
        lam, v = np.linalg.eigh(np.asarray(m))
        return lam.astype(m.dtype), v.astype(m.dtype)

    return jax.pure_callback(host, shapes, jax.lax.stop_gradient(r), vmap_method="broadcast_all")


def hgft(v: jax.Array, s: jax.Array) -> jax.Array:
    """Simplified hypergraph Fourier transform s_hat = V^T s (paper Eq. (8))."""
    return jnp.matmul(v.T, s, precision=jax.lax.Precision.HIGHEST)


def ihgft(v: jax.Array, s_hat: jax.Array) -> jax.Array:
    """Inverse transform s = V s_hat (paper Eq. (9))."""
    return jnp.matmul(v, s_hat, precision=jax.lax.Precision.HIGHEST)


def band_energies(v: jax.Array, t: jax.Array, s: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """High- and low-band energies of s in the basis V, split at the threshold t.

    Args:
      v: (n, n) basis, columns sorted by ascending eigenvalue.
      t: number of high-frequency components (the first t columns).
      s: (n,) or (n, c) signal.

    Returns:
      (l1_high, l1_total, l2_high, l2_low): the L1 norms of the high band and of all of
      s_hat = V^T s (the paper's Eqs. (12), (14)), and the Frobenius norms of the
      projections of s onto each band. The L1 numbers depend on the basis inside degenerate
      eigenspaces; the L2 numbers do not.
    """
    s_hat = hgft(v, s)
    high = (jnp.arange(v.shape[1]) < t).reshape((-1,) + (1,) * (s_hat.ndim - 1))
    a = jnp.abs(s_hat)
    l1_high = jnp.sum(jnp.where(high, a, 0))
    sq = s_hat * s_hat
    return (l1_high, jnp.sum(a), jnp.sqrt(jnp.sum(jnp.where(high, sq, 0))),
            jnp.sqrt(jnp.sum(jnp.where(high, 0, sq))))
