"""Exact floating-point arithmetic in JAX, to reproduce the host's float64 results bit for bit.

The traced builders (:mod:`hgjax.neighbours.cells`, :mod:`hgjax.neighbours.balls`,
:mod:`hgjax.neighbours.radius_graph`) compute what the host computes with NumPy and SciPy's k-d tree.
Two things stand in the way, and this module answers both:

* XLA rewrites floating-point arithmetic. It does not reassociate additions, but its CPU backend
  contracts a product feeding an addition into one fused multiply-add (one rounding instead of
  two: measured, 21% of ``(dx*dx + dy*dy) + dz*dz`` differ from NumPy's and cKDTree's in
  float64), and divides by a constant or a broadcast scalar through its rounded reciprocal
  (measured: 9% of ``x / 17`` differ from NumPy's). Every product and quotient whose rounding
  matters goes through :func:`mul` or :func:`div`, whose select on a traced operand hides the
  operation from the rewrite (XLA folds a select on a constant); sums of float64 values follow
  NumPy's pairwise order (:func:`numpy_sum`: eight accumulators up to 128 terms, halves above),
  so that a mean is NumPy's to the last bit.
* Without x64 there is no float64 in JAX. A value is then carried as a normalised float32 pair
  (hi, lo): hi + lo is the value, |lo| <= ulp(hi) / 2, about 46 bits. The pair operations are
  built on the error-free transformations, which give a float32 operation's rounding error
  exactly: Knuth's TwoSum (:func:`two_sum`), Dekker's FastTwoSum and product (:func:`two_prod`,
  on Veltkamp's :func:`split`). Those need float32 operands (the split constant 4097 = 2^12 + 1
  is float32's) that neither overflow nor underflow.

Layer 0: this module imports nothing from hgjax.

Examples:
  >>> import jax.numpy as jnp
  >>> from hgjax import _exact
  >>> s, e = _exact.two_sum(jnp.float32(1), jnp.float32(2.0 ** -30))  # the part float32 rounds away
  >>> float(s), float(e) == 2.0 ** -30
  (1.0, True)
  >>> hi, lo = _exact.pair_const(0.1)  # float32 alone is 1.5e-9 off
  >>> abs(float(hi) - 0.1) > 1e-9, abs((float(hi) + float(lo)) - 0.1) < 1e-16
  (True, True)
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = ["div", "fast_two_sum", "mul", "numpy_sum", "pair_add", "pair_const", "pair_div", "pair_less", "pair_mul",
           "pair_sqrt", "pair_square", "pair_sum", "split", "two_prod", "two_sum"]


# ----------------------------------------------------------------------------- NumPy's float64 operations

def mul(a, b):
    """a * b rounded on its own, as NumPy and C compute it (never fused into a later addition); any dtype.

    The product sits behind a select on each operand (NaN gives NaN, as the product would): XLA folds
    the select of a compile-time constant (a :func:`pair_const` under ``jit``), so the other
    operand's still hides the product when one of them is constant.
    """
    return jnp.where(a == a, jnp.where(b == b, a * b, b), a)  # noqa: PLR0124 (selects XLA cannot see through)


def div(a, b):
    """a / b correctly rounded, as NumPy computes it (never a multiplication by b's reciprocal); any dtype."""
    return a / jnp.where(a == a, b, a)  # noqa: PLR0124 (a select XLA cannot see through)


def numpy_sum(x):
    """Sum over the last axis in NumPy's pairwise order (8 accumulators up to 128 terms, halves above); any length."""
    n = x.shape[-1]
    if n <= 128:
        if n < 8:
            out = jnp.zeros(x.shape[:-1], x.dtype)
            for i in range(n):
                out = out + x[..., i]
            return out
        r = [x[..., j] for j in range(8)]
        i = 8
        while i < n - n % 8:
            r = [r[j] + x[..., i + j] for j in range(8)]
            i += 8
        out = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        for j in range(i, n):
            out = out + x[..., j]
        return out
    half = n // 2
    half -= half % 8
    return numpy_sum(x[..., :half]) + numpy_sum(x[..., half:])


# ----------------------------------------------------------------------------- error-free transformations

def two_sum(a, b):
    """(s, e): s = a + b rounded and s + e == a + b exactly (Knuth's TwoSum); any finite a, b."""
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def fast_two_sum(a, b):
    """(s, e): s = a + b rounded and s + e == a + b exactly (Dekker's FastTwoSum); needs |a| >= |b| or a == 0."""
    s = a + b
    return s, b - (s - a)


def split(a):
    """(hi, lo): hi + lo == a, each of 12 significant bits at most (Veltkamp's split); float32 a, |a| < 2^115."""
    c = mul(a, 4097.0)
    hi = c - (c - a)
    return hi, a - hi


def two_prod(a, b):
    """(p, e): p = a * b rounded and p + e == a * b exactly (Dekker's product); float32, no overflow or underflow."""
    p = mul(a, b)
    ah, al = split(a)
    bh, bl = split(b)
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


# ----------------------------------------------------------------------------- float32 pairs

def pair_const(value):
    """A Python or NumPy float (read as float64) as a float32 pair (hi, lo); finite, within float32's range."""
    hi = np.float32(value)
    return jnp.float32(hi), jnp.float32(np.float64(value) - np.float64(hi))


def pair_add(ah, al, bh, bl):
    """(ah + al) + (bh + bl) as a normalised pair (accurate double-float addition); normalised pairs."""
    s, e = two_sum(ah, bh)
    t, f = two_sum(al, bl)
    s, e = fast_two_sum(s, e + t)
    return fast_two_sum(s, e + f)


def pair_mul(ah, al, bh, bl):
    """(ah + al)(bh + bl) as a normalised pair; normalised pairs."""
    p, e = two_prod(ah, bh)
    return fast_two_sum(p, e + (mul(ah, bl) + mul(al, bh)))


def pair_square(h, l):
    """(h + l)^2 as a normalised pair, for |l| <= ulp(h) / 2."""
    p, e = two_prod(h, h)
    m, f = two_prod(h, l)
    return fast_two_sum(p, e + (2 * m + (2 * f + mul(l, l))))


def pair_div(ah, al, bh, bl):
    """(ah + al) / (bh + bl) as a normalised pair (float32's quotient and one correction); normalised, bh != 0."""
    q = div(ah, bh)
    ph, pl = pair_mul(q, jnp.zeros_like(q), bh, bl)
    r = pair_add(ah, al, -ph, -pl)
    return fast_two_sum(q, div(r[0], bh))


def pair_sqrt(h, l):
    """sqrt(h + l) as a normalised pair (one Newton step on float32's root); a normalised pair, h >= 0 or inf
    (a negative h gives 0, inf gives (inf, 0))."""
    s = jnp.sqrt(jnp.maximum(h, 0))
    p, e = two_prod(s, s)
    pos = s > 0
    r = div(((h - p) - e) + l, jnp.where(pos, 2 * s, 1))
    hi, lo = fast_two_sum(s, jnp.where(pos & jnp.isfinite(s), r, 0))
    return jnp.where(jnp.isfinite(s), hi, s), jnp.where(jnp.isfinite(s), lo, 0)


def pair_sum(hi, lo):
    """Sum over the last axis of normalised pairs (hi, lo) by halving (the order is immaterial at their precision)."""
    while hi.shape[-1] > 1:
        if hi.shape[-1] % 2:
            pad = [(0, 0)] * (hi.ndim - 1) + [(0, 1)]
            hi, lo = jnp.pad(hi, pad), jnp.pad(lo, pad)
        hi, lo = pair_add(hi[..., 0::2], lo[..., 0::2], hi[..., 1::2], lo[..., 1::2])
    return hi[..., 0], lo[..., 0]


def pair_less(ah, al, bh, bl):
    """Whether (ah, al) < (bh, bl): the leading parts, then the trailing ones; normalised pairs."""
    return (ah < bh) | ((ah == bh) & (al < bl))
