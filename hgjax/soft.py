"""Differentiable soft resampling: smooth scores, a soft top-k and per-point keep weights.

The hard resamplers (:func:`hgjax.resample`) are piecewise constant in the coordinates:
HKC/HKF count points in voxels, LHF switches bands on an eigenvalue gap and every selector
sorts. This module makes the whole path from coordinates to keep weights differentiable:

1. Neighbourhoods (integer index arrays) are built once on the host with SciPy
   (:func:`soft_neighbourhoods`). They are piecewise constant, so no gradient flows
   through them; everything after is a pure JAX function of the points.
2. Smooth scores (:func:`soft_scores`), one kernel per neighbourhood, vmapped:

   * ``"hkc"`` / ``"hkf"``: soft voxel occupancy. Along each axis a neighbour at offset o
     belongs to bin j (centre j d) with weight sigmoid((o - (j - 1/2) d) / (tau d)) -
     sigmoid((o - (j + 1/2) d) / (tau d)), a smooth partition of the kernel's extent; the
     3-D membership is the product over the axes. As tau -> 0 the soft counts tend to the
     hard counts of Fig. 2 (exactly, away from voxel faces). The band split is the exact
     one of :func:`hgjax.scores.voxel.low_high`. HKC's beta (Eq. (11)) is +inf on symmetric
     signals, so both names return the bounded beta / (1 + beta) = ||high|| / (||high|| +
     ||low||) with guarded square roots; for the cubic kernel this is also HKF's invariant
     sigma (Eq. (12)), so ``"hkc"`` and ``"hkf"`` are the same smooth score. Lower is sharper.
   * ``"lhf"``: the invariant gamma of Eq. (14), the Haar-expected L1 band ratio of
     :mod:`hgjax.scores.lhf`, computed by the same closed-form 2 x 2 Gram code
     (:func:`hgjax.scores.lhf.gram_bands`, no LAPACK call), whose autodiff
     derivatives are the true ones. The two hard steps on r = mu1 / mu2 become smooth
     switches: the mu1 direction is high band with weight sigmoid((1/2 - r) / tau), and
     u1, u2 count as one 2-D eigenspace (the hard kernel's mu1 = mu2 case) with weight
     exp(-((1 - r) / tau)^2), which keeps gamma and its gradient continuous where the
     eigenvectors turn fast (mu1 near mu2). gamma still jumps where rank(R) drops
     (collinear signals, or a plane containing the direction (1, 1, 1)), with finite
     gradients. The two lengths are combined as in Eqs. (15)-(16). Higher is sharper.
   * ``"ea"``: surface variation l0 / (l0 + l1 + l2) of the k-nearest covariance (EA
     baseline, Bazazian et al. 2015), exactly :func:`hgjax.scores.ea.ea_neighbourhood`:
     an eigenvalue (no eigenvector) has a finite derivative even when degenerate, and the
     division is guarded. Higher is sharper.
   * ``"gfr"``: ||(L P)_i|| with the symmetrised Gaussian-weighted graph Laplacian
     (GFR baseline, Chen et al. 2018, edge weights of
     :func:`hgjax.scores.gfr.gfr_neighbourhood`) on the fixed k-nearest list instead of
     the radius graph, the edge-length variance computed in JAX. Higher is sharper.

3. A soft top-k (:func:`soft_select`): w_i = sigmoid((s_i - theta) / temperature) with the
   threshold theta such that sum(w) = ratio N, found by a fixed number of bisection steps
   and differentiated by the implicit function theorem (custom JVP). As temperature -> 0,
   w tends to the hard top-k mask.

:func:`soft_weights` composes 2 and 3 (pure, jit- and vmap-compatible); :func:`soft_resample`
adds step 1 through a host callback so that it can itself be jitted and vmapped.
"""

from __future__ import annotations

import functools
import importlib
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate
from hgjax.neighbourhoods import SpatialIndex, _resolution, _to_caller_frame
from hgjax.scores import _common, voxel

# The score modules (``hgjax.scores.lhf`` etc. name the functions).
_ea, _gfr, _lhf = (importlib.import_module(f"hgjax.scores.{m}") for m in ("ea", "gfr", "lhf"))

__all__ = [
    "SOFT_METHODS",
    "soft_gfr",
    "soft_hkc_neighbourhood",
    "soft_lhf_neighbourhood",
    "soft_local_signal",
    "soft_neighbourhoods",
    "soft_resample",
    "soft_scores",
    "soft_select",
    "soft_weights",
]

#: Smooth score names and whether resampling keeps their largest values.
SOFT_METHODS: dict[str, bool] = {"hkc": False, "hkf": False, "lhf": True, "ea": True, "gfr": True}

BISECTION_STEPS = 64


# ---------------------------------------------------------------------------------------
# Per-neighbourhood smooth kernels.


def soft_local_signal(centre, nbrs, valid, d, tau, *, kernel_size: int = 3):
    """Soft voxel counts (N_k,) of one cube neighbourhood (smooth version of Fig. 2).

    Along each axis, a neighbour at offset o from the centre belongs to bin j (centre j d,
    j = -(k-1)/2 .. (k-1)/2) with weight sigmoid((o - (j - 1/2) d) / (tau d)) -
    sigmoid((o - (j + 1/2) d) / (tau d)); its voxel membership is the product over x, y, z.
    The weights along an axis sum to a smooth window over the kernel's extent, and as
    tau -> 0 they tend to the hard strict membership |o - j d| < d / 2.

    Args:
      centre: (3,) the point.
      nbrs: (K, 3) its cube neighbourhood (padding rows masked by ``valid``).
      valid: (K,) bool.
      d: voxel spacing (scalar, traced).
      tau: softness relative to d (scalar > 0, traced).
      kernel_size: odd k (static).

    Returns:
      (k^3,) soft counts, x slowest and z fastest like :func:`hgjax.scores.voxel.local_signal`.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.soft import soft_local_signal
      >>> nbrs = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
      >>> s = soft_local_signal(jnp.zeros(3), nbrs, jnp.array([True, True]), 1.0, 1e-3)
      >>> [round(float(s[j]), 6) for j in (13, 22)]  # centre voxel, voxel +x
      [1.0, 1.0]
    """
    o = nbrs - centre[None, :]  # (K, 3)
    h = (kernel_size - 1) // 2
    faces = (jnp.arange(-h, h + 2, dtype=o.dtype) - 0.5) * d  # (k + 1,) bin faces
    cdf = jax.nn.sigmoid((o[:, :, None] - faces[None, None, :]) / (tau * d))  # (K, 3, k + 1)
    member = jnp.where(valid[:, None, None], cdf[:, :, :-1] - cdf[:, :, 1:], 0)  # (K, 3, k)
    counts = jnp.einsum("ki,kj,kl->ijl", member[:, 0], member[:, 1], member[:, 2])
    return counts.reshape(-1)


def soft_hkc_neighbourhood(centre, nbrs, valid, d, tau, *, kernel_size: int = 3):
    """Smooth bounded HKC/HKF score of one cube neighbourhood.

    beta / (1 + beta) = ||high|| / (||high|| + ||low||) (Eqs. (10)-(12)) of the soft counts
    of :func:`soft_local_signal`, with guarded square roots (0 when the signal is 0).

    Args:
      centre, nbrs, valid, d, tau, kernel_size: as :func:`soft_local_signal`.

    Returns:
      Scalar in [0, 1]; lower is sharper.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.soft import soft_hkc_neighbourhood
      >>> nbrs = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
      >>> round(float(soft_hkc_neighbourhood(jnp.zeros(3), nbrs, jnp.ones(3, bool), 1.0, 1e-3)), 6)
      1.0
    """
    s = soft_local_signal(centre, nbrs, valid, d, tau, kernel_size=kernel_size)
    low, high = voxel.low_high(s, kernel_size)
    return _common.band_ratio(jnp.sum(high * high), jnp.sum(low * low))


def _soft_l1_ratio(s, tau):
    """Smooth invariant gamma of one signal s (n, 3); see :func:`soft_lhf_neighbourhood`."""
    bands = _lhf.gram_bands(s)
    high = jax.nn.sigmoid((0.5 - bands.ratio) / tau)
    pair = jnp.exp(-jnp.square((1 - bands.ratio) / tau))
    return _lhf.band_l1_ratio(bands, high, pair)


def soft_lhf_neighbourhood(centre, nbrs, valid, tau, *, lengths=_lhf.DEFAULT_LENGTHS):
    """Smooth single-length LHF sharpness gamma (Eq. (14)) of one k-nearest neighbourhood.

    The invariant (Haar-expected L1) gamma of :mod:`hgjax.scores.lhf`: the eigenspace sums
    of :func:`hgjax.scores.lhf.gram_bands` (closed-form 2 x 2 Gram, shared with the hard
    kernel) combined by :func:`hgjax.scores.lhf.band_l1_ratio` with smooth switches of
    r = mu1 / mu2 instead of the hard steps:

    * band: the mu1 direction is high band with weight sigmoid((1/2 - r) / tau);
    * pair: u1, u2 count as one 2-D eigenspace (Haar factor 4 / pi) with weight
      q = exp(-((1 - r) / tau)^2). The 1-D terms |u_k^T s| turn with the eigenvectors, whose
      derivative grows like 1 / (mu2 - mu1); since 1 - q = O((1 - r)^2), gamma and its
      gradient stay continuous at mu1 = mu2, where the hard gamma jumps.

    gamma still jumps where rank(R) drops (the null space gains a dimension: collinear
    signals, or a plane containing the direction (1, 1, 1)); gradients stay finite there.

    Args:
      centre: (3,) the point.
      nbrs: (K, 3) the point itself then its neighbours by distance, K >= max(lengths).
      valid: (K,) bool; padding rows contribute a zero offset.
      tau: softness of the switches on r = mu1 / mu2 (band split at 1/2, 2-D eigenspace at
        1; scalar > 0, traced); tau -> 0 gives the hard invariant gamma of
        :func:`hgjax.scores.lhf_single` (except for r within a few tau of 1/2 or 1).
      lengths: tuple of lengths n (static), each counting the point itself.

    Returns:
      (len(lengths),) gamma in [0, 1]; higher is sharper. Gradients are finite on
      duplicate, collinear, coplanar and symmetric neighbourhoods.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.soft import soft_lhf_neighbourhood
      >>> nbrs = jnp.zeros((8, 3))  # all points equal: no structure
      >>> soft_lhf_neighbourhood(jnp.zeros(3), nbrs, jnp.ones(8, bool), 0.05, lengths=(4, 8)).tolist()
      [0.0, 0.0]
    """
    signal = jnp.where(valid[:, None], nbrs - centre[None, :], 0)
    return jnp.stack([_soft_l1_ratio(signal[:n], tau) for n in lengths])


def soft_gfr(points, idx):
    """GFR high-pass score ||(L P)_i||_2 on a fixed neighbour list (smooth in the points).

    W0_ij = exp(-q_ij^2 / (2 v)) for the listed neighbours j of i (q the squared distance,
    v its variance over all edges, REFERENCE.md "GFR"), W = W0 + W0^T, L = D - W.

    Args:
      points: (N, 3) float.
      idx: (N, K) int32 k-nearest indices, column 0 the point itself (skipped), padded with N.

    Returns:
      (N,) scores >= 0 in the dtype of ``points``; higher is sharper.

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.soft import soft_gfr
      >>> pts = jnp.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
      >>> idx = jnp.array([[0, 1, 2], [1, 0, 2], [2, 1, 0]], dtype=jnp.int32)
      >>> [round(x, 4) for x in soft_gfr(pts, idx).tolist()]  # the middle point is balanced
      [1.6309, 0.0, 1.6309]
    """
    n = points.shape[0]
    nb = idx[:, 1:]
    valid = nb < n
    ext = jnp.concatenate([points, jnp.zeros((1, 3), points.dtype)])
    diff = ext[nb] - points[:, None, :]  # (N, K-1, 3): p_j - p_i
    q = jnp.where(valid, jnp.sum(diff * diff, axis=-1), 0)
    n_edges = jnp.maximum(jnp.sum(valid), 1).astype(points.dtype)
    mean_q = jnp.sum(q) / n_edges
    var_q = jnp.sum(jnp.where(valid, (q - mean_q) ** 2, 0)) / n_edges
    flow = _map(_gfr.gfr_neighbourhood, points, nb, 2 * var_q)  # (N, K-1, 3): W0_ij (p_j - p_i)
    # (L P)_i = sum_j W_ij (p_i - p_j): row i gets -flow(i->j), and row j gets +flow(i->j).
    lp = (-jnp.sum(flow, axis=1)).at[nb].add(flow, mode="drop")
    return _common.safe_sqrt(jnp.sum(lp * lp, axis=-1))


# ---------------------------------------------------------------------------------------
# Whole-cloud composition.


def _check_method(method: str) -> str:
    return _validate.check_choice(method, "method", SOFT_METHODS)


def _check_traced_points(points):
    """Shape and dtype checks of ``points`` that also work on tracers."""
    if not hasattr(points, "shape") or not hasattr(points, "dtype"):
        raise TypeError(f"points must be an array of shape (N, 3); got {type(points).__name__}")
    if len(points.shape) != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3); got {tuple(points.shape)}")
    if np.dtype(points.dtype) not in _validate.FLOAT_DTYPES:
        raise TypeError(f"points must have dtype float32 or float64; got {points.dtype}")


def _check_arrays(points, idx):
    _check_traced_points(points)
    if not hasattr(idx, "shape") or len(idx.shape) != 2 or idx.shape[0] != points.shape[0]:
        raise ValueError(f"idx must have shape (N, K) with N = {points.shape[0]}; got "
                         f"{getattr(idx, 'shape', type(idx).__name__)}")
    if not np.issubdtype(np.dtype(idx.dtype), np.integer):
        raise TypeError(f"idx must be an integer array; got dtype {idx.dtype}")


def _map(fn: Callable, points, idx, *args):
    """vmap a per-neighbourhood ``fn(centre, nbrs, valid, *args)`` over the whole cloud.

    Gathers with a zero sentinel row and masks with ``idx < N``; scalar ``args`` are
    broadcast.
    """
    n = points.shape[0]
    ext = jnp.concatenate([points, jnp.zeros((1, 3), points.dtype)])
    return jax.vmap(fn, in_axes=(0, 0, 0) + (None,) * len(args))(points, ext[idx], idx < n, *args)


def soft_scores(points, idx, *, method: str = "hkc", d=None, tau=0.1, ratio: float | None = None,
                kernel_size: int = 3, lengths=_lhf.DEFAULT_LENGTHS):
    """Smooth per-point scores, a pure JAX function of ``points`` (jit, vmap, grad).

    Args:
      points: (N, 3) float32 or float64 (NumPy, JAX array or tracer).
      idx: (N, K) integer neighbourhoods from :func:`soft_neighbourhoods` for the same
        method, padded with N. No gradient flows through them.
      method: a key of :data:`SOFT_METHODS` (static).
      d: voxel spacing for ``"hkc"``/``"hkf"`` (traced; :func:`soft_neighbourhoods`
        returns the one it used for the ROI).
      tau: softness of the smooth pieces (traced): voxel membership relative to d for
        HKC/HKF, switches on mu1 / mu2 for LHF; unused by EA and GFR.
      ratio: resampling ratio in (0, 1], needed by ``"lhf"`` to combine its two lengths
        (Eqs. (15)-(16)); static.
      kernel_size: odd k of the HKC/HKF kernel (static).
      lengths: LHF lengths (N_a, N_b) (static); idx needs at least max(lengths) columns.

    Returns:
      (N,) scores in the dtype of ``points``. Which end is kept: ``SOFT_METHODS[method]``
      is True when the largest are kept.

    Raises:
      TypeError, ValueError: bad arrays, method, a missing ``d`` or ``ratio``.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((100, 3))
      >>> idx, d = hgjax.soft_neighbourhoods(pts, method="ea")
      >>> hgjax.soft_scores(pts, idx, method="ea").shape
      (100,)
    """
    _check_arrays(points, idx)
    method = _check_method(method)
    points = jnp.asarray(points)
    idx = jnp.asarray(idx)
    if method in ("hkc", "hkf"):
        if d is None:
            raise ValueError(f"method {method!r} needs the voxel spacing d; got None")
        kernel_size = voxel.check_kernel_size(kernel_size)
        fn = functools.partial(soft_hkc_neighbourhood, kernel_size=kernel_size)
        return _map(fn, points, idx, jnp.asarray(d, points.dtype), jnp.asarray(tau, points.dtype))
    if method == "lhf":
        if ratio is None:
            raise ValueError("method 'lhf' needs ratio to combine its two lengths; got None")
        m = _validate.n_keep(points.shape[0], _validate.check_ratio(ratio))
        g = _map(functools.partial(soft_lhf_neighbourhood, lengths=tuple(lengths)), points, idx,
                 jnp.asarray(tau, points.dtype))
        big = jnp.sort(g, axis=0)[points.shape[0] - m]  # (2,) Gamma_a, Gamma_b (Eq. (16))
        eps = _common.safe_div(big[1], big[0] + big[1], 0.5)
        return eps * g[:, 0] + (1 - eps) * g[:, 1]
    if method == "ea":
        return _map(_ea.ea_neighbourhood, points, idx)
    return soft_gfr(points, idx)


@jax.custom_jvp
def _threshold(scores, temperature, target):
    """theta with sum(sigmoid((scores - theta) / temperature)) = target, by bisection."""
    span = 40 * temperature

    def step(_, bounds):
        lo, hi = bounds
        mid = (lo + hi) / 2
        above = jnp.sum(jax.nn.sigmoid((scores - mid) / temperature)) > target
        return jnp.where(above, mid, lo), jnp.where(above, hi, mid)

    lo, hi = jax.lax.fori_loop(0, BISECTION_STEPS, step, (jnp.min(scores) - span, jnp.max(scores) + span))
    return (lo + hi) / 2


@_threshold.defjvp
def _threshold_jvp(primals, tangents):
    scores, temperature, target = primals
    ds, dt, dm = tangents
    theta = _threshold(scores, temperature, target)
    z = (scores - theta) / temperature
    w = jax.nn.sigmoid(z)
    g = w * (1 - w)  # derivative of the sigmoid
    # Implicit function theorem on F = sum sigmoid(z) - target = 0.
    num = jnp.sum(g * ds) - jnp.sum(g * z) * dt - temperature * dm
    return theta, _common.safe_div(num, jnp.sum(g), 0.0)


def soft_select(scores, ratio, *, temperature=0.05, largest: bool = True):
    """Soft top-k: keep weights in [0, 1] that sum to ratio * N.

    w_i = sigmoid((s_i - theta) / temperature) (or of theta - s_i with ``largest=False``),
    theta found by 64 bisection steps so that sum(w) = ratio * N, and differentiated by the
    implicit function theorem: d theta = sum_i g_i ds_i / sum_i g_i with g the sigmoid
    slopes. As temperature -> 0 the weights tend to the hard top-k mask (ties share).

    Args:
      scores: (N,) float scores without NaN (traced).
      ratio: fraction alpha in (0, 1] (traced: a new value does not recompile).
      temperature: > 0, in the units of the scores (traced).
      largest: keep the largest scores (True) or the smallest (static).

    Returns:
      (N,) weights in [0, 1] in the dtype of ``scores``; their sum is ratio * N up to the
      bisection's precision (and < N when ratio = 1, each weight then being about 1).

    Raises:
      ValueError: if ``scores`` is not one-dimensional.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> w = hgjax.soft_select(jnp.array([0.1, 0.9, 0.5, 0.7]), 0.5, temperature=1e-3)
      >>> [round(float(x), 3) for x in w]
      [0.0, 1.0, 0.0, 1.0]
    """
    scores = jnp.asarray(scores)
    if scores.ndim != 1:
        raise ValueError(f"scores must have shape (N,); got {scores.shape}")
    if not largest:
        scores = -scores
    temperature = jnp.asarray(temperature, scores.dtype)
    target = jnp.asarray(ratio, scores.dtype) * scores.shape[0]
    theta = _threshold(scores, temperature, target)
    return jax.nn.sigmoid((scores - theta) / temperature)


def soft_weights(points, idx, ratio: float, *, method: str = "hkc", temperature=0.05, tau=0.1, d=None,
                 kernel_size: int = 3, lengths=_lhf.DEFAULT_LENGTHS):
    """Per-point keep weights, pure in ``points``: soft_select(soft_scores(...)).

    Jit with ``static_argnames=("ratio", "method", "kernel_size", "lengths")``; ``points``,
    ``temperature``, ``tau`` and ``d`` are traced (gradients flow to all four). vmap over a
    batch of clouds of the same size with points (B, N, 3) and idx (B, N, K).

    Args:
      points: (N, 3) float32 or float64.
      idx: (N, K) neighbourhoods from :func:`soft_neighbourhoods` (same method).
      ratio: fraction alpha in (0, 1] (static: LHF uses it for its combination weights).
      method, d, tau, kernel_size, lengths: as :func:`soft_scores`.
      temperature: softness of the selection, in score units (traced).

    Returns:
      (N,) weights in [0, 1] summing to ratio * N.

    Raises:
      TypeError, ValueError: as :func:`soft_scores`.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((100, 3))
      >>> idx, d = hgjax.soft_neighbourhoods(pts, method="hkc")
      >>> w = hgjax.soft_weights(pts, idx, 0.2, method="hkc", d=d)
      >>> round(float(w.sum()), 6)
      20.0
    """
    method = _check_method(method)
    ratio = _validate.check_ratio(ratio)
    s = soft_scores(points, idx, method=method, d=d, tau=tau, ratio=ratio, kernel_size=kernel_size,
                    lengths=lengths)
    return soft_select(s, ratio, temperature=temperature, largest=SOFT_METHODS[method])


def _host_neighbourhoods(points: np.ndarray, d_factor: float, resolution: float, *, method: str,
                         kernel_size: int, roi_margin: float, capacity: int, k: int):
    """(idx (N, K) int32, d) for one validated cloud; the host half of :func:`soft_resample`."""
    index = SpatialIndex(points)
    res = resolution if resolution > 0 else _common.resolution_or_default(index, None)
    d = d_factor * res
    if method in ("hkc", "hkf"):
        idx = index.cube((kernel_size / 2 + roi_margin) * d, capacity=capacity, max_capacity=capacity)
        if idx.shape[1] < capacity:  # only when capacity > N
            idx = np.concatenate([idx, np.full((idx.shape[0], capacity - idx.shape[1]), index.n, np.int32)], 1)
    else:
        _validate.check_min_points(index.n, k, f"{k} nearest neighbours")
        idx = index.knn(k)
    return _to_caller_frame(index, idx), points.dtype.type(d)


def _neighbourhood_args(method, kernel_size, roi_margin, capacity, k, lengths):
    method = _check_method(method)
    kernel_size = voxel.check_kernel_size(kernel_size)
    roi_margin = float(roi_margin)
    if not roi_margin >= 0:
        raise ValueError(f"roi_margin must be >= 0; got {roi_margin!r}")
    capacity = _validate.check_int(capacity, "capacity", minimum=1)
    if method == "lhf":
        k = max(_lhf._check_length(n, "lengths") for n in lengths)
    else:
        k = _validate.check_int(k, "k", minimum=2)
    return dict(method=method, kernel_size=kernel_size, roi_margin=roi_margin, capacity=capacity, k=k)


def soft_neighbourhoods(points, *, method: str = "hkc", d_factor: float = voxel.DEFAULT_D_FACTOR,
                        resolution: float | None = None, kernel_size: int = 3, roi_margin: float = 0.5,
                        capacity: int = 128, k: int = 16,
                        lengths=_lhf.DEFAULT_LENGTHS):
    """Host step of soft resampling: the fixed integer neighbourhoods (not jittable).

    Build them once per cloud, then call :func:`soft_weights` (jitted) as often as needed.

    Args:
      points: (N, 3) float32 or float64 (concrete, not a tracer).
      method: a key of :data:`SOFT_METHODS`.
      d_factor: voxel spacing d = d_factor * resolution (HKC/HKF); the default is the hard
        scores' default for the invariant variant (``voxel.DEFAULT_D_FACTOR``).
      resolution: override the intrinsic resolution (default: computed).
      kernel_size: odd k of the HKC/HKF kernel.
      roi_margin: HKC/HKF ROI is the cube of half-width (k / 2 + roi_margin) d, a little
        larger than the kernel so that points near its faces enter smoothly.
      capacity: columns of the HKC/HKF index (static shape); a cube with more points raises.
      k: neighbourhood size (counting the point) for EA and GFR.
      lengths: LHF lengths; the index has max(lengths) columns.

    Returns:
      (idx, d): idx (N, K) int32 in the caller's order, padded with N (cube rows) or the
      point itself first then its neighbours by distance (kNN rows); d the voxel spacing
      as a scalar of the points' dtype.

    Raises:
      TypeError, ValueError: invalid input, or a cube holding more than ``capacity`` points.

    Examples:
      >>> import numpy as np, hgjax
      >>> idx, d = hgjax.soft_neighbourhoods(np.random.default_rng(0).random((50, 3)), method="lhf")
      >>> idx.shape
      (50, 12)
    """
    pts = _validate.check_points(points)
    d_factor = _validate.check_positive(d_factor, "d_factor")
    res = 0.0 if resolution is None else _validate.check_positive(resolution, "resolution")
    _validate.check_min_points(pts.shape[0], 2, "soft resampling")
    return _host_neighbourhoods(pts, d_factor, res, **_neighbourhood_args(method, kernel_size, roi_margin,
                                                                          capacity, k, lengths))


def soft_resample(points, ratio: float, *, method: str = "hkc", temperature=0.05, tau=0.1,
                  d_factor=voxel.DEFAULT_D_FACTOR, resolution=None, kernel_size: int = 3, roi_margin: float = 0.5,
                  capacity: int = 128, k: int = 16, lengths=_lhf.DEFAULT_LENGTHS):
    """Differentiable soft resampling: per-point keep weights summing to ratio * N.

    The neighbourhoods are built on the host through ``jax.pure_callback`` on
    ``stop_gradient(points)`` (integers: no gradient flows through them), then
    :func:`soft_weights` runs in JAX. So this function can be jitted (static: ``ratio``,
    ``method``, ``kernel_size``, ``roi_margin``, ``capacity``, ``k``, ``lengths``), vmapped
    over clouds of the same size (the callback runs once per cloud) and differentiated with
    respect to ``points``, ``temperature``, ``tau``, ``d_factor`` and ``resolution``. The
    intrinsic resolution computed when ``resolution`` is None is held constant. In an
    optimisation loop, call :func:`soft_neighbourhoods` once and jit :func:`soft_weights`.

    Args:
      points: (N, 3) float32 or float64.
      ratio: fraction alpha in (0, 1].
      method: a key of :data:`SOFT_METHODS`.
      temperature: soft top-k temperature, in score units (see :func:`soft_select`).
      tau: softness of the score (see :func:`soft_scores`).
      d_factor, resolution, kernel_size, roi_margin, capacity, k, lengths: as
        :func:`soft_neighbourhoods`.

    Returns:
      (N,) weights in [0, 1] in the dtype of ``points``, summing to ratio * N.

    Raises:
      TypeError, ValueError: invalid arguments (a cube overflowing ``capacity`` raises
      from inside the callback at run time).

    Examples:
      >>> import jax, numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((100, 3))
      >>> f = jax.jit(lambda p: hgjax.soft_resample(p, 0.2, method="ea")[0])
      >>> g = jax.grad(f)(pts)
      >>> g.shape, bool(np.isfinite(g).all())
      ((100, 3), True)
    """
    ratio = _validate.check_ratio(ratio)
    _check_traced_points(points)
    _validate.check_min_points(points.shape[0], 2, "soft resampling")
    opts = _neighbourhood_args(method, kernel_size, roi_margin, capacity, k, lengths)
    points = jnp.asarray(points)
    dtype = points.dtype
    n_cols = opts["capacity"] if opts["method"] in ("hkc", "hkf") else opts["k"]
    d_factor = jnp.asarray(d_factor, dtype)
    res = jnp.asarray(0 if resolution is None else resolution, dtype)

    def host(p, dfac, r):
        return _host_neighbourhoods(np.asarray(p), float(dfac), float(r), **opts)

    out_shape = (jax.ShapeDtypeStruct((points.shape[0], n_cols), jnp.int32), jax.ShapeDtypeStruct((), dtype))
    idx, d_host = jax.pure_callback(host, out_shape, *(jax.lax.stop_gradient(x) for x in (points, d_factor, res)),
                                    vmap_method="sequential")
    d = d_factor * res if resolution is not None else d_factor * jax.lax.stop_gradient(d_host / d_factor)
    return soft_weights(points, idx, ratio, method=opts["method"], temperature=temperature, tau=tau, d=d,
                        kernel_size=opts["kernel_size"], lengths=lengths)
