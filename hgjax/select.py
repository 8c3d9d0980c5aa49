"""Selection of the kept points from per-point scores.

Deterministic top-k with stable ties, and weighted sampling without replacement driven by an
explicit ``jax.random`` key, both on the host (``np.argpartition`` is an order of magnitude
faster than ``jax.lax.top_k`` for large k on CPU), returning int64 indices ordered from the
highest to the lowest keep priority; and the differentiable soft top-k :func:`soft_select`,
pure JAX, returning per-point keep weights.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate
from hgjax.scores import _common

__all__ = ["soft_select", "top_k", "weighted_sample"]

BISECTION_STEPS = 64


def top_k(scores, m: int, *, largest: bool = True) -> np.ndarray:
    """Indices of the m best scores, best first; equal scores keep index order (stable).

    Args:
      scores: (N,) float scores without NaN (+-inf allowed).
      m: number to keep, 1 <= m <= N.
      largest: keep the largest scores (True) or the smallest (False).

    Returns:
      (m,) int64 unique indices, sorted by priority (then by index among equal scores).

    Raises:
      ValueError, TypeError: bad scores or m.

    Examples:
      >>> import numpy as np
      >>> from hgjax.select import top_k
      >>> top_k(np.array([0.5, 2.0, 2.0, 1.0]), 2).tolist()
      [1, 2]
      >>> top_k(np.array([0.5, 2.0, 2.0, 1.0]), 2, largest=False).tolist()
      [0, 3]
    """
    s = _validate.check_scores(scores)
    n = s.shape[0]
    m = _validate.check_int(m, "m", minimum=1)
    if m > n:
        raise ValueError(f"m must be <= N = {n}; got {m}")
    key = -s if largest else s
    kth = np.partition(key, m - 1)[m - 1]
    better = np.flatnonzero(key < kth)
    ties = np.flatnonzero(key == kth)[: m - better.size]
    chosen = np.concatenate([better, ties])
    return chosen[np.lexsort((chosen, key[chosen]))].astype(np.int64)


def weighted_sample(key: jax.Array, weights, m: int) -> np.ndarray:
    """Draw m distinct indices with probability proportional to ``weights``, in draw order.

    Sampling without replacement by the Gumbel-top-k trick: the order of log w + Gumbel
    noise has exactly the law of sequential draws without replacement. Points with zero
    weight are drawn only after every positive-weight point.

    Args:
      key: a ``jax.random`` key (``jax.random.key(seed)``); the same key gives the same draw.
      weights: (N,) non-negative finite weights, not all zero.
      m: number of draws, 1 <= m <= N.

    Returns:
      (m,) int64 unique indices in draw order.

    Raises:
      ValueError, TypeError: bad weights, m or key.

    Examples:
      >>> import jax, numpy as np
      >>> from hgjax.select import weighted_sample
      >>> idx = weighted_sample(jax.random.key(0), np.array([0.0, 1.0, 1.0]), 2)
      >>> sorted(idx.tolist())
      [1, 2]
    """
    w = _validate.check_scores(weights, "weights")
    if (w < 0).any() or not np.isfinite(w).all() or not (w > 0).any():
        raise ValueError("weights must be finite, >= 0 and not all zero")
    if key is None:
        raise ValueError("key must be a jax.random key, e.g. jax.random.key(0); got None")
    g = np.asarray(jax.random.gumbel(key, w.shape, dtype=np.float64 if jax.config.jax_enable_x64 else np.float32),
                   dtype=np.float64)
    with np.errstate(divide="ignore"):
        perturbed = np.where(w > 0, np.log(w.astype(np.float64)) + g, -np.inf)
    # Zero-weight points come last, in index order (stable).
    return top_k(perturbed, m, largest=True)


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
      ValueError: if ``scores`` is not one-dimensional, or a concrete ``ratio`` or
        ``temperature`` is out of range (NaN, 0 or below).

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> w = hgjax.soft_select(jnp.array([0.1, 0.9, 0.5, 0.7]), 0.5, temperature=1e-3)
      >>> [round(float(x), 3) for x in w]
      [0.0, 1.0, 0.0, 1.0]
    """
    scores = jnp.asarray(scores)
    if scores.ndim != 1:
        raise ValueError(f"scores must have shape (N,); got {scores.shape}")
    ratio = _validate.check_traced_ratio(ratio)
    temperature = _validate.check_traced_positive(temperature, "temperature")
    if not largest:
        scores = -scores
    temperature = jnp.asarray(temperature, scores.dtype)
    target = jnp.asarray(ratio, scores.dtype) * scores.shape[0]
    theta = _threshold(scores, temperature, target)
    return jax.nn.sigmoid((scores - theta) / temperature)
