"""Local hypergraph filtering (LHF), paper Sec. III-C, Algorithm 3, Eqs. (13)-(16).

For each point p_i and a length n, the local signal is s (n, 3) = the n nearest points of
p_i (p_i itself first) minus p_i (Eq. (13)); its first row is 0. Its spectrum comes from
R = s_n s_n^T (n, n) with s_n the centred signal (by rows in the reference, by columns in
the default); t = argmax(diff(lam)) + 1 splits the
high band (the first t components) from the low band. The single-length sharpness is

* ``variant="reference"`` (Eq. (14), REFERENCE.md): gamma = sum_{j<t,k} |T[j, k]| /
  sum_{j,k} |T[j, k]| with T = V^T s, through a batched n x n ``eigh``. R has rank <= 2, so
  the high band contains an (n - 2)-dimensional degenerate eigenspace and the L1 ratio
  depends on the basis the eigensolver returns there.
* ``variant="invariant"`` (default): Eq. (14) made independent of the cloud's orientation
  and of the eigensolver's basis. Row-centring subtracts from each row its mean along
  (1, 1, 1), a direction of the coordinate axes, and the per-column L1 sums weigh the axes
  unequally: both change with a rotation of the cloud. Here the rows are centred by the
  neighbourhood centroid (s_c = s - 1 c^T, c the mean row), so R = s_c s_c^T turns with
  nothing, and each coefficient row T[j] = u_j^T s (3,) counts by its L2 norm, which is
  the L1 norm averaged over random rotations up to a common factor 3/2. The eigenspaces
  of R are the eigenvectors of mu0 <= mu1 <= mu2, the eigenvalues of C = s_c^T s_c, with
  ||T[j]||_2 = sqrt(mu_j) in any basis of equal mu; and the null space, of dimension d =
  n - 3 (d = 1 for n = 3), which holds P_null s = 1 c^T. Its rows are averaged over
  Haar-random bases as for the reference's degenerate L1: d c_d sqrt(n) ||c||, with c_d =
  E|v_1| = Gamma(d/2) / (sqrt(pi) Gamma((d + 1)/2)) for v uniform on S^{d-1}. So

      gamma = (d c_d sqrt(n) ||c|| + sum_{j in high} sqrt(mu_j)) / (d c_d sqrt(n) ||c|| + sum_j sqrt(mu_j)),

  the ratio of the expectations of Eq. (14)'s numerator and denominator over a random
  rotation of the cloud and random bases inside every eigenspace (not the expectation of
  the ratio): still the high-band share of the signal, with the band threshold t =
  argmax(diff(lam)) + 1 of the normalised eigenvalues (0, ..., 0, mu0, mu1, mu2) / mu2.
  The edge signal is the centroid offset ||c|| and the spread along the normal(s), sqrt(mu0).
  Computed from the 3 x 3 covariance C (:func:`bands`, Jacobi eigenvalues, no LAPACK call);
  ``solver="eigh"`` computes the same number through the n x n ``eigh`` (the tests prove the
  two agree wherever rank(s_c) = 3). On the defaults study it ranks edges far better than
  the previous (row-centred) invariant variant: bench/results/edge_defaults.md.

The score is ratio-free: :func:`score` gives gamma at both lengths (N_a, N_b), (N, 2).
LHF's selection combines them (Eqs. (15)-(16), :func:`combine`): gamma_i = eps gamma_a +
(1 - eps) gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b), Gamma the m-th largest value of
each column for the kept count m = ceil(ratio N) (the paper's definition, not the reference
code's arbitrary element). Higher gamma means sharper; resampling keeps the largest.

Degenerate neighbourhoods: duplicates and collinear or coplanar points give finite gamma in
[0, 1]; a signal with no structure at all (all points equal) gives gamma = 0. Vanishing
eigenvalues of C leave d unchanged (their directions carry no part of s), so the invariant
gamma is continuous in s except where the band threshold t moves; the smooth twin
:func:`soft_gamma` shares :func:`bands` and blends across those jumps.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _exact, _method, _stream, _validate, spectrum
from hgjax.engine import select
from hgjax.neighbours import backend, nearest, spatial
from hgjax.scores import _common, eigen

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
    return d * math.exp(math.lgamma(d / 2) - math.lgamma((d + 1) / 2)) / math.sqrt(math.pi)


def _null_dim(n: int) -> int:
    """Dimension of the fixed null eigenspace of R for a column-centred signal of n rows."""
    return max(n - 3, 1)


class Bands(NamedTuple):
    """Eigenspace sums of the invariant LHF (Eq. (14)) for one signal, from :func:`bands`.

    Combined into gamma by :func:`band_ratio`.
    """

    null: jax.Array  #: d c_d sqrt(n) ||c||: the null eigenspace of R (always high band).
    amplitude: jax.Array  #: (3,) sqrt(mu_k), ascending: the eigenvectors of R with mu_k = eig(s_c^T s_c).
    jumps: jax.Array  #: (3,) mu0 / mu2, (mu1 - mu0) / mu2, 1 - mu1 / mu2: the last three steps of lam.


def bands(s) -> Bands:
    """Eigenspace sums of the invariant LHF (Eq. (14)) through the 3 x 3 covariance.

    With s_c = s - 1 c^T (c the mean row, the neighbourhood centroid minus the point), R =
    s_c s_c^T has the eigenvalues mu0 <= mu1 <= mu2 of C = s_c^T s_c and a null eigenspace
    of dimension d = n - 3 (d = 1 for n = 3, where mu0 = 0 always), which contains 1. An
    eigenvector u_k of mu_k > 0 gives the row T[k] = u_k^T s = u_k^T s_c with ||T[k]||_2 =
    sqrt(mu_k), whatever basis is chosen inside an eigenspace of equal mu. The null space
    gives P_null s = 1 c^T, of rank one, whose row norms in a Haar-random basis add up to
    d c_d sqrt(n) ||c|| on average. Eigenvalues of C vanishing by rounding or geometry do
    not change d (their directions then carry no part of s), so every sum is continuous in s.
    No n x n eigendecomposition, no LAPACK call; s is first scaled by a power of two and
    everything is computed in its dtype.

    Shared by the hard kernel (``variant="invariant"``) and the smooth LHF of
    :func:`soft_gamma`, which differ only in the band weights passed to :func:`band_ratio`.

    Args:
      s: (n, 3) local signal (Eq. (13)).

    Returns:
      :class:`Bands` in the dtype of ``s``, for s scaled by a power of two (only ratios of
      ``null`` and ``amplitude`` are meaningful).
    """
    n = s.shape[0]
    # gamma is scale-free: scale s by a power of two to max|s| in [1/2, 1). Exact, so every
    # rounding below scales with it and no square under- or overflows.
    c, cov = _common.centred_entries(_common.unit_scale(s))  # c: the centroid offset
    mu = jnp.maximum(jnp.stack(eigen.eigenvalues(cov)), 0)
    if n == 3:  # three centred rows span at most a plane
        mu = mu.at[0].set(0)
    r = _common.safe_div(mu, mu[2], 0.0)
    return Bands(
        null=_haar_l1_factor(_null_dim(n)) * math.sqrt(n) * _common.safe_sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]),
        amplitude=_common.safe_sqrt(mu),
        jumps=jnp.stack([r[0], r[1] - r[0], 1 - r[1]]),
    )


def band_ratio(b: Bands, weights):
    """gamma = A_high / (A_high + A_low) of the invariant LHF from band weights.

    The band threshold t = argmax(diff(lam)) + 1 falls at one of the last three steps of
    lam (the null eigenvalues are 0, the others sum to at least one): after the null space
    (weights (1, 0, 0)), after mu0 ((0, 1, 0)) or after mu1 ((0, 0, 1)). ``weights`` (3,)
    weigh those three cases; the hard kernel passes the one-hot argmax of ``b.jumps``,
    :func:`soft_gamma` a softmax.

    Args:
      b: :class:`Bands` from :func:`bands`.
      weights: (3,) non-negative, summing to 1.

    Returns:
      Scalar gamma in [0, 1]; 0 for a signal without structure (all rows equal).
    """
    a_high = b.null + (weights[1] + weights[2]) * b.amplitude[0] + weights[2] * b.amplitude[1]
    return _common.safe_div(a_high, b.null + jnp.sum(b.amplitude), 0.0)


def _invariant_bands(s):
    """Rotation-invariant gamma through :func:`bands` with the hard band threshold."""
    b = bands(s)
    return band_ratio(b, jax.nn.one_hot(jnp.argmax(b.jumps), 3, dtype=b.jumps.dtype))


def _invariant_eigh(s):
    """Rotation-invariant gamma through the n x n eigh of R (proof path for :func:`bands`).

    Eq. (14) with L2 row norms ||T[j]||_2 (T = V^T s) in place of the per-column L1 sums,
    and the null eigenspace (the first d columns) averaged over its bases as d c_d ||P s||_F.
    Agrees with :func:`bands` where rank(s_c) = 3 (otherwise eigh's basis mixes the null
    space with the vanishing directions of C).
    """
    n = s.shape[0]
    lam, v = spectrum.estimate_spectrum(s, axis="column")
    t = spectrum.band_threshold(lam)
    coef = spectrum.hgft(v, s)  # (n, 3)
    sq = jnp.sum(coef * coef, axis=1)  # (n,)
    j = jnp.arange(n)
    null = j < _null_dim(n)
    rows = jnp.where(null, 0, _common.safe_sqrt(sq))
    a_null = _haar_l1_factor(_null_dim(n)) * _common.safe_sqrt(jnp.sum(jnp.where(null, sq, 0)))
    return _common.safe_div(a_null + jnp.sum(jnp.where(j < t, rows, 0)), a_null + jnp.sum(rows), 0.0)


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
        fn = _invariant_bands if solver == "gram" else _invariant_eigh
    return jnp.stack([fn(signal[:n]) for n in lengths])


def soft_gamma(offsets, valid, tau, *, lengths=DEFAULT_LENGTHS):
    """Smooth LHF sharpness gamma (Eq. (14)) of one k-nearest neighbourhood for each length.

    The invariant gamma, with the eigenspace sums of :func:`bands` (shared with the hard
    kernel) combined by :func:`band_ratio` with a softmax of the last three steps of lam
    (softness ``tau``) in place of the hard argmax of the band threshold, so gamma is
    continuous where the threshold moves.

    Args:
      offsets, valid: as :func:`gamma`.
      tau: softness of the band threshold (scalar > 0, traced); tau -> 0 gives the hard
        invariant gamma except where two steps of lam are within a few tau of each other.
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
        b = bands(signal[:n])
        # softmax is shift-invariant: the max is a constant shift (no derivative; XLA CPU
        # compiles the JVP of a traced max here under jit and vmap into NaN).
        top = jax.lax.stop_gradient(jnp.max(b.jumps))
        weights = jax.nn.softmax(_common.switch_argument(b.jumps - top, tau))
        out.append(band_ratio(b, weights))
    return jnp.stack(out)


def combine(gamma, m, *, count=None):
    """Combine the two single-length gammas of every point (paper Eqs. (15)-(16)).

    LHF's selection: the weight eps comes from the order statistics at the kept count m, so
    it belongs to :func:`hgjax.keep` and :func:`hgjax.soft_weights` (which call it through
    the registry), not to the score. Pure JAX when any input is traced (``m`` and ``count``
    may then be traced too), NumPy otherwise.

    Args:
      gamma: (N, 2) single-length sharpness values (:func:`score`), column j at ``lengths[j]``.
      m: the number of kept points, 1 <= m <= n.
      count: the number of real rows of a padded cloud (its first ``count``; see
        :attr:`hgjax.Neighbourhoods.count`), or None for all N. The order statistics are
        taken over the real rows only, so they are the unpadded cloud's.

    Returns:
      (N,) eps gamma_a + (1 - eps) gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b), where
      Gamma is the m-th largest value of each column over the n = ``count`` real rows
      (eps = 0.5 when both are 0).

    Examples:
      >>> import numpy as np, hgjax
      >>> hgjax.scores.lhf.combine(np.array([[0.2, 0.1], [0.4, 0.3]]), 1).round(3).tolist()
      [0.143, 0.343]
      >>> padded = hgjax.scores.lhf.combine(np.array([[0.2, 0.1], [0.4, 0.3], [0.9, 0.9]]), 1, count=2)
      >>> padded[:2].round(3).tolist()  # the third row is padding: not an order statistic
      [0.143, 0.343]
    """
    xp = jnp if _stream.is_traced(gamma, m, count) else np
    g = xp.asarray(gamma)  # (N, 2)
    n = g.shape[0]
    # padding rows below every gamma in [0, 1]: sorted first, never an order statistic
    real = g if count is None else xp.where((xp.arange(n) < count)[:, None], g, -1)
    big = xp.sort(real, axis=0)[n - m]  # (2,) Gamma_a, Gamma_b
    if xp is np and np.isinf(g).any():  # keep's +-inf (LHF's own gammas lie in [0, 1])
        return _mix_infinite(g[:, 0], g[:, 1], big[0], big[1])
    return mix(g[:, 0], g[:, 1], big[0], big[1])


def _mix_infinite(gamma_a, gamma_b, big_a, big_b):
    """:func:`mix` (NumPy) of gammas or order statistics that may be infinite, as every method's
    :func:`hgjax.keep` takes them: eps is the limit of Gamma_b / (Gamma_a + Gamma_b) (0 or 1 when
    one of them is infinite, 0.5 when both are) and a column of weight 0 adds 0, so an infinite
    gamma of a weighted column ranks its point at that end.

    Raises:
      ValueError: a row holds +inf and -inf in weighted columns (no rank).
    """
    infinite_a, infinite_b = np.isinf(big_a), np.isinf(big_b)
    if infinite_a or infinite_b:
        eps = np.asarray(0.5 if infinite_a and infinite_b else 1.0 * bool(infinite_b), gamma_a.dtype)
    else:
        total = big_a + big_b
        eps = np.asarray(big_b / total if total > 0 else 0.5, gamma_a.dtype)
    with np.errstate(invalid="ignore"):
        out = np.where(eps > 0, eps * gamma_a, 0) + np.where(eps < 1, (1 - eps) * gamma_b, 0)
    if np.isnan(out).any():
        raise ValueError(f"scores holds +inf and -inf in one row at {int(np.isnan(out).sum())} point(s);"
                         " LHF's combination (Eq. (16)) cannot rank them")
    return out.astype(gamma_a.dtype)


def mix(gamma_a, gamma_b, big_a, big_b):
    """eps gamma_a + (1 - eps) gamma_b with eps = Gamma_b / (Gamma_a + Gamma_b) (Eq. (16)).

    Args:
      gamma_a, gamma_b: (N,) single-length sharpness (NumPy or JAX).
      big_a, big_b: the order statistics Gamma_a, Gamma_b (scalars in the same dtype).

    Returns:
      (N,) combined gamma; eps = 0.5 when Gamma_a + Gamma_b = 0.
    """
    if not _stream.is_traced(gamma_a, gamma_b, big_a, big_b):
        total = big_a + big_b
        eps = np.where(total > 0, big_b / np.where(total > 0, total, 1), 0.5).astype(gamma_a.dtype)
        return eps * gamma_a + (1 - eps) * gamma_b
    total = big_a + big_b  # traced: each product and the quotient rounded on its own, as NumPy rounds them
    eps = jnp.where(total > 0, _exact.div(big_b, jnp.where(total > 0, total, 1)), 0.5).astype(gamma_a.dtype)
    return _exact.mul(eps, gamma_a) + _exact.mul(1 - eps, gamma_b)


def neighbourhoods(points, *, lengths=DEFAULT_LENGTHS, variant: str = "invariant", dedupe: bool | None = None,
                   capacity: int | None = None, search: str = "host",
                   cell_slots: int | None = None, cell_edge=None) -> spatial.Neighbourhoods:
    """k-nearest neighbourhoods of LHF, k = max(lengths) (host; jittable with ``search="jax"``).

    Args:
      points: (N, 3) float32 or float64, N >= max(lengths).
      lengths: (N_a, N_b), each >= 3, counting the point itself.
      variant: ``"invariant"`` or ``"reference"``; sets the default of ``dedupe``.
      dedupe: count exact duplicates once (default True for "invariant", False for
        "reference", the paper's neighbourhoods).
      capacity: columns of ``idx`` (>= max(lengths)); default max(lengths).
      search: ``"host"`` (SciPy's k-d tree; not jittable) or ``"jax"`` (the traced search:
        jit, vmap, grad; the same neighbour sets, :func:`hgjax.neighbours.nearest.build`).
      cell_slots, cell_edge: the traced search's candidates read per step (static) and first
        cell edge (traced, or None from the data): speed settings, never limits.

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
    pts = backend.checked_points(points, search)
    _validate.check_min_points(pts.shape[0], max(lengths), f"LHF lengths={lengths}")
    nb = nearest.build(pts, max(lengths), dedupe=params["dedupe"], capacity=capacity, search=search,
                           cell_slots=cell_slots, cell_edge=cell_edge)
    searched = {k: v for k, v in nb.params if k in ("search", "cell_slots", "cell_edge")}
    return dataclasses.replace(nb, params=spatial.record({**params, **searched}))


def build_params(*, lengths=DEFAULT_LENGTHS, variant: str = "invariant", dedupe: bool | None = None) -> dict:
    """Validated build parameters of LHF: lengths, variant and dedupe (default: True for "invariant").

    Raises:
      TypeError, ValueError: invalid arguments.
    """
    lengths = _validate.check_lengths(lengths)
    variant = _validate.check_variant(variant)
    dedupe = variant == "invariant" if dedupe is None else _validate.check_bool(dedupe, "dedupe")
    return {"lengths": lengths, "variant": variant, "dedupe": dedupe}


@functools.lru_cache(maxsize=None)
def _kernel(lengths, variant, solver):
    return functools.partial(gamma, lengths=lengths, variant=variant, solver=solver)


def score(nb, *, lengths=DEFAULT_LENGTHS, variant: str = "invariant", solver: str = "gram",
          chunk_size: int | None = None, progress: bool = False):
    """The two single-length LHF sharpness values (Eq. (14)) of every neighbourhood; higher is sharper.

    Ratio-free: their combination (Eqs. (15)-(16)) takes the order statistics at the kept
    count, so it is part of LHF's selection (:func:`combine`, called by :func:`hgjax.keep`,
    :func:`hgjax.soft_weights` and the tiled engine).

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods` (k-nearest rows, the
        point first, at least max(lengths) columns).
      lengths: (N_a, N_b) (static). Default ``DEFAULT_LENGTHS`` = (8, 16): of (3, 6) ...
        (12, 24), the only pair within 0.05 of the best in every regime (grid, random,
        labelled real clouds; bench/results/edge_defaults.md).
      variant: ``"invariant"`` (default) or ``"reference"`` (static).
      solver: ``"gram"`` (default) or ``"eigh"`` for the invariant variant (static).
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N, 2) gamma in [0, 1], in the dtype of ``nb.points``: column j at ``lengths[j]``.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "lhf")
      >>> hgjax.scores.lhf.score(nb).shape
      (100, 2)
    """
    out = single(nb, lengths=_validate.check_lengths(lengths), variant=variant, solver=solver,
                 chunk_size=chunk_size, progress=progress)
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
    variant = _validate.check_variant(variant)
    solver = _validate.check_choice(solver, "solver", SOLVERS)
    _validate.check_columns(nb, max(lengths), f"LHF with length {max(lengths)}")
    out = _stream.map_neighbourhoods(_kernel(lengths, variant, solver), nb, chunk_size=chunk_size, progress=progress)
    return out if _stream.is_traced(nb) else np.asarray(out)


def soft_score(nb, *, tau=0.1, lengths=DEFAULT_LENGTHS):
    """Smooth twin of :func:`score` (:func:`soft_gamma`), pure JAX and differentiable.

    Ratio-free like :func:`score`; :func:`hgjax.soft_weights` combines the two columns
    (:func:`combine`, Eqs. (15)-(16)) at its ratio. Called eagerly it streams fixed-size chunks
    through one compiled kernel, as :func:`score`.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      tau: softness of the band switches (traced, > 0).
      lengths: (N_a, N_b) (static).

    Returns:
      (N, 2) gamma in [0, 1], column j at ``lengths[j]``; higher is sharper.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "lhf")
      >>> hgjax.scores.lhf.soft_score(nb).shape
      (100, 2)
    """
    lengths = _validate.check_lengths(lengths)
    _validate.check_columns(nb, max(lengths), f"LHF with length {max(lengths)}")
    tau = _validate.check_traced_positive(tau, "tau")
    return _stream.map_neighbourhoods(_soft_kernel(lengths), nb, args=(_stream.as_arg(tau, nb.points.dtype),))


@functools.lru_cache(maxsize=None)
def _soft_kernel(lengths):
    return functools.partial(soft_gamma, lengths=lengths)


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of LHF for a tiled run of ``n`` points.

    Raises:
      TypeError, ValueError: invalid parameters, or fewer than max(lengths) points.
    """
    b = build_params(**{k: params[k] for k in ("lengths", "variant", "dedupe") if k in params})
    solver = _validate.check_choice(params.get("solver", "gram"), "solver", SOLVERS)
    _validate.check_capacity_param(params, max(b["lengths"]))
    _validate.check_min_points(n, max(b["lengths"]), f"LHF lengths={b['lengths']}")
    return (backend.with_search({"k": max(b["lengths"]), "dedupe": b["dedupe"]}, params),
            {"lengths": b["lengths"], "variant": b["variant"], "solver": solver})


def _tile_kernel(params: dict):
    return _kernel(params["lengths"], params["variant"], params["solver"]), False


def tiled_select(runner, parts, plan, key=None):
    """Eqs. (15)-(16) over the tiles: the two global order statistics, then each tile's combined gamma.

    Gamma_a and Gamma_b are the m-th largest single-length gammas of the whole cloud, found
    exactly from per-tile histograms (:func:`hgjax.engine.select.kth_pair`).

    Returns:
      (parts of combined gamma, their order keys, {"gamma_a", "gamma_b"}, True).
    """
    del key  # deterministic
    big = []
    for column in range(2):
        keyed = runner.each(select.part_keys, parts, True, column)
        big.append(select.key_value(select.kth_pair(keyed, plan.m, run=runner.run(keyed))[0], largest=True))
    mixed = runner.each(_mix_part, parts, big[0], big[1])
    return mixed, runner.each(select.part_keys, mixed, True), {"gamma_a": big[0], "gamma_b": big[1]}, True


def _mix_part(part, big_a: float, big_b: float):
    gids, g = part
    return gids, mix(g[:, 0], g[:, 1], g.dtype.type(big_a), g.dtype.type(big_b))


METHOD = _method.Method(
    "lhf", "knn", largest=True, needs_key=False,
    summary="local hypergraph filtering: keep the largest two-length sharpness gamma",
    citation=f"{_method.PAPER}, Alg. 3, Eqs. (14)-(16)", build=neighbourhoods, score=score,
    soft_score=soft_score,
    columns=2, combine=combine,
    tiling=_method.Tiling(params=tile_params, reach=nearest.reach, rows=nearest.tile_rows, kernel=_tile_kernel,
                          select=tiled_select))
