"""Hypergraph kernel convolution (HKC), paper Sec. III-A, Algorithm 1, Eqs. (10)-(11).

For each point, the voxel counts s_i of a cubic kernel (see :mod:`hgjax.scores.cubic_kernel`) are
filtered by the Haar-like high-pass G_hat = 1 - lam in the kernel's hypergraph spectrum:
s_oi = V diag(1 - lam) V^T s_i (Eq. (10)), and the local smoothness is

    beta_i = ||s_oi||_2 / ||s_i - s_oi||_2                                   (Eq. (11)).

Lower beta means sharper; resampling keeps the smallest. Because 1 - lam is constant on
each eigenspace, beta does not depend on the eigensolver's basis: it is computed through the
exact low-band projector (R / lambda_max). The variants
(:func:`hgjax.neighbours.balls.build`):

* ``"reference"``: the axis-aligned cube of the paper, d = 1.3 x the global resolution.
* ``"invariant"`` (default): d from the local spacing; the cube is turned into the point's
  local frame (:func:`hgjax.scores.cubic_kernel.oriented`, the eigenvectors of the covariance of a
  Euclidean ball that holds the cube in every orientation), and the band energies are
  averaged over the 8 sign choices of the frame's axes
  (:func:`hgjax.scores.cubic_kernel.band_energies`), so beta does not change when the cloud is
  rotated, wherever the frame is well defined (distinct covariance eigenvalues).

beta is +inf where the low band is exactly zero (signals symmetric about the centre, e.g.
interior points of a flat face aligned with the kernel).

The smooth twin :func:`soft_beta` counts with soft voxel memberships and returns the bounded
beta / (1 + beta) = ||high|| / (||high|| + ||low||), which is finite everywhere.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp

from hgjax import _method, _stream, _validate
from hgjax.neighbours import backend, balls
from hgjax.scores import _common, cubic_kernel

__all__ = ["beta", "score", "soft_beta", "soft_score"]


def beta(offsets, valid, d, *, kernel_size: int = 3, variant: str = "invariant"):
    """beta (Eq. (11)) of one cube (reference) or ball (invariant) neighbourhood.

    Args:
      offsets: (K, 3) the neighbourhood minus the point, padding rows masked by
        ``valid`` (K,).
      d: voxel spacing (scalar).
      kernel_size: k of the k x k x k kernel (static).
      variant: ``"invariant"`` (kernel in the local frame) or ``"reference"`` (static).

    Returns:
      Scalar beta >= 0, +inf when the low band is 0.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> offsets = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
      >>> round(float(hgjax.scores.hkc.beta(offsets, jnp.ones(3, bool), 1.0, variant="reference")), 4)
      8.9443
    """
    high2, low2 = cubic_kernel.band_energies(cubic_kernel.kernel_signal(offsets, valid, d, kernel_size, variant), kernel_size, variant)
    return _common.safe_div(_common.safe_sqrt(high2), _common.safe_sqrt(low2), jnp.inf)


def soft_beta(offsets, valid, d, tau, *, kernel_size: int = 3, variant: str = "invariant"):
    """Smooth bounded HKC score of one cube neighbourhood: beta / (1 + beta) of soft counts.

    ||high|| / (||high|| + ||low||) (Eqs. (10)-(11)) of
    :func:`hgjax.scores.cubic_kernel.soft_local_signal`, with guarded square roots (0 when the
    signal is 0). As tau -> 0 it tends to beta / (1 + beta) of the hard counts.

    Args:
      offsets, valid, d: as :func:`beta`.
      tau: softness of the voxel membership, relative to d (scalar > 0, traced).
      kernel_size: k (static).
      variant: as :func:`beta` (static).

    Returns:
      Scalar in [0, 1]; lower is sharper.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> offsets = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
      >>> round(float(hgjax.scores.hkc.soft_beta(offsets, jnp.ones(3, bool), 1.0, 1e-3)), 6)
      1.0
    """
    s = cubic_kernel.kernel_signal(offsets, valid, d, kernel_size, variant, tau)
    return _common.band_ratio(*cubic_kernel.band_energies(s, kernel_size, variant))


@functools.lru_cache(maxsize=None)
def _kernel(kernel_size: int, variant: str):
    return functools.partial(beta, kernel_size=kernel_size, variant=variant)


@functools.lru_cache(maxsize=None)
def _soft_kernel(kernel_size: int, variant: str):
    return functools.partial(soft_beta, kernel_size=kernel_size, variant=variant)


def score(nb, *, variant: str = "invariant", kernel_size: int = 3, chunk_size: int | None = None,
          progress: bool = False):
    """HKC beta (Eq. (11)) of every neighbourhood; lower is sharper.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`hgjax.neighbours.balls.build`
        (its ``scale`` is the voxel spacing d per point).
      variant: the one the neighbourhoods were built for (static).
      kernel_size: odd k, the one the neighbourhoods were built for (static).
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) beta in the dtype of ``nb.points``; +inf where the low band vanishes.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((200, 3)), "hkc")
      >>> hgjax.scores.hkc.score(nb).shape
      (200,)
    """
    variant = _validate.check_variant(variant)
    kernel_size = _validate.check_kernel_size(kernel_size)
    _validate.check_scale(nb, "hkc")
    return _stream.map_neighbourhoods(_kernel(kernel_size, variant), nb, row_args=(nb.scale,), chunk_size=chunk_size,
                                      progress=progress, narrow=True)


def soft_score(nb, *, tau=0.1, variant: str = "invariant", kernel_size: int = 3):
    """Smooth HKC score of every neighbourhood (:func:`soft_beta`), pure JAX and differentiable.

    Called eagerly it streams fixed-size chunks through one compiled kernel, as :func:`score`.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`hgjax.neighbours.balls.build`.
      tau: softness of the voxel membership, relative to d (traced).
      variant: the one the neighbourhoods were built for (static).
      kernel_size: odd k (static).

    Returns:
      (N,) scores in [0, 1]; lower is sharper.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "hkc")
      >>> s = hgjax.scores.hkc.soft_score(nb)
      >>> bool(((s >= 0) & (s <= 1)).all())
      True
    """
    variant = _validate.check_variant(variant)
    kernel_size = _validate.check_kernel_size(kernel_size)
    _validate.check_scale(nb, "hkc")
    tau = _validate.check_traced_positive(tau, "tau")
    return _stream.map_neighbourhoods(_soft_kernel(kernel_size, variant), nb, row_args=(nb.scale,),
                                      args=(_stream.as_arg(tau, nb.points.dtype),))


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of HKC or HKF for a tiled run of ``n`` points.

    The build parameters still to be decided from the whole cloud (``d_factor``, the
    reference resolution) stay None until :func:`resolve_build`.

    Raises:
      TypeError, ValueError: invalid parameters, or fewer than 2 points.
    """
    build = balls.build_params(**{k: params[k] for k in ("variant", "d_factor", "kernel_size", "resolution",
                                                          "dedupe") if k in params})
    _validate.check_capacity_param(params, 1)
    _validate.check_min_points(n, 2, "HKC/HKF")
    return backend.with_search(build, params), {"kernel_size": build["kernel_size"], "variant": build["variant"]}


def resolve_build(build: dict, stats) -> dict:
    """``build`` with the cube's spacing decided from the seeded sample's nearest distances ``stats()``."""
    return balls.resolve(build, stats()) if balls.needs_stats(build) else build


def tile_rows(index, rows, build: dict, dtype):
    """(part, idx, (d,), reach) per batch: the cube neighbourhoods of ``rows`` by the build's search
    (:func:`hgjax.neighbours.balls.tile_batches`)."""
    for part, idx, scale, reach in balls.tile_batches(index, rows, build):
        yield part, idx, (scale.astype(dtype),), reach


def cube_reach(build: dict) -> tuple[int, int]:
    """(k, radii) of the cube's halo: its spacing estimate reads the k-nearest radius of each of the
    point's k nearest neighbours (:func:`hgjax.neighbours.spatial.local_spacing`), two radii, where the invariant
    cube is sized by it (no fixed ``resolution``); one otherwise."""
    adaptive = build["variant"] == "invariant" and build["resolution"] is None
    return balls.LOCAL_K + 1, 2 if adaptive else 1


def _tile_kernel(params: dict):
    return _kernel(params["kernel_size"], params["variant"]), True


METHOD = _method.Method(
    "hkc", "cube", largest=False, needs_key=False,
    summary="hypergraph kernel convolution: keep the smallest high/low band ratio beta",
    citation=f"{_method.PAPER}, Alg. 1, Eq. (11)", build=balls.build, score=score,
    soft_score=soft_score,
    tiling=_method.Tiling(params=tile_params, reach=cube_reach, resolve=resolve_build, rows=tile_rows,
                          kernel=_tile_kernel))
