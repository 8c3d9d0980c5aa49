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

from hgjax import _stream, _validate
from hgjax.neighbours import backend, balls, spatial
from hgjax.scores import _common, eigen

__all__ = ["band_energies", "default_d_factor", "frame", "local_signal", "low_high", "neighbourhoods", "oriented",
           "soft_local_signal"]


FRAME_GAP = 1e-9  # eigenvalue gaps below this x trace(C) are degenerate: no frame derivative across them
REFERENCE_D_FACTOR = 1.3  # d = 1.3 x resolution (REFERENCE.md)
# The default variant's d = f x local spacing, f from the sampling irregularity c (the
# coefficient of variation of nearest-neighbour distances): REGULAR_D_FACTOR for lattices
# (c <= 0.25: grids up to noise p = 0.2 spacings), IRREGULAR_D_FACTOR for random samples
# (c >= 0.45), linear in between. Measured on the edge benchmark in both regimes
# (bench/results/edge_defaults.md).
REGULAR_D_FACTOR, IRREGULAR_D_FACTOR = 1.1, 1.6
IRREGULARITY_RANGE = (0.25, 0.45)
LOCAL_K = 16  # neighbours from which the default variant's local spacing is estimated
MAX_COUNT = 256  # the default variant's cube shrinks to hold fewer points than this


def default_d_factor(irregularity: float) -> float:
    """The default variant's d factor for a cloud of this sampling irregularity.

    Args:
      irregularity: std / mean of the nearest-neighbour distances
        (:func:`hgjax.neighbours.spatial.irregularity`).

    Returns:
      1.1 up to 0.25 (lattice-like sampling), 1.6 from 0.45 (random sampling), linear
      in between.

    Examples:
      >>> from hgjax.scores import voxel
      >>> voxel.default_d_factor(0.0), voxel.default_d_factor(0.52)
      (1.1, 1.6)
    """
    lo, hi = IRREGULARITY_RANGE
    t = min(max((irregularity - lo) / (hi - lo), 0.0), 1.0)
    return REGULAR_D_FACTOR + t * (IRREGULAR_D_FACTOR - REGULAR_D_FACTOR)


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
      >>> from hgjax.scores import voxel
      >>> s = voxel.local_signal(jnp.array([[0.0, 0, 0], [1, 0, 0]]), jnp.ones(2, bool), 1.0, 3)
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
      >>> from hgjax.scores import voxel
      >>> s = voxel.soft_local_signal(jnp.array([[0.0, 0, 0], [1, 0, 0]]), jnp.ones(2, bool), 1.0, 1e-3, 3)
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
      >>> from hgjax.scores import voxel
      >>> low, high = voxel.low_high(jnp.zeros(27).at[13].set(1.0), 3)  # symmetric: no low band
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
      >>> from hgjax.scores.voxel import frame
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
      >>> from hgjax.scores.voxel import oriented
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
      >>> from hgjax.scores.voxel import band_energies
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


def build_params(*, variant: str = "invariant", d_factor: float | None = None, kernel_size: int = 3,
                 resolution: float | None = None, dedupe: bool | None = None) -> dict:
    """Validated build parameters of HKC/HKF; ``d_factor`` and a reference ``resolution`` may still be None.

    Raises:
      TypeError, ValueError: invalid arguments.
    """
    variant = _validate.check_choice(variant, "variant", ("invariant", "reference"))
    return {
        "variant": variant,
        "d_factor": None if d_factor is None else _validate.check_positive(d_factor, "d_factor"),
        "kernel_size": _validate.check_kernel_size(kernel_size),
        "resolution": None if resolution is None else _validate.check_positive(resolution, "resolution"),
        "dedupe": variant == "invariant" if dedupe is None else _validate.check_bool(dedupe, "dedupe"),
    }


def needs_stats(params: dict) -> bool:
    """Whether resolving ``params`` needs the cloud's :class:`hgjax.neighbours.spatial.SampleStats`."""
    return params["d_factor"] is None or (params["variant"] == "reference" and params["resolution"] is None)


def resolve(params: dict, stats: spatial.SampleStats | None) -> dict:
    """Build parameters with every whole-cloud decision made: d_factor, and the reference resolution.

    The invariant variant's d factor comes from the sample's irregularity
    (:func:`default_d_factor`); the reference variant's resolution is the sample's mean
    nearest-other distance (1.0 when the cloud has a single location) and its factor 1.3.
    """
    out = dict(params)
    if out["d_factor"] is None:
        out["d_factor"] = REFERENCE_D_FACTOR if out["variant"] == "reference" else default_d_factor(stats.irregularity())
    if out["variant"] == "reference" and out["resolution"] is None:
        out["resolution"] = stats.resolution(robust=False) or 1.0
    return out


def row_batches(index: spatial.SpatialIndex, rows: np.ndarray, params: dict):
    """Cube neighbourhoods of sorted ``rows`` (R,) with resolved ``params`` (see :func:`resolve`), batch by batch.

    Batches are :func:`hgjax.neighbours.spatial.batches` of the rows; each is built as soon as the
    previous one is consumed, reusing what the previous ones found (spacings of shared
    neighbours, the typical row width).

    Yields:
      (part, idx, scale, reach) per batch: part a slice of ``rows``; idx (r, W) int32
      sorted-frame indices by increasing distance (Chebyshev for "reference", Euclidean for
      "invariant"), padded with n, W the batch's fullest row; scale (r,) float64 voxel
      spacing d; reach (r,) the distance per axis within which every point the row used
      lies (cube or ball, and spacing estimate), inf where ``index`` holds LOCAL_K locations
      or fewer (no radius short of the whole cloud holds the estimate's neighbours).
    """
    rows = np.asarray(rows, dtype=np.int64)
    k = params["kernel_size"]
    invariant = params["variant"] == "invariant"
    # The invariant variant turns its cube into the point's local frame, so it queries the
    # ball that holds the cube in every orientation (radius sqrt(3) x the half-width).
    widen = np.sqrt(3.0) if invariant else 1.0
    factor = widen * k / 2 * params["d_factor"]
    max_count = MAX_COUNT if invariant else None
    norm = 2 if invariant else np.inf
    adaptive = params["resolution"] is None
    rk = np.full(index.n, np.nan) if adaptive else None
    start = 64 if adaptive else 32
    for part in spatial.batches(rows.size):
        if adaptive:
            # One query per batch serves the spacing (its first LOCAL_K + 1 columns) and the
            # ball (a prefix of each row; rows whose ball is longer are queried again).
            nearest = index.nearest(rows[part], min(max(start, LOCAL_K + 2), index.n))
            res, reach = spatial.local_spacing(index, rows[part], LOCAL_K, query=nearest, rk=rk)
            if index.n <= LOCAL_K:  # the estimate read fewer neighbours than the whole cloud may hold
                reach = np.full(reach.shape, np.inf)
        else:
            nearest, res, reach = None, params["resolution"], 0.0
        half = np.broadcast_to(factor * res, rows[part].shape)
        reach = np.maximum(reach, half)
        idx, half = index.cube(half, rows[part], capacity=start, max_count=max_count, norm=norm,
                               query=nearest if invariant else None)
        # Rows are in spatial order, so the next batch is alike: start it at this one's 95th
        # percentile count instead of doubling up from 32 again.
        start = int(np.percentile((idx < index.n).sum(axis=1), 95)) + 2
        yield part, idx, 2 / k * half / widen, reach


def neighbourhoods(points, *, variant: str = "invariant", d_factor: float | None = None, kernel_size: int = 3,
                   resolution: float | None = None, dedupe: bool | None = None,
                   capacity: int | None = None, search: str = "host", cell_slots: int | None = None,
                   cell_edge=None) -> spatial.Neighbourhoods:
    """Cube neighbourhoods of HKC/HKF and the voxel spacing d of each point (host; jittable with ``search="jax"``).

    The ROI of point i is the axis-aligned cube of half-width k d_i / 2 (Fig. 2), with

    * ``variant="reference"``: d_i = 1.3 x the intrinsic resolution (REFERENCE.md: mean
      distance to the nearest other point), duplicates kept;
    * ``variant="invariant"`` (default): d_i = f x the point's local spacing s_i =
      1 / sqrt(areal density) estimated from its 16 nearest distinct points
      (:func:`hgjax.neighbours.spatial.local_spacing`), exact duplicates counted once, and f from
      the cloud's sampling irregularity (:func:`default_d_factor`: 1.1 on lattice-like
      clouds, 1.6 on random samples). The spacing, unlike the nearest-neighbour distance,
      means the same on grids and on random samples, and where the density changes the
      kernel follows it. Where a cube would still hold 256 points or more (a sparse point next
      to a much denser region), it shrinks to the Chebyshev distance of the point's 256th
      nearest point: every cube holds all its points (no truncation) and at most 255, so
      mixed densities never raise a capacity error. Exact duplicates and far outliers
      change nothing.

    Args:
      points: (N, 3) float32 or float64, N >= 2.
      variant: ``"invariant"`` or ``"reference"``.
      d_factor: d = d_factor x resolution (default: :func:`default_d_factor` for
        "invariant", 1.3 for "reference").
      kernel_size: odd k of the k x k x k kernel.
      resolution: a fixed resolution (spacing) for every point instead of the computed one.
      dedupe: count exact duplicates once (default: True for "invariant", False for
        "reference").
      capacity: fixed number of columns K (see :func:`hgjax.cube`); default automatic. With
        ``search="jax"`` under ``jit`` it sets a static shape: pass the one an eager build
        recorded (``nb.params``); without it, 256 columns for "invariant" (a cube never
        holds more) and 128 for "reference" (a wider cube stops the program, naming the
        capacity it needs).
      search: ``"host"`` (SciPy's k-d tree; not jittable) or ``"jax"`` (the traced search,
        :func:`hgjax.neighbours.balls.traced`: jit, vmap; the host's neighbour sets and ``scale``,
        every whole-cloud decision (d factor, resolution) traced too).
      cell_slots, cell_edge: the traced search's candidates read per step (static) and first
        cell edge (traced, or None from the data): speed settings, never limits.

    Returns:
      :class:`hgjax.Neighbourhoods` with ``scale`` = (N,) voxel spacing d_i.

    Raises:
      TypeError, ValueError: invalid arguments, N < 2, or a fixed capacity too small.

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import voxel
      >>> nb = voxel.neighbourhoods(np.random.default_rng(0).random((300, 3)))
      >>> nb.scale.shape, bool((nb.idx[:, 0] == np.arange(300)).all())
      ((300,), True)
    """
    search = _validate.check_choice(search, "search", backend.SEARCHES)
    if search == "jax":
        return _traced_neighbourhoods(points, build_params(variant=variant, d_factor=d_factor, kernel_size=kernel_size,
                                                           resolution=resolution, dedupe=dedupe),
                                      capacity, cell_slots, cell_edge)
    pts = _validate.check_points(points)
    params = build_params(variant=variant, d_factor=d_factor, kernel_size=kernel_size, resolution=resolution,
                          dedupe=dedupe)
    _validate.check_min_points(pts.shape[0], 2, "HKC/HKF")
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    index = spatial.SpatialIndex(spatial.local_frame(pts)[0], dedupe=params["dedupe"])
    resolved = resolve(params, spatial.sample_stats(index) if needs_stats(params) else None)
    scales = []

    def rows():
        for _, idx, scale, _ in row_batches(index, np.arange(index.n), resolved):
            scales.append(scale)
            yield idx

    idx = spatial.caller_rows(index, rows(), cap, what="cube")
    return spatial.assemble(pts, index, idx, np.concatenate(scales), params=params)


def _traced_neighbourhoods(points, params: dict, capacity, cell_slots, cell_edge) -> spatial.Neighbourhoods:
    """:func:`neighbourhoods` by the traced search: the cube (or ball) with every decision of :func:`resolve` traced."""
    traced = _stream.is_traced(points)
    pts = _validate.check_traced_points(points) if traced else _validate.check_points(points)
    _validate.check_min_points(pts.shape[0], 2, "HKC/HKF")
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    cells = None if cell_slots is None else _validate.check_int(cell_slots, "cell_slots", minimum=1)
    invariant = params["variant"] == "invariant"
    if params["resolution"] is not None:
        spacing = params["resolution"]
    else:
        spacing = "local" if invariant else "mean_other"
    d_factor = params["d_factor"]
    if d_factor is None and not invariant:
        d_factor = REFERENCE_D_FACTOR
    return balls.traced(
        pts, metric="l2" if invariant else "linf", widen=np.sqrt(3.0) if invariant else 1.0,
        kernel_size=params["kernel_size"], d_factor=d_factor,
        ramp=(IRREGULARITY_RANGE, (REGULAR_D_FACTOR, IRREGULAR_D_FACTOR)), spacing=spacing, local_k=LOCAL_K,
        max_count=MAX_COUNT if invariant else None, dedupe=params["dedupe"], capacity=cap, cell_slots=cells,
        cell_edge=cell_edge, params=params)
