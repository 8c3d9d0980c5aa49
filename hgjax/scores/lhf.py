"""Local hypergraph filtering (LHF), paper Sec. III-C, Algorithm 3, Eqs. (13)-(16).

For each point p_i and a length n, the local signal is s (n, 3) = the n nearest points of
p_i (p_i itself first) minus p_i (Eq. (13)); its first row is 0. Its spectrum comes from
R = s_n s_n^T (n, n) with s_n the row-centred signal; t = argmax(diff(lam)) + 1 splits the
high band (the first t components) from the low band. The single-length sharpness is

* ``variant="reference"`` (Eq. (14), REFERENCE.md): gamma = sum_{j<t,k} |T[j, k]| /
  sum_{j,k} |T[j, k]| with T = V^T s, through a batched n x n ``eigh``. R has rank <= 2, so
  the high band contains an (n - 2)-dimensional degenerate eigenspace and the L1 ratio
  depends on the basis the eigensolver returns there.
* ``variant="invariant"`` (default): gamma = ||P_high s||_F / (||P_high s||_F +
  ||P_low s||_F), the L1 norm of the two band energies. It is computed from the 3 x 3 Gram
  matrix G = s_n^T s_n, whose non-zero eigenpairs (mu_k, w_k) give those of R
  (u_k = s_n w_k / sqrt(mu_k)), plus an explicit projection onto the null space. Since
  s_n 1 = 0, that Gram reduces to a 2 x 2 one solved in closed form. No n x n
  eigendecomposition, no LAPACK call, no basis dependence. ``solver="eigh"`` computes the same number through the n x n ``eigh`` (the
  tests prove the two agree).

Two lengths (N_a, N_b) are combined (Eqs. (15)-(16)): gamma_i = eps gamma_a + (1 - eps)
gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b), Gamma the value at the top-ratio fraction
of each sorted gamma (the paper's definition, not the reference code's arbitrary element).
Higher gamma means sharper; resampling keeps the largest.

Degenerate neighbourhoods: duplicates and collinear or coplanar points give finite gamma in
[0, 1]; a signal with no structure at all (every row of s constant, e.g. all points equal)
gives gamma = 0.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbourhoods import SpatialIndex
from hgjax.scores import _common
from hgjax import spectrum

__all__ = ["DEFAULT_LENGTHS", "combine", "lhf", "lhf_neighbourhood", "lhf_single"]

DEFAULT_LENGTHS = (4, 8)
SOLVERS = ("eigh", "gram")


def _reference(s):
    """Eq. (14) through the n x n eigh (L1 over the eigensolver's basis)."""
    lam, v = spectrum.estimate_spectrum(s)
    t = spectrum.band_threshold(lam)
    l1_high, l1_total, _, _ = spectrum.band_energies(v, t, s)
    return _common.safe_div(l1_high, l1_total, 0.0)


def _invariant_eigh(s):
    """Band-energy ratio through the n x n eigh (proof path for the Gram solver)."""
    lam, v = spectrum.estimate_spectrum(s)
    t = spectrum.band_threshold(lam)
    _, _, high, low = spectrum.band_energies(v, t, s)
    return _common.band_ratio(high * high, low * low)


# Orthonormal basis (3, 2) of the plane orthogonal to (1, 1, 1): row-centring projects onto it.
_PLANE = np.array([[1 / np.sqrt(2), 1 / np.sqrt(6)], [-1 / np.sqrt(2), 1 / np.sqrt(6)], [0.0, -2 / np.sqrt(6)]])


def _invariant_gram(s):
    """Band-energy ratio through a closed-form 2 x 2 Gram eigenproblem (no LAPACK call).

    Row-centring is the projection of each row onto the plane orthogonal to (1, 1, 1), so
    s_n = y Q^T with y = s Q (n, 2) and Q the fixed orthonormal basis of that plane. The
    non-zero eigenpairs of R = s_n s_n^T = y y^T are those of the 2 x 2 Gram y^T y: its
    eigenvector angle is 0.5 atan2(2b, a - c), the eigenvectors of R are z_k / ||z_k|| with
    z_k = y w_k, and mu_k = ||z_k||^2. The null-space part of s is the residual of the row
    means m after projection onto span(z_1, z_2), the same for all three columns.
    """
    n = s.shape[0]
    q = _PLANE
    # Small products written out elementwise: XLA fuses them, batched dots of this size are slow.
    y0 = s[:, 0] * q[0, 0] + s[:, 1] * q[1, 0]
    y1 = s[:, 0] * q[0, 1] + s[:, 1] * q[1, 1] + s[:, 2] * q[2, 1]
    y = jnp.stack([y0, y1], axis=1)  # (n, 2) = s Q
    a, c, b = jnp.sum(y[:, 0] * y[:, 0]), jnp.sum(y[:, 1] * y[:, 1]), jnp.sum(y[:, 0] * y[:, 1])
    iso = (a == c) & (b == 0)  # isotropic in the plane (or empty): any basis; keep grads finite
    theta = 0.5 * jnp.arctan2(jnp.where(iso, 0, 2 * b), jnp.where(iso, 1, a - c))
    cos, sin = jnp.cos(theta), jnp.sin(theta)
    w = jnp.stack([jnp.stack([-sin, cos]), jnp.stack([cos, sin])], axis=1)  # (2, 2): small, large
    z = jnp.stack([y0 * w[0, 0] + y1 * w[1, 0], y0 * w[0, 1] + y1 * w[1, 1]], axis=1)  # (n, 2) = y w
    mu = jnp.sum(z * z, axis=0)  # (2,) eigenvalues of R: mu[0] <= mu[1] up to rounding
    top = jnp.maximum(mu[0], mu[1])
    nonzero = mu > 8 * n * jnp.finfo(s.dtype).eps * top
    inv = jnp.where(nonzero, 1 / _common.safe_sqrt(jnp.where(nonzero, mu, 1)), 0)
    u = z * inv[None, :]  # (n, 2) orthonormal eigenvectors of R (zero columns if null)
    m = jnp.mean(s, axis=1)  # (n,) row means: s = s_n + m 1^T
    proj = jnp.sum(u[:, :, None] * s[:, None, :], axis=0)  # (2, 3) = u^T s
    band2 = jnp.sum(proj * proj, axis=1)  # (2,) energy of s on each eigenvector
    res = m - jnp.sum(u * jnp.sum(u * m[:, None], axis=0)[None, :], axis=1)  # null-space part of s
    null2 = 3 * jnp.sum(res * res)
    # Normalised spectrum: [0]*(n-2), mu1/mu2, 1. The high band takes the mu1 direction
    # when the gap 0 -> mu1/mu2 is smaller than the gap mu1/mu2 -> 1 (argmax picks the first).
    r = _common.safe_div(jnp.minimum(mu[0], mu[1]), top, 0.0)
    small = jnp.where(mu[0] <= mu[1], 0, 1)
    small2, large2 = band2[small], band2[1 - small]
    mu1_high = r < 0.5
    high2 = null2 + jnp.where(mu1_high, small2, 0)
    low2 = large2 + jnp.where(mu1_high, 0, small2)
    return jnp.where(top > 0, _common.band_ratio(high2, low2), 0.0)


def lhf_neighbourhood(centre, nbrs, valid, *, lengths=DEFAULT_LENGTHS, variant: str = "invariant",
                      solver: str = "gram"):
    """gamma (Eq. (14)) of one k-nearest neighbourhood for each length.

    Args:
      centre: (3,) the point.
      nbrs: (K, 3) the point itself then its neighbours by distance, K >= max(lengths).
      valid: (K,) bool (unused for full kNN rows; padding rows give gamma = 0).
      lengths: tuple of lengths n (static), each counting the point itself.
      variant: ``"invariant"`` or ``"reference"`` (static).
      solver: ``"gram"`` or ``"eigh"`` for the invariant variant (static).

    Returns:
      (len(lengths),) gamma in [0, 1].

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> nbrs = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]])
      >>> g = hgjax.scores.lhf_neighbourhood(jnp.zeros(3), nbrs, jnp.ones(4, bool), lengths=(3, 4))
      >>> g.shape
      (2,)
    """
    signal = jnp.where(valid[:, None], nbrs - centre[None, :], 0)
    if variant == "reference":
        fn = _reference
    else:
        fn = _invariant_gram if solver == "gram" else _invariant_eigh
    out = []
    for n in lengths:
        # Serialise the lengths: two batched LAPACK eigh calls running concurrently inside one
        # XLA CPU program can deadlock in jaxlib's thread pool (seen with jax 0.10.2).
        signal = jax.lax.optimization_barrier((signal, out))[0] if out else signal
        out.append(fn(signal[:n]))
    return jnp.stack(out)


@functools.lru_cache(maxsize=None)
def _chunk_kernel(lengths, variant, solver):
    fn = functools.partial(lhf_neighbourhood, lengths=lengths, variant=variant, solver=solver)
    return jax.jit(_common.map_neighbourhoods(fn))


def _check_length(n, name):
    return _validate.check_int(n, name, minimum=3)


def _single_lengths(points, lengths, variant, solver, chunk_size, progress):
    """(N, len(lengths)) single-length gammas in the caller's order."""
    pts = _validate.check_points(points)
    variant = _common.check_variant(variant)
    _validate.check_choice(solver, "solver", SOLVERS)
    k = max(lengths)
    _validate.check_min_points(pts.shape[0], k, f"LHF with length {k}")
    index = SpatialIndex(pts)
    per_point = 8 * k * k * 3 if (variant == "reference" or solver == "eigh") else 8 * k * 16
    chunk = _common.chunk_size_or_auto(chunk_size, index.n, per_point)
    out = _stream.stream(_chunk_kernel(tuple(lengths), variant, solver), index,
                         lambda rows: index.knn(k, rows), chunk_size=chunk, progress=progress)
    return _common.finish(index, out, pts.dtype)


def lhf_single(points, length: int, *, variant: str = "invariant", solver: str = "gram",
               chunk_size: int | None = None, progress: bool = False) -> np.ndarray:
    """Single-length LHF sharpness gamma (paper Eq. (14)); higher is sharper.

    Args:
      points: (N, 3) float32 or float64.
      length: n >= 3, the number of points in the local signal counting the point itself
        (static: a new value compiles a new kernel).
      variant: ``"invariant"`` (default) or ``"reference"``; see the module docstring.
      solver: ``"gram"`` (default, 3 x 3) or ``"eigh"`` (n x n) for the invariant variant.
      chunk_size: points per streamed chunk (default: automatic). Does not change results.
      progress: show a progress bar on stderr for long runs.

    Returns:
      (N,) gamma in [0, 1], in the dtype of ``points``.

    Raises:
      TypeError, ValueError: invalid input, N < length, unknown variant or solver.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((100, 3))
      >>> g = hgjax.scores.lhf_single(pts, 6)
      >>> g.shape, bool(((g >= 0) & (g <= 1)).all())
      ((100,), True)
    """
    length = _check_length(length, "length")
    return _single_lengths(points, (length,), variant, solver, chunk_size, progress)[:, 0]


def combine(gamma_a, gamma_b, ratio: float):
    """Combine two single-length gammas (paper Eqs. (15)-(16)).

    Args:
      gamma_a, gamma_b: (N,) single-length sharpness values.
      ratio: the resampling ratio alpha in (0, 1].

    Returns:
      (N,) eps gamma_a + (1 - eps) gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b), where
      Gamma is the ceil(alpha N)-th largest value of each (0.5 when both Gammas are 0).

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.scores.lhf_combine(np.array([0.2, 0.4]), np.array([0.1, 0.3]), 0.5).round(3).tolist()
      [0.143, 0.343]
    """
    ratio = _validate.check_ratio(ratio)
    ga, gb = np.asarray(gamma_a), np.asarray(gamma_b)
    m = _validate.n_keep(ga.shape[0], ratio)
    big_a = np.partition(ga, ga.shape[0] - m)[ga.shape[0] - m]
    big_b = np.partition(gb, gb.shape[0] - m)[gb.shape[0] - m]
    total = big_a + big_b
    eps = big_b / total if total > 0 else ga.dtype.type(0.5)
    return (eps * ga + (1 - eps) * gb).astype(ga.dtype)


def lhf(points, *, ratio: float, lengths=DEFAULT_LENGTHS, variant: str = "invariant",
        solver: str = "gram", chunk_size: int | None = None, progress: bool = False) -> np.ndarray:
    """Combined LHF sharpness gamma per point (paper Eqs. (14)-(16)); higher is sharper.

    Args:
      points: (N, 3) float32 or float64, N >= max(lengths).
      ratio: resampling ratio alpha in (0, 1]; sets the weight eps (Eq. (16)).
      lengths: (N_a, N_b), each >= 3 and counting the point itself. Default (4, 8): the best
        of (4, 8) ... (16, 32) on the edge benchmark (bench/results/edge_defaults.md). Static: new values compile a new kernel.
      variant: ``"invariant"`` (default) or ``"reference"``; see the module docstring.
      solver: ``"gram"`` (default) or ``"eigh"`` for the invariant variant.
      chunk_size: points per streamed chunk (default: automatic). Does not change results.
      progress: show a progress bar on stderr for long runs.

    Returns:
      (N,) gamma in [0, 1], in the dtype of ``points``.

    Raises:
      TypeError, ValueError: invalid input, ratio outside (0, 1], N < max(lengths), bad
        lengths, unknown variant or solver.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((100, 3))
      >>> hgjax.scores.lhf(pts, ratio=0.2).shape
      (100,)
    """
    ratio = _validate.check_ratio(ratio)
    if not isinstance(lengths, (tuple, list)) or len(lengths) != 2:
        raise ValueError(f"lengths must be a pair (N_a, N_b); got {lengths!r}")
    lengths = (_check_length(lengths[0], "lengths[0]"), _check_length(lengths[1], "lengths[1]"))
    g = _single_lengths(points, lengths, variant, solver, chunk_size, progress)
    return combine(g[:, 0], g[:, 1], ratio)
