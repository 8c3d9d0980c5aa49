"""Hypergraph kernel filtering (HKF), paper Sec. III-B, Algorithm 2, Eq. (12).

Same kernel and local signal s_i as HKC (:mod:`hgjax.scores.cubic_kernel`). With the band
threshold t = argmax(diff(lam)) + 1 (t = N_k - 2 for a cubic kernel) the local smoothness is
the share of high-frequency energy:

* ``variant="reference"`` (Eq. (12), REFERENCE.md): sigma_i = sum_{j<t} |s_hat(j)| /
  sum_j |s_hat(j)| with s_hat = V^T s_i and V the basis NumPy's ``eigh`` returns for the
  kernel's R. The high band is a 25-dimensional degenerate eigenspace, so this L1 ratio
  depends on that arbitrary basis (another LAPACK build gives other scores).
* ``variant="invariant"`` (default): sigma_i = ||P_high s_i|| / (||P_high s_i|| +
  ||P_low s_i||), the L1 norm of the two band energies (L2 norms of the projections onto
  each band), which no choice of basis can change, with HKC's invariant kernel (turned
  into the local frame, energies averaged over the frame's axis signs:
  :func:`hgjax.scores.cubic_kernel.band_energies`). This equals beta / (1 + beta) with HKC's
  beta, so it ranks points exactly like HKC, and its smooth twin is HKC's: the registry's
  HKF soft score is :func:`hgjax.scores.hkc.soft_score`.

Lower sigma means sharper; resampling keeps the smallest. sigma is always finite in [0, 1].
"""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp

from hgjax import _method, _stream, _validate
from hgjax.neighbours import balls
from hgjax.scores import _common, cubic_kernel, hkc

__all__ = ["score", "sigma"]


def sigma(offsets, valid, d, *, kernel_size: int = 3, variant: str = "invariant"):
    """sigma (Eq. (12)) of one cube neighbourhood.

    Args:
      offsets: (K, 3) the cube neighbourhood minus the point, padding rows masked by
        ``valid`` (K,).
      d: voxel spacing (scalar).
      kernel_size: k (static).
      variant: ``"invariant"`` or ``"reference"`` (static).

    Returns:
      Scalar sigma in [0, 1].

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> offsets = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
      >>> round(float(hgjax.scores.hkf.sigma(offsets, jnp.ones(3, bool), 1.0)), 4)  # invariant: LAPACK-independent
      0.8144
    """
    if variant == "reference":
        s = cubic_kernel.local_signal(offsets, valid, d, kernel_size)
        _, v, t = cubic_kernel.reference_spectrum(kernel_size)
        s_hat = jnp.abs(_common.matmul(jnp.asarray(v, s.dtype).T, s))
        return _common.safe_div(jnp.sum(s_hat[:t]), jnp.sum(s_hat), 0.0)
    s = cubic_kernel.kernel_signal(offsets, valid, d, kernel_size, variant)
    return _common.band_ratio(*cubic_kernel.band_energies(s, kernel_size, variant))


@functools.lru_cache(maxsize=None)
def _kernel(kernel_size: int, variant: str):
    return functools.partial(sigma, kernel_size=kernel_size, variant=variant)


def score(nb, *, variant: str = "invariant", kernel_size: int = 3, chunk_size: int | None = None,
          progress: bool = False):
    """HKF sigma (Eq. (12)) of every neighbourhood; lower is sharper.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`hgjax.neighbours.balls.build`.
      variant: ``"invariant"`` (default, basis-free band energies) or ``"reference"`` (the
        paper's L1 ratio in NumPy's eigenbasis); static.
      kernel_size: odd k (static).
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) sigma in [0, 1], in the dtype of ``nb.points``.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((200, 3)), "hkf", variant="reference")
      >>> s = hgjax.scores.hkf.score(nb, variant="reference")
      >>> bool(((s >= 0) & (s <= 1)).all())
      True
    """
    variant = _validate.check_variant(variant)
    kernel_size = _validate.check_kernel_size(kernel_size)
    _validate.check_scale(nb, "hkf")
    return _stream.map_neighbourhoods(_kernel(kernel_size, variant), nb, row_args=(nb.scale,),
                                      chunk_size=chunk_size, progress=progress, narrow=True)


def _tile_kernel(params: dict):
    return _kernel(params["kernel_size"], params["variant"]), True


METHOD = _method.Method(
    "hkf", "cube", largest=False, needs_key=False,
    summary="hypergraph kernel filtering: keep the smallest high-band share sigma",
    citation=f"{_method.PAPER}, Alg. 2, Eq. (12)", build=balls.build, score=score,
    soft_score=hkc.soft_score,
    tiling=dataclasses.replace(hkc.METHOD.tiling, kernel=_tile_kernel),
    ranks_as=(hkc.METHOD.name, "HKF's sigma = beta / (1 + beta) grows with HKC's beta, on the same cubes"))
