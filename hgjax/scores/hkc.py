"""Hypergraph kernel convolution (HKC), paper Sec. III-A, Algorithm 1, Eqs. (10)-(11).

For each point, the voxel counts s_i of a cubic kernel (see :mod:`hgjax.scores.voxel`) are
filtered by the Haar-like high-pass G_hat = 1 - lam in the kernel's hypergraph spectrum:
s_oi = V diag(1 - lam) V^T s_i (Eq. (10)), and the local smoothness is

    beta_i = ||s_oi||_2 / ||s_i - s_oi||_2                                   (Eq. (11)).

Lower beta means sharper; resampling keeps the smallest. Because 1 - lam is constant on
each eigenspace, beta does not depend on the eigensolver's basis: for a given d both variants
compute the same value, through the exact low-band projector (R / lambda_max). The variants
differ only in the default d factor: 1.3 for ``"reference"`` (REFERENCE.md) and 2.5 for
``"invariant"`` (bench/results/edge_defaults.md). beta is +inf where the low band is exactly zero (signals
symmetric about the centre, e.g. interior points of an axis-aligned flat face).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate
from hgjax.neighbourhoods import SpatialIndex
from hgjax.scores import _common, voxel

__all__ = ["hkc", "hkc_neighbourhood"]


def hkc_neighbourhood(centre, nbrs, valid, d, *, kernel_size: int = 3):
    """beta (Eq. (11)) of one cube neighbourhood.

    Args:
      centre: (3,) the point.
      nbrs: (K, 3) its cube neighbourhood, padding rows masked by ``valid`` (K,).
      d: voxel spacing.
      kernel_size: k of the k x k x k kernel (static).

    Returns:
      Scalar beta >= 0, +inf when the low band is 0.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> nbrs = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
      >>> round(float(hgjax.scores.hkc_neighbourhood(jnp.zeros(3), nbrs, jnp.ones(3, bool), 1.0)), 4)
      8.9443
    """
    s = voxel.local_signal(centre, nbrs, valid, d, kernel_size)
    low, high = voxel.low_high(s, kernel_size)
    return _common.safe_div(jnp.linalg.norm(high), jnp.linalg.norm(low), jnp.inf)


@functools.lru_cache(maxsize=None)
def _chunk_kernel(kernel_size: int):
    fn = functools.partial(hkc_neighbourhood, kernel_size=kernel_size)
    return jax.jit(_common.map_neighbourhoods(fn))


def hkc(points, *, variant: str = "invariant", d_factor: float | None = None, kernel_size: int = 3,
        resolution: float | None = None, chunk_size: int | None = None,
        progress: bool = False) -> np.ndarray:
    """HKC local smoothness beta per point (paper Eq. (11)); lower is sharper.

    Args:
      points: (N, 3) float32 or float64, N >= 2.
      variant: ``"invariant"`` or ``"reference"``; they differ only in the default d_factor.
      d_factor: voxel spacing d = d_factor * resolution. Default: 1.3 (REFERENCE.md) for
        ``variant="reference"``, 2.5 (``voxel.DEFAULT_D_FACTOR``, tuned on the edge benchmark)
        for ``"invariant"``.
      kernel_size: odd k of the k x k x k kernel (default 3, N_k = 27). Static: a new value
        compiles a new kernel.
      resolution: override the intrinsic resolution (default: computed).
      chunk_size: points per streamed chunk (default: automatic). Does not change results.
      progress: show a progress bar on stderr for long runs.

    Returns:
      (N,) beta in the dtype of ``points``; +inf where the low band vanishes.

    Raises:
      TypeError, ValueError: invalid points or parameters, N < 2, unknown variant.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((200, 3))
      >>> beta = hgjax.scores.hkc(pts)
      >>> beta.shape, beta.dtype
      ((200,), dtype('float64'))
    """
    pts = _validate.check_points(points)
    variant = _common.check_variant(variant)
    d_factor = voxel.d_factor_or_default(d_factor, variant)
    kernel_size = voxel.check_kernel_size(kernel_size)
    _validate.check_min_points(pts.shape[0], 2, "HKC")
    index = SpatialIndex(pts)
    d = d_factor * _common.resolution_or_default(index, resolution)
    return _common.finish(index, voxel.stream_cubes(index, _chunk_kernel(kernel_size), d, kernel_size,
                                                    chunk_size, progress), pts.dtype)
