"""Local hypergraph filtering (LHF), paper Sec. III-C, Algorithm 3, Eqs. (13)-(16).

For each point p_i and a length n, the local signal is s (n, 3) = the n nearest points of
p_i (p_i itself first) minus p_i (Eq. (13)); its first row is 0. Its spectrum comes from
R = s_n s_n^T (n, n) with s_n the row-centred signal; t = argmax(diff(lam)) + 1 splits the
high band (the first t components) from the low band. The single-length sharpness is

* ``variant="reference"`` (Eq. (14), REFERENCE.md): gamma = sum_{j<t,k} |T[j, k]| /
  sum_{j,k} |T[j, k]| with T = V^T s, through a batched n x n ``eigh``. R has rank <= 2, so
  the high band contains an (n - 2)-dimensional degenerate eigenspace and the L1 ratio
  depends on the basis the eigensolver returns there.
* ``variant="invariant"`` (default): Eq. (14) with the eigensolver's basis averaged out.
  For x in a d-dimensional eigenspace E, the expected L1 norm of its coordinates in a
  uniformly (Haar) random orthonormal basis of E is d c_d ||x||_2, with c_d = E|v_1| =
  Gamma(d/2) / (sqrt(pi) Gamma((d + 1)/2)) for v uniform on the sphere S^{d-1} (c_1 = 1: a
  1-D eigenspace gives |u^T x| exactly). Summing over the columns s_k and the eigenspaces
  E of each band,

      A_band = sum_{E in band} d_E c_{d_E} sum_k ||P_E s_k||_2,   gamma = A_high / (A_high + A_low),

  the ratio of the expectations of Eq. (14)'s numerator and denominator over random bases
  inside every eigenspace (not the expectation of the ratio; for n = 3 every eigenspace is
  1-D and gamma equals the reference). The eigenspaces of R are its null space (dimension
  d = n - rank(R), always in the high band; since s = s_n + m 1^T with m the row means,
  P_null s has the same column res for k = 1, 2, 3) and the eigenvectors u1, u2 of
  mu1 <= mu2, or one 2-D eigenspace when mu1 = mu2 (to 8 n eps).
  Why: the edge signal of Eq. (14) is res, the residual of the row means after a
  least-squares fit on the in-plane coordinates (a plane fit through p_i). The L1 norm
  weighs it by 3 d c_d against the 1-D terms; Frobenius band norms ||P_band s||_F (the
  previous definition of this variant) weigh it by sqrt(3) only, and the in-plane spread
  along u1 then dominates. On the edge benchmark (F1 at ratio 0.2, 12 shapes, lengths
  (4, 8) and (6, 12), noise p <= 0.2, axis-aligned and rotated) band norms ranked barely
  above uniform sampling, while this definition scores above the reference variant in every
  setting and on the three labelled real clouds (MCC). At p >= 0.5 every LHF variant is
  near uniform.
  Computed from the 3 x 3 Gram matrix G = s_n^T s_n, whose non-zero eigenpairs (mu_k, w_k)
  give those of R (u_k = s_n w_k / sqrt(mu_k)), plus an explicit projection onto the null
  space. Since s_n 1 = 0, that Gram reduces to a 2 x 2 one solved in closed form. No n x n
  eigendecomposition, no LAPACK call, no basis dependence. ``solver="eigh"`` computes the
  same number through the n x n ``eigh`` (the tests prove the two agree).

Two lengths (N_a, N_b) are combined (Eqs. (15)-(16)): gamma_i = eps gamma_a + (1 - eps)
gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b), Gamma the value at the top-ratio fraction
of each sorted gamma (the paper's definition, not the reference code's arbitrary element).
Higher gamma means sharper; resampling keeps the largest.

Degenerate neighbourhoods: duplicates and collinear or coplanar points give finite gamma in
[0, 1]; a signal with no structure at all (every row of s constant, e.g. all points equal)
gives gamma = 0. The invariant gamma jumps where an eigenspace changes dimension (rank(R)
drops, mu1 meets mu2), as the band threshold t already does at mu1 / mu2 = 1/2; the smooth
twin :func:`soft_gamma` shares :func:`gram_bands` and blends across the last two.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate, spatial, spectrum
from hgjax.scores import _common

__all__ = ["DEFAULT_LENGTHS", "combine", "gamma", "neighbourhoods", "score", "single", "soft_gamma", "soft_score"]

# The only pair of (3, 6) ... (12, 24) within 0.05 of the best pair in each regime of the defaults
# study (grid and random synthetic clouds: F1/best; labelled real clouds: MCC), with no rule on the
# data needed: bench/results/edge_defaults.md.
DEFAULT_LENGTHS = (8, 16)
SOLVERS = ("eigh", "gram")


def _reference(s):
    """Eq. (14) through the n x n eigh (L1 over the eigensolver's basis)."""
    lam, v = spectrum.estimate_spectrum(s)
    t = spectrum.band_threshold(lam)
    l1_high, l1_total, _, _ = spectrum.band_energies(v, t, s)
    return _common.safe_div(l1_high, l1_total, 0.0)


def _haar_l1_factor(d: int) -> float:
    """d c_d: expected L1 norm of a unit vector's coordinates in a Haar-random basis of R^d."""
    return d * math.exp(math.lgamma(d / 2) - math.lgamma((d + 1) / 2)) / math.sqrt(math.pi) if d else 0.0


def _null_factor(rank, n, dtype):
    """d c_d for the null space of R, d = n - rank with a traced rank in {0, 1, 2}."""
    return jnp.asarray([_haar_l1_factor(n - r) for r in range(3)], dtype=dtype)[rank]


def _row_sum(x):
    """Sum over the last axis, written out as adds for short axes (XLA CPU reductions are slow there)."""
    if x.shape[-1] > 32:
        return jnp.sum(x, axis=-1)
    out = x[..., 0]
    for j in range(1, x.shape[-1]):
        out = out + x[..., j]
    return out


def _degeneracy_tol(n, dtype):
    """Relative eigenvalue tolerance for 'zero' and 'equal' (both solvers use it)."""
    return 8 * n * jnp.finfo(dtype).eps


def _invariant_eigh(s):
    """Haar-expected L1 band ratio through the n x n eigh (proof path for the Gram solver).

    Eigenspaces from the normalised eigenvalues: the first d = n - rank columns (null
    space), then the last two separately, or together when they are equal.
    """
    n = s.shape[0]
    lam, v = spectrum.estimate_spectrum(s)
    t = spectrum.band_threshold(lam)
    coef = spectrum.hgft(v, s)  # (n, 3)
    tol = _degeneracy_tol(n, lam.dtype)
    rank = jnp.sum(lam > tol)  # <= 2: only the last two eigenvalues can be non-zero
    j = jnp.arange(n)
    null = j < n - rank
    null_norms = _common.safe_sqrt(jnp.sum(jnp.where(null[:, None], coef * coef, 0), axis=0))  # (3,)
    null_l1 = _null_factor(rank, n, s.dtype) * jnp.sum(null_norms)
    a = jnp.sum(jnp.abs(coef), axis=1)  # (n,) L1 on each eigenvector: exact for 1-D eigenspaces
    high_1d = jnp.sum(jnp.where(~null & (j < t), a, 0))
    low_1d = jnp.sum(jnp.where(~null & (j >= t), a, 0))
    # mu1 = mu2: one 2-D eigenspace, in the low band (its normalised eigenvalue is 1).
    equal = (rank == 2) & (lam[n - 1] - lam[n - 2] <= tol)
    pair = _haar_l1_factor(2) * jnp.sum(_common.safe_sqrt(coef[n - 2] ** 2 + coef[n - 1] ** 2))
    high = null_l1 + jnp.where(equal, 0, high_1d)
    low = jnp.where(equal, pair, low_1d)
    return jnp.where(rank > 0, _common.safe_div(high, high + low, 0.0), 0.0)


# Orthonormal basis (3, 2) of the plane orthogonal to (1, 1, 1): row-centring projects onto it.
_PLANE = np.array([[1 / np.sqrt(2), 1 / np.sqrt(6)], [-1 / np.sqrt(2), 1 / np.sqrt(6)], [0.0, -2 / np.sqrt(6)]])


class GramBands(NamedTuple):
    """Haar-expected L1 sums of Eq. (14) over the eigenspaces of R for one signal (scalars).

    Built by :func:`gram_bands`, combined into gamma by :func:`band_l1_ratio`.
    """

    null: jax.Array  #: 3 d c_d ||res||: the null space of R (d = n - rank(R)), always high band.
    small: jax.Array  #: sum_k |u1^T s_k|: the mu1 direction (0 when mu1 is null).
    large: jax.Array  #: sum_k |u2^T s_k|: the mu2 direction, always low band.
    pair: jax.Array  #: 2 c_2 sum_k ||P s_k||, P onto span(u1, u2) = range(R) as one 2-D eigenspace.
    ratio: jax.Array  #: mu1 / mu2 in [0, 1], the middle normalised eigenvalue (0 when R = 0).
    equal: jax.Array  #: bool, mu1 = mu2 != 0 to the degeneracy tolerance.
    top: jax.Array  #: mu2 = max eigenvalue of R; 0 for a signal without structure.


def gram_bands(s, *, unrolled: bool = True) -> GramBands:
    """Eigenspace L1 sums of the invariant LHF (Eq. (14)) through a closed-form 2 x 2 Gram.

    Row-centring is the projection of each row onto the plane orthogonal to (1, 1, 1), so
    s_n = y Q^T with y = s Q (n, 2) and Q the fixed orthonormal basis of that plane. The
    non-zero eigenpairs of R = s_n s_n^T = y y^T are those of the 2 x 2 Gram G = y^T y: with
    G w_k = mu_k w_k, the eigenvectors of R are u_k = z_k / ||z_k||, z_k = y w_k, and mu_k =
    ||z_k||^2. The null-space part of s is the residual res of the row means m after
    projection onto span(z_1, z_2), the same for all three columns, so the null space
    contributes 3 d c_d ||res||. No LAPACK call.

    Three passes over the n rows, each one fused loop with its sums written out:
    1. G and vm = y^T m, which give w_k in closed form and mu_l, u_l^T s_k;
    2. z_s = y w_s, which gives mu_s = ||z_s||^2 and u_s^T s_k. From G, mu_s would be a
       difference of O(mu_l) terms (relative error ~eps mu_l / mu_s); summed, it is not;
    3. res = m - y g with g = G^+ vm the plane-fit coefficients of m (explicit, so no
       cancellation when res is small).
    Autodiff gives the true derivatives; where G is isotropic to rounding the eigenvectors
    are any basis with zero derivative, which only the basis-dependent 1-D sums see (the
    pair and null sums go through G^{-1} there). s is first scaled by a power of two and
    everything is computed in its dtype.

    Shared by the hard kernel (``variant="invariant"``) and the smooth LHF of
    :func:`soft_gamma`, which differ only in the weights passed to :func:`band_l1_ratio`.

    Args:
      s: (n, 3) local signal (Eq. (13)).
      unrolled: sums over the n rows written out as adds (the hard kernel) or as reductions
        (the differentiated soft path: value_and_grad through the written-out adds compiled
        7x slower than its forward; bench/results/compile_grad.md). Static.

    Returns:
      :class:`GramBands` of scalars in the dtype of ``s``, for s scaled by a power of two
      (only their ratios are meaningful).
    """
    n = s.shape[0]
    info = jnp.finfo(s.dtype)
    row_sum = _row_sum if unrolled else functools.partial(jnp.sum, axis=-1)
    # gamma is scale-free: scale s by a power of two to max|s| in [1/2, 1). Exact, so every
    # rounding below scales with it; squares and 1 / det then neither underflow nor overflow.
    s = _common.unit_scale(s)
    q = jnp.asarray(_PLANE, s.dtype)  # NumPy float64 scalars would promote a float32 s under x64
    # Small products written out elementwise: XLA fuses them, batched dots of this size are slow.
    x0, x1, x2 = s[:, 0], s[:, 1], s[:, 2]
    y0 = x0 * q[0, 0] + x1 * q[1, 0]  # y = s Q (n, 2); Q[2, 0] = 0
    y1 = x0 * q[0, 1] + x1 * q[1, 1] + x2 * q[2, 1]
    m = (x0 + x1 + x2) / 3  # (n,) row means: s = s_n + m 1^T

    # Pass 1: G = [[a, b], [b, c]] and vm; y^T s = y^T s_n + vm 1^T = G Q^T + vm 1^T.
    a, c, b, vm0, vm1 = (row_sum(u * v) for u, v in ((y0, y0), (y1, y1), (y0, y1), (y0, m), (y1, m)))
    # Eigenvectors of G in closed form: with d = (a - c) / 2, r = sqrt(d^2 + b^2) and rho =
    # b / (r + |d|) (|rho| <= 1), w_l = (1, rho) for d >= 0 and (rho, 1) for d < 0, normalised;
    # w_s = w_l turned by 90 degrees. Everything below is invariant to the sign of w. No
    # trigonometry: XLA CPU would recompute it in every fusion that reads the angle.
    # Isotropic to rounding (r <= eps (a + c), or r^2 so small that its derivatives, ~1 / r^2,
    # would overflow): w_l = (1, 0) with zero derivative; then mu_s = mu_l to the degeneracy
    # tolerance and only the pair and null sums, which do not use w, count.
    d = (a - c) / 2
    r2 = d * d + b * b
    iso = r2 <= jnp.maximum(jnp.square(info.eps * (a + c)), jnp.sqrt(info.tiny))
    rho = jnp.where(iso, 0, b / (jnp.sqrt(jnp.where(iso, 1, r2)) + jnp.abs(d)))
    k = jax.lax.rsqrt(1 + rho * rho)
    first = (d >= 0) | iso
    cos = jnp.where(first, 1, rho) * k  # w_l = (cos, sin), w_s = (-sin, cos)
    sin = jnp.where(first, rho, 1) * k
    mu_l = a * cos * cos + 2 * b * sin * cos + c * sin * sin  # w_l^T G w_l
    tol = _degeneracy_tol(n, s.dtype)
    nz_l = mu_l > 0
    inv_l = jnp.where(nz_l, 1 / jnp.where(nz_l, mu_l, 1), 0)
    # u_l^T s_k = w_l^T vy_k / sqrt(mu_l) = sqrt(mu_l) w_l^T q_k + w_l^T vm / sqrt(mu_l) (q_k row k of Q)
    vm_l = cos * vm0 + sin * vm1
    p_l = _common.safe_sqrt(mu_l) * (cos * q[:, 0] + sin * q[:, 1]) + vm_l * _common.safe_sqrt(inv_l)  # (3,)

    # Pass 2: z_s = y w_s.
    z_s = cos * y1 - sin * y0
    mu_s, vm_s, zx0, zx1, zx2 = (row_sum(z_s * v) for v in (z_s, m, x0, x1, x2))
    top = jnp.maximum(mu_s, mu_l)
    nz_s = mu_s > tol * top
    inv_s = jnp.where(nz_s, 1 / jnp.where(nz_s, mu_s, 1), 0)
    p_s = jnp.stack([zx0, zx1, zx2]) * _common.safe_sqrt(inv_s)  # (3,) u_s^T s_k, 0 if null
    ratio = _common.safe_div(jnp.minimum(mu_s, mu_l), top, 0.0)
    # Projections onto range(R) (pair, null), invariant to the basis. For ratio >= 1/2
    # (cond(G) <= 2) they go through G^{-1} = adj(G) / det instead of the eigenvectors: the
    # eigenvectors' derivatives grow like 1 / (mu_l - mu_s), and their rounding would swamp
    # the gradients near mu_s = mu_l. Below 1/2 the gap is >= mu_l / 2 and the eigenvectors
    # are the well-conditioned route (G^{-1} is not, as mu_s -> 0).
    near = ratio >= 0.5
    inv_det = 1 / jnp.where(near, a * c - b * b, 1)
    vy0 = a * q[:, 0] + b * q[:, 1] + vm0  # (3,) y_0^T s_k
    vy1 = b * q[:, 0] + c * q[:, 1] + vm1  # (3,) y_1^T s_k
    quad = (c * vy0 * vy0 - 2 * b * vy0 * vy1 + a * vy1 * vy1) * inv_det  # (3,) ||P s_k||^2
    norms = jnp.where(near, quad, p_s * p_s + p_l * p_l)  # (3,) ||P s_k||^2
    f_s, f_l = inv_s * vm_s, inv_l * vm_l  # (w^T vm) / mu (vm_s = z_s^T m = w_s^T vm)
    g0 = jnp.where(near, (c * vm0 - b * vm1) * inv_det, cos * f_l - sin * f_s)
    g1 = jnp.where(near, (a * vm1 - b * vm0) * inv_det, sin * f_l + cos * f_s)

    # Pass 3: res = m - y g = P_null s_k, the same for k = 1, 2, 3.
    res = m - (y0 * g0 + y1 * g1)
    rank = nz_s.astype(jnp.int32) + nz_l.astype(jnp.int32)
    first_small = mu_s <= mu_l
    l1_s, l1_l = row_sum(jnp.abs(p_s)), row_sum(jnp.abs(p_l))  # L1 over the 3 columns
    return GramBands(
        null=3 * _null_factor(rank, n, s.dtype) * _common.safe_sqrt(row_sum(res * res)),
        small=jnp.where(first_small, l1_s, l1_l),
        large=jnp.where(first_small, l1_l, l1_s),
        pair=_haar_l1_factor(2) * row_sum(_common.safe_sqrt(norms)),
        ratio=ratio,
        equal=nz_s & (jnp.abs(mu_l - mu_s) <= tol * top),
        top=top,
    )


def band_l1_ratio(bands: GramBands, high, pair):
    """gamma = A_high / (A_high + A_low) of the invariant LHF from weighted eigenspace sums.

    A_high = null + (1 - pair) high small and A_low = pair pair_sum + (1 - pair) (large +
    (1 - high) small): ``high`` is the high-band weight of the mu1 direction, ``pair`` the
    weight of counting span(u1, u2) as one 2-D eigenspace. The hard kernel passes the 0/1
    steps (mu1 / mu2 < 1/2: t = argmax(diff(lam)) + 1 puts mu1 in the high band) and
    ``bands.equal``; :func:`soft_gamma` passes smooth switches of ``bands.ratio``.

    Args:
      bands: :class:`GramBands` from :func:`gram_bands`.
      high: weight in [0, 1] (scalar, in the dtype of the bands).
      pair: weight in [0, 1] (scalar, in the dtype of the bands).

    Returns:
      Scalar gamma in [0, 1]; 0 for a signal without structure (R = 0).
    """
    keep = 1 - pair
    a_high = bands.null + keep * (high * bands.small)
    a_low = pair * bands.pair + keep * (bands.large + (1 - high) * bands.small)
    return jnp.where(bands.top > 0, _common.safe_div(a_high, a_high + a_low, 0.0), 0.0)


def _invariant_gram(s):
    """Haar-expected L1 band ratio through :func:`gram_bands` with the hard band switches."""
    bands = gram_bands(s)
    dtype = bands.top.dtype
    return band_l1_ratio(bands, (bands.ratio < 0.5).astype(dtype), bands.equal.astype(dtype))


def gamma(offsets, valid, *, lengths=DEFAULT_LENGTHS, variant: str = "invariant", solver: str = "gram"):
    """gamma (Eq. (14)) of one k-nearest neighbourhood for each length.

    Args:
      offsets: (K, 3) the point itself (a zero row) then its neighbours by distance, minus
        the point; K >= max(lengths).
      valid: (K,) bool (padding rows count as zero offsets).
      lengths: tuple of lengths n (static), each counting the point itself.
      variant: ``"invariant"`` or ``"reference"`` (static).
      solver: ``"gram"`` or ``"eigh"`` for the invariant variant (static).

    Returns:
      (len(lengths),) gamma in [0, 1].

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> offsets = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]])
      >>> hgjax.scores.lhf.gamma(offsets, jnp.ones(4, bool), lengths=(3, 4)).shape
      (2,)
    """
    signal = jnp.where(valid[:, None], offsets, 0)
    if variant == "reference":
        fn = _reference
    else:
        fn = _invariant_gram if solver == "gram" else _invariant_eigh
    return jnp.stack([fn(signal[:n]) for n in lengths])


def soft_gamma(offsets, valid, tau, *, lengths=DEFAULT_LENGTHS):
    """Smooth LHF sharpness gamma (Eq. (14)) of one k-nearest neighbourhood for each length.

    The invariant (Haar-expected L1) gamma, with the eigenspace sums of :func:`gram_bands`
    (shared with the hard kernel) combined by :func:`band_l1_ratio` with smooth switches of
    r = mu1 / mu2 instead of the hard steps:

    * band: the mu1 direction is high band with weight sigmoid((1/2 - r) / tau);
    * pair: u1, u2 count as one 2-D eigenspace (Haar factor 4 / pi) with weight
      q = exp(-((1 - r) / tau)^2). The 1-D terms |u_k^T s| turn with the eigenvectors, whose
      derivative grows like 1 / (mu2 - mu1); since 1 - q = O((1 - r)^2), gamma and its
      gradient stay continuous at mu1 = mu2, where the hard gamma jumps.

    gamma still jumps where rank(R) drops (collinear signals, or a plane containing the
    direction (1, 1, 1)); gradients stay finite there.

    Args:
      offsets, valid: as :func:`gamma`.
      tau: softness of the switches on r (scalar > 0, traced); tau -> 0 gives the hard
        invariant gamma except for r within a few tau of 1/2 or 1.
      lengths: tuple of lengths n (static).

    Returns:
      (len(lengths),) gamma in [0, 1]; higher is sharper. Gradients are finite on
      duplicate, collinear, coplanar and symmetric neighbourhoods.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> offsets = jnp.zeros((8, 3))  # all points equal: no structure
      >>> hgjax.scores.lhf.soft_gamma(offsets, jnp.ones(8, bool), 0.05, lengths=(4, 8)).tolist()
      [0.0, 0.0]
    """
    signal = jnp.where(valid[:, None], offsets, 0)
    out = []
    for n in lengths:
        bands = gram_bands(signal[:n], unrolled=False)
        high = jax.nn.sigmoid(_common.switch_argument(0.5 - bands.ratio, tau))
        pair = jnp.exp(-jnp.square(_common.switch_argument(1 - bands.ratio, tau)))
        out.append(band_l1_ratio(bands, high, pair))
    return jnp.stack(out)


def combine(gamma_a, gamma_b, ratio, *, count=None):
    """Combine two single-length gammas (paper Eqs. (15)-(16)).

    Pure JAX when any input is traced (``ratio`` and ``count`` may then be traced too),
    NumPy otherwise.

    Args:
      gamma_a, gamma_b: (N,) single-length sharpness values.
      ratio: the resampling ratio alpha in (0, 1].
      count: the number of real rows of a padded cloud (its first ``count``; see
        :attr:`hgjax.Neighbourhoods.count`), or None for all N. The order statistics are
        taken over the real rows only, so they are the unpadded cloud's.

    Returns:
      (N,) eps gamma_a + (1 - eps) gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b), where
      Gamma is the ceil(alpha n)-th largest value of each over the n = ``count`` real rows
      (eps = 0.5 when both are 0).

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.scores.lhf.combine(np.array([0.2, 0.4]), np.array([0.1, 0.3]), 0.5).round(3).tolist()
      [0.143, 0.343]
      >>> padded = hgjax.scores.lhf.combine(np.array([0.2, 0.4, 0.9]), np.array([0.1, 0.3, 0.9]), 0.5, count=2)
      >>> padded[:2].round(3).tolist()  # the third row is padding: not an order statistic
      [0.143, 0.343]
    """
    xp = jnp if _stream.is_traced(gamma_a, gamma_b, ratio, count) else np
    g = xp.stack([xp.asarray(gamma_a), xp.asarray(gamma_b)], axis=1)  # (N, 2)
    n = g.shape[0]
    if count is not None:  # padding rows below every gamma in [0, 1]: sorted first, never an order statistic
        count = count if xp is jnp else int(count)
        g_real = xp.where((xp.arange(n) < count)[:, None], g, -1)
    else:
        g_real, count = g, n
    if isinstance(ratio, float) and _stream.is_traced(count):  # the host's count, not float32's ratio x count
        m = _validate.n_keep_traced(count, ratio)
    else:
        x = ratio * count
        m = xp.clip(xp.where(xp.abs(x - xp.round(x)) <= 1e-9 * x, xp.round(x), xp.ceil(x)), 1, count).astype(xp.int32)
    big = xp.sort(g_real, axis=0)[n - m]  # (2,) Gamma_a, Gamma_b
    return mix(g[:, 0], g[:, 1], big[0], big[1])


def mix(gamma_a, gamma_b, big_a, big_b):
    """eps gamma_a + (1 - eps) gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b) (Eq. (16)).

    Args:
      gamma_a, gamma_b: (N,) single-length sharpness (NumPy or JAX).
      big_a, big_b: the order statistics Gamma_a, Gamma_b (scalars in the same dtype).

    Returns:
      (N,) combined gamma; eps = 0.5 when Gamma_a + Gamma_b = 0.
    """
    xp = jnp if _stream.is_traced(gamma_a, gamma_b, big_a, big_b) else np
    total = big_a + big_b
    eps = xp.where(total > 0, big_b / xp.where(total > 0, total, 1), 0.5).astype(gamma_a.dtype)
    return eps * gamma_a + (1 - eps) * gamma_b


def neighbourhoods(points, *, lengths=DEFAULT_LENGTHS, variant: str = "invariant", dedupe: bool | None = None,
                   capacity: int | None = None) -> spatial.Neighbourhoods:
    """k-nearest neighbourhoods of LHF, k = max(lengths) (host, not jittable).

    Args:
      points: (N, 3) float32 or float64, N >= max(lengths).
      lengths: (N_a, N_b), each >= 3, counting the point itself.
      variant: ``"invariant"`` or ``"reference"``; sets the default of ``dedupe``.
      dedupe: count exact duplicates once (default True for "invariant", False for
        "reference", the paper's neighbourhoods).
      capacity: columns of ``idx`` (>= max(lengths)); default max(lengths).

    Returns:
      :class:`hgjax.Neighbourhoods` (no scale).

    Raises:
      TypeError, ValueError: invalid arguments, or too few points.

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import lhf
      >>> lhf.neighbourhoods(np.random.default_rng(0).random((100, 3)), lengths=(4, 8)).idx.shape
      (100, 8)
    """
    params = build_params(lengths=lengths, variant=variant, dedupe=dedupe)
    lengths = params["lengths"]
    _validate.check_min_points(_validate.check_points(points).shape[0], max(lengths), f"LHF lengths={lengths}")
    nb = spatial.knn(points, max(lengths), dedupe=params["dedupe"], capacity=capacity)
    return dataclasses.replace(nb, params=spatial.record(params))


def build_params(*, lengths=DEFAULT_LENGTHS, variant: str = "invariant", dedupe: bool | None = None) -> dict:
    """Validated build parameters of LHF: lengths, variant and dedupe (default: True for "invariant").

    Raises:
      TypeError, ValueError: invalid arguments.
    """
    lengths = _validate.check_lengths(lengths)
    variant = _common.check_variant(variant)
    dedupe = variant == "invariant" if dedupe is None else _validate.check_bool(dedupe, "dedupe")
    return {"lengths": lengths, "variant": variant, "dedupe": dedupe}


@functools.lru_cache(maxsize=None)
def _kernel(lengths, variant, solver):
    return functools.partial(gamma, lengths=lengths, variant=variant, solver=solver)


def score(nb, *, ratio, lengths=DEFAULT_LENGTHS, variant: str = "invariant", solver: str = "gram",
          chunk_size: int | None = None, progress: bool = False):
    """Combined LHF sharpness gamma (Eqs. (14)-(16)) of every neighbourhood; higher is sharper.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods` (k-nearest rows, the
        point first, at least max(lengths) columns).
      ratio: resampling ratio alpha in (0, 1]; sets the weight eps (Eq. (16)). Traced under
        jit (a new value does not recompile).
      lengths: (N_a, N_b) (static). Default ``DEFAULT_LENGTHS`` = (8, 16): of (3, 6) ...
        (12, 24), the only pair within 0.05 of the best in every regime (grid, random,
        labelled real clouds; bench/results/edge_defaults.md).
      variant: ``"invariant"`` (default) or ``"reference"`` (static).
      solver: ``"gram"`` (default) or ``"eigh"`` for the invariant variant (static).
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) gamma in [0, 1], in the dtype of ``nb.points``.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "lhf")
      >>> hgjax.scores.lhf.score(nb, ratio=0.2).shape
      (100,)
    """
    g = single(nb, lengths=lengths, variant=variant, solver=solver, chunk_size=chunk_size, progress=progress)
    out = combine(g[:, 0], g[:, 1], _validate.check_traced_ratio(ratio), count=nb.count)
    return out if _stream.is_traced(out) else jax.device_put(out)


def single(nb, *, lengths=DEFAULT_LENGTHS, variant: str = "invariant", solver: str = "gram",
           chunk_size: int | None = None, progress: bool = False):
    """Single-length LHF sharpness gamma (Eq. (14)) of every neighbourhood for each length.

    Args:
      nb, variant, solver, chunk_size, progress: as :func:`score`.
      lengths: tuple of lengths (static), each >= 3 and at most the columns of ``nb.idx``.

    Returns:
      (N, len(lengths)) gamma in [0, 1], in the dtype of ``nb.points``.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "lhf")
      >>> hgjax.scores.lhf.single(nb, lengths=(6,)).shape
      (100, 1)
    """
    lengths = tuple(_validate.check_int(n, "lengths", minimum=3) for n in lengths)
    variant = _common.check_variant(variant)
    solver = _validate.check_choice(solver, "solver", SOLVERS)
    _validate.check_columns(nb, max(lengths), f"LHF with length {max(lengths)}")
    out = _stream.map_neighbourhoods(_kernel(lengths, variant, solver), nb, chunk_size=chunk_size, progress=progress)
    return out if _stream.is_traced(nb) else np.asarray(out)


def soft_score(nb, *, ratio, tau=0.1, lengths=DEFAULT_LENGTHS):
    """Smooth combined LHF gamma (:func:`soft_gamma`, Eqs. (15)-(16)), pure JAX and differentiable.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      ratio: resampling ratio alpha in (0, 1] (traced).
      tau: softness of the band switches (traced, > 0).
      lengths: (N_a, N_b) (static).

    Returns:
      (N,) gamma in [0, 1]; higher is sharper.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "lhf")
      >>> hgjax.scores.lhf.soft_score(nb, ratio=0.2).shape
      (100,)
    """
    lengths = _validate.check_lengths(lengths)
    _validate.check_columns(nb, max(lengths), f"LHF with length {max(lengths)}")
    tau = _validate.check_traced_positive(tau, "tau")
    g = _common.soft_map(functools.partial(soft_gamma, lengths=lengths), nb, args=(tau,))
    ratio = jnp.asarray(_validate.check_traced_ratio(ratio), g.dtype)
    return combine(g[:, 0], g[:, 1], ratio, count=nb.count)
