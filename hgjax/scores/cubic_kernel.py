"""The cubic hypergraph kernel shared by HKC and HKF (paper Sec. III-A, Fig. 2).

A k x k x k kernel (k odd) has N_k = k^3 voxel centres C = d * {-(k-1)/2, ..., (k-1)/2}^3,
ordered x slowest and z fastest (index k^2 i + k j + l). The local signal s_i (N_k,) of
point p_i counts the points q with |q - p_i - C[j]| < d / 2 in every coordinate (strict),
p_i itself included in the centre voxel.

The spectrum estimated from the centres (row-centred C_n, R = C_n C_n^T) depends only on
the kernel, never on the data: R has rank 2 and, for a cubic kernel, its two non-zero
eigenvalues are equal. After normalisation the spectrum is N_k - 2 zeros (high band) and
two ones (low band), and the low-band projector is exactly R / lambda_max. It is computed
here once, on the host, in float64.
"""

from __future__ import annotations

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax.scores import _common, eigen

__all__ = ["band_energies", "frame", "local_signal", "low_high", "oriented", "soft_local_signal"]


FRAME_GAP = 1e-9  # eigenvalue gaps below this x trace(C) are degenerate: no frame derivative across them


@functools.lru_cache(maxsize=None)
def integer_offsets(kernel_size: int) -> np.ndarray:
    """(N_k, 3) integer voxel offsets, x slowest and z fastest."""
    h = (kernel_size - 1) // 2
    return np.array(list(itertools.product(range(-h, h + 1), repeat=3)), dtype=np.float64)


@functools.lru_cache(maxsize=None)
def low_band(kernel_size: int) -> tuple[np.ndarray, float]:
    """Exact low-band projector factors of the kernel spectrum.

    Returns:
      (B, mu): B (N_k, 3) = 3 C - (C 1) 1^T, an integer matrix proportional to the row-centred
      centres, and mu = lambda_max(B^T B). The projector onto the low band is B B^T / mu, so
      low = B (B^T s) / mu, where B^T s is exact for integer counts; low is exactly 0 iff the
      signal is symmetric about the centre.
    """
    c = integer_offsets(kernel_size)
    b = 3.0 * c - c.sum(axis=1, keepdims=True)
    mu = float(np.linalg.eigvalsh(b.T @ b).max())
    return b, mu


@functools.lru_cache(maxsize=None)
def reference_spectrum(kernel_size: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The spectrum as REFERENCE.md computes it: NumPy ``eigh`` of R for the kernel.

    R is built from the integer voxel offsets (d = 1): for another d, R scales by d^2, which
    leaves the normalised eigenvalues, the band threshold and the eigenspaces unchanged.
    Only the basis LAPACK returns inside the degenerate eigenspaces depends on the bits of
    R; fixing d = 1 makes the reference scores independent of the cloud's units and dtype.

    Returns:
      (lam, V, t): lam (N_k,) = eig / max eig (ascending), V (N_k, N_k) the basis NumPy's
      LAPACK returns (arbitrary inside the degenerate eigenspaces), and the band threshold
      t = argmax(diff(lam)) + 1.
    """
    c = integer_offsets(kernel_size)
    cn = c - c.mean(axis=1, keepdims=True)
    lam, v = np.linalg.eigh(cn @ cn.T)
    lam = lam / lam.max()
    return lam, v, int(np.argmax(np.diff(lam)) + 1)


def local_signal(offsets: jax.Array, valid: jax.Array, d: jax.Array, kernel_size: int) -> jax.Array:
    """Voxel counts s_i (N_k,) of one neighbourhood (the paper's local signal, Fig. 2).

    Args:
      offsets: (K, 3) the cube neighbourhood minus the point p_i (padding rows masked).
      valid: (K,) bool.
      d: voxel spacing (scalar).
      kernel_size: k (static).

    Returns:
      (k^3,) counts in the dtype of ``offsets``.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import cubic_kernel
      >>> s = cubic_kernel.local_signal(jnp.array([[0.0, 0, 0], [1, 0, 0]]), jnp.ones(2, bool), 1.0, 3)
      >>> [int(s[j]) for j in (13, 22)]  # centre voxel, voxel +x
      [1, 1]
    """
    o = offsets
    h = (kernel_size - 1) // 2
    # Per-axis slab j of each neighbour (|o - (j - h) d| < d / 2; the slabs are disjoint), then
    # its voxel code (N_k outside the kernel or padding), then the counts by a scatter-add of
    # ones (exact small integers, in any order). On XLA CPU this is 1.5x faster than the
    # contraction over K of the slab memberships, and much faster than comparing the codes
    # with every voxel.
    slab = jnp.zeros(o.shape, jnp.int32)
    found = jnp.zeros(o.shape, bool)
    for j in range(kernel_size):
        hit = jnp.abs(o - (j - h) * d) < d / 2  # (K, 3)
        slab, found = slab + j * hit, found | hit
    inside = valid & found[:, 0] & found[:, 1] & found[:, 2]
    n_k = kernel_size**3
    code = jnp.where(inside, (slab[:, 0] * kernel_size + slab[:, 1]) * kernel_size + slab[:, 2], n_k)  # (K,)
    return jnp.zeros(n_k + 1, o.dtype).at[code].add(1)[:n_k]


def soft_local_signal(offsets: jax.Array, valid: jax.Array, d: jax.Array, tau: jax.Array,
                      kernel_size: int) -> jax.Array:
    """Soft voxel counts (N_k,) of one neighbourhood, the smooth twin of :func:`local_signal`.

    Along each axis a neighbour at offset o belongs to bin j (centre j d) with weight
    sigmoid((o - (j - 1/2) d) / (tau d)) - sigmoid((o - (j + 1/2) d) / (tau d)); its voxel
    membership is the product over x, y, z. As tau -> 0 the weights tend to the hard strict
    membership |o - j d| < d / 2, so the counts tend to :func:`local_signal`'s.

    Args:
      offsets: (K, 3) the neighbourhood minus the point (padding rows masked by ``valid``).
      valid: (K,) bool.
      d: voxel spacing (scalar, traced).
      tau: softness relative to d (scalar > 0, traced).
      kernel_size: odd k (static).

    Returns:
      (k^3,) soft counts, x slowest and z fastest.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import cubic_kernel
      >>> s = cubic_kernel.soft_local_signal(jnp.array([[0.0, 0, 0], [1, 0, 0]]), jnp.ones(2, bool), 1.0, 1e-3, 3)
      >>> [round(float(s[j]), 6) for j in (13, 22)]
      [1.0, 1.0]
    """
    h = (kernel_size - 1) // 2
    faces = jnp.arange(-h, h + 2, dtype=offsets.dtype) - 0.5  # (k + 1,) bin faces in units of d
    cdf = jax.nn.sigmoid(_common.switch_argument(offsets[:, :, None] / d - faces[None, None, :], tau))  # (K, 3, k + 1)
    member = jnp.where(valid[:, None, None], cdf[:, :, :-1] - cdf[:, :, 1:], 0)  # (K, 3, k)
    return jnp.einsum("ki,kj,kl->ijl", member[:, 0], member[:, 1], member[:, 2],
                      precision=jax.lax.Precision.HIGHEST).reshape(-1)


def low_high(s: jax.Array, kernel_size: int) -> tuple[jax.Array, jax.Array]:
    """Split s (N_k,) into (low, high) bands: low = R s / lambda_max, high = s - low.

    This is V diag(lam) V^T s and V diag(1 - lam) V^T s of the paper (Eq. (10) with the
    Haar-like high-pass G_hat = 1 - lam), computed without a basis: exact and
    basis-invariant.

    Args:
      s: (N_k,) local signal.
      kernel_size: k (static).

    Returns:
      (low, high), each (N_k,).

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores import cubic_kernel
      >>> low, high = cubic_kernel.low_high(jnp.zeros(27).at[13].set(1.0), 3)  # symmetric: no low band
      >>> float(jnp.abs(low).max()), float(high[13])
      (0.0, 1.0)
    """
    b, mu = low_band(kernel_size)
    b = jnp.asarray(b, dtype=s.dtype)
    # Reductions over the minor axis only, sums of 3 written out: XLA CPU is slow otherwise.
    w = jnp.sum(b.T * s[None, :], axis=1)  # (3,) = B^T s, exact for integer counts
    low = (b[:, 0] * w[0] + b[:, 1] * w[1] + b[:, 2] * w[2]) / jnp.asarray(mu, dtype=s.dtype)
    return low, s - low


@jax.custom_jvp
def frame(entries) -> jax.Array:
    """Orthonormal eigenvectors (3, 3), as columns, of a symmetric 3 x 3 given by its six entries (Jacobi).

    Their order and signs are whatever :mod:`hgjax.scores.ea` 's Jacobi sweeps give; the
    invariant kernel does not depend on them (:func:`band_energies`). The derivative is
    first-order perturbation theory, dv_k = sum_j v_j (v_j^T dC v_k) / (l_k - l_j), leaving
    out the pairs closer than ``FRAME_GAP`` x trace: exact where the eigenvalues are
    distinct, finite where they are not (there the basis of the eigenspace is arbitrary).

    Args:
      entries: six scalars C[0, 0], C[1, 1], C[2, 2], C[0, 1], C[0, 2], C[1, 2]
        (``_common.PAIRS`` order, as :func:`hgjax.scores._common.centred_entries` gives them).

    Returns:
      (3, 3) orthonormal, in the dtype of ``entries``.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores.cubic_kernel import frame
      >>> v = frame((2.0, 2.0, 5.0, 1.0, 0.0, 0.0))
      >>> bool(jnp.allclose(v.T @ v, jnp.eye(3), atol=1e-6))
      True
    """
    return eigen.rotations(entries, vectors=True)[1]


@frame.defjvp
def _frame_jvp(primals, tangents):
    (entries,), (dc,) = primals, tangents
    lam, vec = eigen.rotations(entries, vectors=True)
    tol = FRAME_GAP * jnp.abs(entries[0] + entries[1] + entries[2])
    cols = []
    for k in range(3):
        dv = jnp.zeros_like(vec[:, k])
        for j in range(3):
            if j != k:
                gap = lam[k] - lam[j]
                far = jnp.abs(gap) > tol
                dv = dv + jnp.where(far, _common.form(dc, vec[:, j], vec[:, k]) / jnp.where(far, gap, 1), 0) * vec[:, j]
        cols.append(dv)
    return vec, jnp.stack(cols, axis=1)


def oriented(offsets: jax.Array, valid: jax.Array, d: jax.Array) -> jax.Array:
    """Offsets (K, 3) in the neighbourhood's local frame: the eigenvectors of its covariance.

    The frame turns with the cloud, so the voxel counts of the turned offsets do not depend
    on the cloud's orientation wherever the covariance's eigenvalues are distinct. Where two
    are equal (e.g. the in-plane ones at the interior of a flat patch) the frame inside
    their eigenspace is the one Jacobi returns: deterministic, but orientation-dependent.

    Args:
      offsets: (K, 3) the neighbourhood minus the point (padding rows masked by ``valid``).
      valid: (K,) bool.
      d: voxel spacing (scalar), the unit in which the covariance is formed.

    Returns:
      (K, 3) offsets @ V, V from :func:`frame` of the scatter of the valid offsets / d.

    Examples:
      >>> import jax.numpy as jnp, numpy as np
      >>> from hgjax.scores.cubic_kernel import oriented
      >>> x = np.random.default_rng(0).normal(size=(20, 3)) * [3.0, 2.0, 1.0]
      >>> q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))  # a rotation (or reflection)
      >>> a, b = (oriented(jnp.asarray(y), jnp.ones(20, bool), 1.0) for y in (x, x @ q.T))
      >>> spread = lambda y: np.sort(np.linalg.norm(np.asarray(y), axis=0))  # per local axis
      >>> bool(np.allclose(spread(a), spread(b), rtol=1e-4))
      True
    """
    v = frame(_common.centred_entries(offsets / d, valid)[1])
    # offsets @ v with its sums of 3 written out: under vmap XLA CPU runs the (K, 3) x (3, 3)
    # product as a batched dot, slower than the rest of the kernel.
    return jnp.stack([offsets[:, 0] * v[0, j] + offsets[:, 1] * v[1, j] + offsets[:, 2] * v[2, j] for j in range(3)],
                     axis=1)


def kernel_signal(offsets: jax.Array, valid: jax.Array, d: jax.Array, kernel_size: int, variant: str,
                  tau: jax.Array | None = None) -> jax.Array:
    """The kernel's voxel counts (N_k,) of one neighbourhood, in its local frame for ``"invariant"``.

    :func:`local_signal` (or :func:`soft_local_signal` with ``tau``) of the offsets, first
    turned by :func:`oriented` in the invariant variant; the reference variant keeps the
    axis-aligned cube.
    """
    if variant == "invariant":
        offsets = oriented(offsets, valid, d)
    if tau is None:
        return local_signal(offsets, valid, d, kernel_size)
    return soft_local_signal(offsets, valid, d, tau, kernel_size)


def band_energies(s: jax.Array, kernel_size: int, variant: str) -> tuple[jax.Array, jax.Array]:
    """Squared high- and low-band norms (||high||^2, ||low||^2) of a voxel signal s (N_k,).

    * ``"reference"``: of the projections of Eq. (10) (:func:`low_high`).
    * ``"invariant"``: averaged over the kernel's orientations in the local frame. The low
      band is span{C w : w orthogonal to (1, 1, 1)} (row-centred centres), so it depends on
      the signs of the frame's axes (not on their order): the 8 sign choices average its
      projector to (2/3) C C^T / m (C^T C = m I), whence ||low||^2 = (2/3) ||C^T s||^2
      / m and ||high||^2 = ||s||^2 - ||low||^2. No sign or order convention of the frame
      matters, and low is 0 exactly for signals symmetric about the centre, as in Eq. (10).

    Args:
      s: (N_k,) local signal.
      kernel_size: k (static).
      variant: ``"invariant"`` or ``"reference"`` (static).

    Returns:
      (high2, low2), scalars >= 0 (high2 up to rounding).

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores.cubic_kernel import band_energies
      >>> [float(e) for e in band_energies(jnp.ones(27), 3, "invariant")]  # symmetric: no low band
      [27.0, 0.0]
    """
    if variant == "reference":
        low, high = low_high(s, kernel_size)
        return jnp.sum(high * high), jnp.sum(low * low)
    c = integer_offsets(kernel_size)
    m = float(np.sum(c[:, 0] ** 2))
    c = jnp.asarray(c, dtype=s.dtype)
    w = jnp.sum(c.T * s[None, :], axis=1)  # (3,) C^T s, exact for integer counts
    low2 = (2.0 / 3.0) * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) / m
    return jnp.maximum(jnp.sum(s * s) - low2, 0), low2


