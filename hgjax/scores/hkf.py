"""Hypergraph kernel filtering (HKF), paper Sec. III-B, Algorithm 2, Eq. (12).

Same kernel and local signal s_i as HKC (:mod:`hgjax.scores.voxel`). With the band
threshold t = argmax(diff(lam)) + 1 (t = N_k - 2 for a cubic kernel) the local smoothness is
the share of high-frequency energy:

* ``variant="reference"`` (Eq. (12), REFERENCE.md): sigma_i = sum_{j<t} |s_hat(j)| /
  sum_j |s_hat(j)| with s_hat = V^T s_i and V the basis NumPy's ``eigh`` returns for the
  kernel's R. The high band is a 25-dimensional degenerate eigenspace, so this L1 ratio
  depends on that arbitrary basis (another LAPACK build gives other scores).
* ``variant="invariant"`` (default): sigma_i = ||P_high s_i|| / (||P_high s_i|| +
  ||P_low s_i||), the L1 norm of the two band energies (L2 norms of the projections onto
  each band), which no choice of basis can change. For a cubic kernel this equals
  beta / (1 + beta) with HKC's beta, so it ranks points exactly like HKC.

Lower sigma means sharper; resampling keeps the smallest. sigma is always finite in [0, 1].
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbourhoods import SpatialIndex
from hgjax.scores import _common, voxel

__all__ = ["hkf", "hkf_neighbourhood"]


def hkf_neighbourhood(centre, nbrs, valid, d, v=None, t=None, *, kernel_size: int = 3,
                      variant: str = "invariant"):
    """sigma (Eq. (12)) of one cube neighbourhood.

    Args:
      centre: (3,) the point.
      nbrs: (K, 3) its cube neighbourhood, padding rows masked by ``valid`` (K,).
      d: voxel spacing.
      v: (N_k, N_k) kernel basis (``"reference"`` only).
      t: band threshold (``"reference"`` only).
      kernel_size: k (static).
      variant: ``"invariant"`` or ``"reference"`` (static).

    Returns:
      Scalar sigma in [0, 1].

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> nbrs = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
      >>> round(float(hgjax.scores.hkf_neighbourhood(jnp.zeros(3), nbrs, jnp.ones(3, bool), 1.0)), 4)
      0.8994
    """
    s = voxel.local_signal(centre, nbrs, valid, d, kernel_size)
    if variant == "reference":
        s_hat = jnp.abs(v.T @ s)
        high = jnp.sum(jnp.where(jnp.arange(s.shape[0]) < t, s_hat, 0))
        return _common.safe_div(high, jnp.sum(s_hat), 0.0)
    low, high = voxel.low_high(s, kernel_size)
    nh, nl = jnp.linalg.norm(high), jnp.linalg.norm(low)
    return _common.safe_div(nh, nh + nl, 0.0)


@functools.lru_cache(maxsize=None)
def _chunk_kernel(kernel_size: int, variant: str):
    fn = functools.partial(hkf_neighbourhood, kernel_size=kernel_size, variant=variant)
    return jax.jit(_common.map_neighbourhoods(fn))


def hkf(points, *, variant: str = "invariant", d_factor: float | None = None, kernel_size: int = 3,
        resolution: float | None = None, chunk_size: int | None = None,
        progress: bool = False) -> np.ndarray:
    """HKF local smoothness sigma per point (paper Eq. (12)); lower is sharper.

    Args:
      points: (N, 3) float32 or float64, N >= 2.
      variant: ``"invariant"`` (default, basis-free band energies) or ``"reference"``
        (the paper's L1 ratio in NumPy's eigenbasis); see the module docstring.
      d_factor: voxel spacing d = d_factor * resolution. Default: 1.3 (REFERENCE.md) for
        ``variant="reference"``, 2.5 (``voxel.DEFAULT_D_FACTOR``, tuned on the edge benchmark)
        for ``"invariant"``.
      kernel_size: odd k of the k x k x k kernel (default 3). Static: recompiles.
      resolution: override the intrinsic resolution (default: computed).
      chunk_size: points per streamed chunk (default: automatic). Does not change results.
      progress: show a progress bar on stderr for long runs.

    Returns:
      (N,) sigma in [0, 1], in the dtype of ``points``.

    Raises:
      TypeError, ValueError: invalid points or parameters, N < 2, unknown variant.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((200, 3))
      >>> sigma = hgjax.scores.hkf(pts, variant="reference")
      >>> bool(((sigma >= 0) & (sigma <= 1)).all())
      True
    """
    pts = _validate.check_points(points)
    variant = _common.check_variant(variant)
    d_factor = voxel.d_factor_or_default(d_factor, variant)
    kernel_size = voxel.check_kernel_size(kernel_size)
    _validate.check_min_points(pts.shape[0], 2, "HKF")
    index = SpatialIndex(pts)
    d = d_factor * _common.resolution_or_default(index, resolution)
    extra = ()
    if variant == "reference":
        _, v, t = voxel.reference_spectrum(kernel_size, d)
        extra = (jnp.asarray(v, dtype=_stream.working_dtype(pts.dtype)), jnp.asarray(t, dtype=jnp.int32))
    out = voxel.stream_cubes(index, _chunk_kernel(kernel_size, variant), d, kernel_size, chunk_size,
                             progress, extra)
    return _common.finish(index, out, pts.dtype)
