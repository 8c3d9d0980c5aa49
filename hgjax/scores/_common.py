"""Pieces shared by the per-method score modules: safe arithmetic, exact scaling."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp


def matmul(*factors: jax.Array) -> jax.Array:
    """The product of ``factors``, left to right, at full float precision.

    XLA may run a float32 product on a GPU in TF32 (10-bit mantissa) at its default
    precision; the local frames and eigenvalues here need every bit of the caller's dtype.
    """
    return functools.reduce(functools.partial(jnp.matmul, precision=jax.lax.Precision.HIGHEST), factors)


def centred_scatter(x: jax.Array, valid: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(count, mean (3,), scatter (3, 3)) of the valid rows of x (K, 3): sum (x - mean)(x - mean)^T.

    Padding rows (``valid`` False) take no part, whatever they hold; count is at least 1, so
    an empty neighbourhood gives a zero mean and scatter.
    """
    x = jnp.where(valid[:, None], x, 0)
    count = jnp.maximum(jnp.sum(valid), 1).astype(x.dtype)
    mean = jnp.sum(x, axis=0) / count
    y = jnp.where(valid[:, None], x - mean[None, :], 0)
    return count, mean, matmul(y.T, y)


PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # the six entries of a symmetric 3 x 3, in this order


def centred_entries(x: jax.Array, valid: jax.Array | None = None):
    """(mean, entries) of the rows of x (n, 3): the mean row and the scatter sum (x - mean)(x - mean)^T.

    Summed per coordinate, with the scatter as its six entries in ``PAIRS`` order (scalars,
    not a stacked (3, 3)): XLA fuses these sums, where batched dots of this size and stacked
    matrices are slow (:func:`hgjax.scores.eigen.eigenvalues` takes the entries as they are).

    Args:
      x: (n, 3) rows.
      valid: (n,) bool, or None for all rows. Padding rows take no part, whatever they hold;
        the count is at least 1, so an empty neighbourhood gives a zero mean and scatter.

    Returns:
      (mean: three scalars, entries: six scalars), in the dtype of ``x``.
    """
    cols = [x[:, k] if valid is None else jnp.where(valid, x[:, k], 0) for k in range(3)]
    count = x.shape[0] if valid is None else jnp.maximum(jnp.sum(valid), 1).astype(x.dtype)
    mean = [jnp.sum(col) / count for col in cols]
    y = [col - m if valid is None else jnp.where(valid, col - m, 0) for col, m in zip(cols, mean)]
    return mean, tuple(jnp.sum(y[i] * y[j]) for i, j in PAIRS)


def form(entries, u: jax.Array, w: jax.Array) -> jax.Array:
    """u^T C w for the symmetric 3 x 3 C given by its six ``entries`` (``PAIRS`` order) and u, w (3,)."""
    c = dict(zip(PAIRS, entries))
    return sum(c[i, j] * (u[i] * w[j] if i == j else u[i] * w[j] + u[j] * w[i]) for i, j in PAIRS)


def safe_div(num: jax.Array, den: jax.Array, empty) -> jax.Array:
    """num / den, and ``empty`` where den == 0 (no NaN, finite gradients)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), empty)


SWITCH_CLIP = 40.0  # |argument| beyond which a soft switch is flat (sigmoid(40) = 1 - 4e-18)
SWITCH_TAU_FLOOR = 2.0**-40  # softness below which a switch is as sharp as at the floor


def switch_argument(x: jax.Array, tau) -> jax.Array:
    """x / max(tau, 2^-40) clipped to +-SWITCH_CLIP: a soft switch's argument for |x| of order 1.

    Its derivatives stay finite however small tau is: the tau derivative -x / tau^2 is at most
    |x| 2^80, so the flat tails contribute 0 rather than 0 x inf. Below the floor the switch
    keeps its sharpness at the floor and its tau derivative is 0. The floor is a constant
    rather than a comparison of |x| with tau: with that comparison XLA CPU compiles a JVP of
    LHF's eigenvalue ratio that drops a tangent term under ``jit`` (its reshape-mover and
    algebraic-simplifier passes together).
    """
    return jnp.clip(x / jnp.maximum(tau, SWITCH_TAU_FLOOR), -SWITCH_CLIP, SWITCH_CLIP)


def safe_sqrt(x: jax.Array) -> jax.Array:
    """sqrt(x) for x > 0 and 0 elsewhere, with finite gradients at 0."""
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def band_ratio(high2: jax.Array, low2: jax.Array) -> jax.Array:
    """sqrt(high2) / (sqrt(high2) + sqrt(low2)) from squared band energies; 0 when both vanish."""
    h, l = safe_sqrt(high2), safe_sqrt(low2)
    return safe_div(h, h + l, 0.0)


def _pow2(k, dtype):
    """2.0 ** k in ``dtype`` for an integer array k in the normal exponent range (exact bits)."""
    info = jnp.finfo(dtype)
    return jax.lax.bitcast_convert_type((k + (info.maxexp - 1)) << info.nmant, dtype)


def unit_scale(s):
    """s times the power of two that brings max|s| into [1/2, 1) (an all-zero s stays 0).

    Exact, so every rounding after it scales with it. The exponent is read from the bits of
    max|s| (one float reduction, then integer arithmetic on one scalar: XLA would recompute a
    frexp chain in every fusion that reads the scale, and it runs an integer max over every
    entry's exponent bits 1.4x slower in LHF's kernel); a subnormal max|s| is brought to
    [2^-p, 1) with p the mantissa bits. Two factors, because 2^e alone can overflow.
    """
    info = jnp.finfo(s.dtype)
    bits = jnp.int64 if info.bits == 64 else jnp.int32
    top = jnp.max(jnp.abs(jax.lax.stop_gradient(s)))
    field = (jax.lax.bitcast_convert_type(top, bits) >> info.nmant) & (2 * info.maxexp - 1)
    e = (info.maxexp - 2) - field  # max|s| in [2^(E - bias), 2^(E - bias + 1))
    h = e >> 1
    return s * _pow2(h, s.dtype) * _pow2(e - h, s.dtype)
