"""Selection of the kept points from per-point scores.

Deterministic top-k with stable ties, and weighted sampling without replacement driven by an
explicit ``jax.random`` key, both on the host (``np.argpartition`` is an order of magnitude
faster than ``jax.lax.top_k`` for large k on CPU), returning int64 indices ordered from the
highest to the lowest keep priority; and the differentiable soft top-k :func:`soft_select`,
pure JAX, returning per-point keep weights.
"""

from __future__ import annotations

import dataclasses
import fractions
import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _validate
from hgjax.neighbours import spatial
from hgjax.scores import _common

__all__ = ["ExactSum", "key_value", "keyed_top", "kth_pair", "order_keys", "point_bits", "soft_select", "top_k", "top_pairs", "weighted_sample"]

BISECTION_STEPS = 64
DRAW_CHUNK = 1 << 16  # ids per compiled draw: a new cloud size compiles nothing
DRAW_PART = 1 << 20  # ids per part of :func:`keyed_top`
EXACT_PART = 1 << 25  # values per bincount of :meth:`ExactSum.of` (its sums stay exact)
RADIX_BITS = 16  # bits of the key resolved per histogram round of :func:`kth_pair`


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
      >>> from hgjax.engine.select import top_k
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
    return chosen[spatial.lex_order(key[chosen], chosen)].astype(np.int64)


def order_keys(scores, *, largest: bool) -> np.ndarray:
    """Order-preserving uint64 keys of float scores: the smaller the key, the higher the priority.

    The float64 bit pattern is mapped to an unsigned integer in the order of the values
    (-0.0 and 0.0 are the same key; -inf and +inf are ordinary values), then reversed when
    the largest scores are kept. Integer keys sum and compare exactly, so a global ranking
    built from per-tile histograms of them never depends on how the cloud was cut.

    Args:
      scores: (N,) float scores without NaN.
      largest: the largest scores have the highest priority.

    Returns:
      (N,) uint64 keys.

    Examples:
      >>> import numpy as np
      >>> from hgjax.engine.select import order_keys
      >>> np.argsort(order_keys(np.array([0.5, -1.0, 2.0]), largest=True)).tolist()
      [2, 0, 1]
    """
    ascending = ascending_bits(np.asarray(scores, dtype=np.float64))
    return np.invert(ascending, out=ascending) if largest else ascending


def ascending_bits(values: np.ndarray) -> np.ndarray:
    """Unsigned integers of float32 (uint32) or float64 (uint64) ``values``, in the values' order.

    The sign bit set for the non-negative values, every bit flipped for the negative ones;
    -0.0 is 0.0 first, so equal values get equal integers.
    """
    width = values.dtype.itemsize * 8
    uint = np.dtype(f"uint{width}").type
    bits = (values + values.dtype.type(0)).view(uint)
    # xor with all ones (negative: every bit flipped) or with the sign bit alone (set it)
    return bits ^ (np.negative(bits >> uint(width - 1)) | uint(1 << (width - 1)))


def part_keys(part, largest: bool, column: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(keys, gids) of a tile's (gids, scores) part: its scores, or one column of them, as :func:`order_keys`."""
    gids, scores = part
    return order_keys(scores if column is None else scores[:, column], largest=largest), gids


@dataclasses.dataclass(frozen=True)
class ExactSum:
    """The exact sum of float64 values: integer mantissa sums per binary exponent.

    Adding two ExactSums is exact and associative, so a sum reduced over tiles in any
    grouping or order gives the same bits; :meth:`value` rounds once, correctly.

    Examples:
      >>> from hgjax.engine.select import ExactSum
      >>> (ExactSum.of([1e20, 1.0]) + ExactSum.of([-1e20])).value()
      1.0
    """

    terms: tuple = ()  # sorted (exponent, integer) pairs: the sum is sum(t * 2**(e - 53))

    @classmethod
    def of(cls, values, exponents=None) -> "ExactSum":
        """The exact sum of finite ``values``, each times 2^``exponents`` (integers of the same
        shape, default 0): a sum of squares q^2 = (m^2) 2^(2 e) of q = m 2^e beyond float64's range."""
        v = np.asarray(values, dtype=np.float64).ravel()
        extra = None if exponents is None else np.asarray(exponents, dtype=np.int64).ravel()
        total = cls()
        for start in range(0, v.size, EXACT_PART):
            mant, exp = np.frexp(v[start:start + EXACT_PART])  # v = mant 2^exp, mant 2^53 an integer
            if extra is not None:
                exp = exp + extra[start:start + EXACT_PART]
            high = np.floor(mant * 2.0**27)  # mant 2^53 = high 2^26 + low, 0 <= low < 2^26, all exact
            low = mant * 2.0**53 - high * 2.0**26
            at = exp - exp.min()  # exponents span at most about 2100 values: a bincount, not a sort
            # float64 bincount sums of |high| <= 2^27 and low < 2^26 over <= 2^25 terms stay exact
            sums_high, sums_low = np.bincount(at, weights=high), np.bincount(at, weights=low)
            present = np.flatnonzero((sums_high != 0) | (sums_low != 0))
            total = total + cls(tuple((int(e), (int(a) << 26) + int(b)) for e, a, b in
                                      zip(present + exp.min(), sums_high[present], sums_low[present])))
        return total

    def __add__(self, other: "ExactSum") -> "ExactSum":
        out = dict(self.terms)
        for e, t in other.terms:
            out[e] = out.get(e, 0) + t
        return ExactSum(tuple(sorted(out.items())))

    def value(self, scale: int = 0) -> float:
        """The sum times 2^``scale`` rounded once to float64 (:meth:`exponent` picks a ``scale``
        that keeps a sum beyond float64's range representable)."""
        if not self.terms:
            return 0.0
        low = min(e for e, _ in self.terms)
        whole = sum(t << (e - low) for e, t in self.terms)
        return float(fractions.Fraction(whole) * fractions.Fraction(2) ** (low - 53 + scale))

    def exponent(self) -> int:
        """The binary exponent of the largest term (0 for an empty sum): the sum of values of
        one sign times 2^-exponent lies in [1/2, 2 x the number of values]."""
        return max((e - 53 + abs(t).bit_length() for e, t in self.terms), default=0)


def key_value(key: int, *, largest: bool) -> float:
    """The float64 score whose :func:`order_keys` key is ``key`` (the inverse map)."""
    ascending = np.uint64(key)
    if largest:
        ascending = ~ascending
    top = np.uint64(1 << 63)
    bits = ascending & ~top if ascending & top else ~ascending
    return float(np.array([bits], dtype=np.uint64).view(np.float64)[0])


def run_here(parts):
    """Run ``fn(part, *args)`` on every part, here, one part at a time: the default of :func:`kth_pair`'s ``run``."""
    return lambda fn, *args: (fn(part, *args) for part in parts)


def digit_histogram(part, level: int, prefix: int) -> np.ndarray:
    """(2^16,) counts of the level-th 16-bit digit of the part's keys whose higher digits are ``prefix``."""
    keys = part[0]
    if level:
        keys = keys[(keys >> np.uint64(64 - RADIX_BITS * level)) == np.uint64(prefix)]
    digit = (keys >> np.uint64(64 - RADIX_BITS * (level + 1))) & np.uint64((1 << RADIX_BITS) - 1)
    return np.bincount(digit.astype(np.int64), minlength=1 << RADIX_BITS)


def ids_with_key(part, key: int) -> np.ndarray:
    """The global ids of a part whose key is exactly ``key``."""
    return part[1][part[0] == np.uint64(key)]


def kept_pairs(part, key: int, gid: int):
    """(keys, gids) of a part at or before the pair (key, gid) in (key, gid) order."""
    keys, gids = part
    sel = (keys < np.uint64(key)) | ((keys == np.uint64(key)) & (gids <= gid))
    return keys[sel], gids[sel]


def kth_pair(parts, m: int, *, run=None) -> tuple[int, int]:
    """The m-th smallest (key, global id) pair over several parts, exactly, from summaries.

    Four rounds of per-part histograms of the next 16 bits of the keys (integer counts, whose
    sums do not depend on the order of the parts) find the m-th key, each round among the
    keys that share the digits found so far; then the ids holding exactly that key are
    gathered and the remaining rank is taken among them. Only histograms and the ids of one
    key leave a part, never its scores.

    Args:
      parts: sequence of (keys (n_i,) uint64, gids (n_i,) int64).
      m: rank, 1 <= m <= sum n_i.
      run: ``run(fn, *args)`` yields ``fn(part, *args)`` for each part, computed wherever
        the parts live (a Dask client's workers); default here. Each result is read once, as
        it comes: the histograms are summed one part at a time, never held all at once.

    Returns:
      (key, gid) of the m-th smallest pair in (key, gid) order.

    Examples:
      >>> import numpy as np
      >>> from hgjax.engine.select import kth_pair
      >>> parts = [(np.array([5, 1], np.uint64), np.array([0, 1])), (np.array([1, 9], np.uint64), np.array([2, 3]))]
      >>> kth_pair(parts, 2)
      (1, 2)
    """
    run = run or run_here(parts)
    prefix, need = 0, m
    for level in range(64 // RADIX_BITS):
        cum = np.cumsum(sum(run(digit_histogram, level, prefix)))
        digit = int(np.searchsorted(cum, need))
        need -= int(cum[digit - 1]) if digit else 0
        prefix = (prefix << RADIX_BITS) | digit
    ids = np.sort(np.concatenate(list(run(ids_with_key, prefix))))
    return prefix, int(ids[need - 1])


def top_pairs(parts, m: int, *, run=None, boundary: bool = False):
    """Global ids of the m smallest (key, global id) pairs over several parts, in that order.

    Exact: the threshold is :func:`kth_pair`'s, and each part contributes the ids at or
    before it, so the result is the same whatever the parts (tiles) are.

    Args:
      parts: sequence of (keys (n_i,) uint64, gids (n_i,) int64).
      m: number kept, 1 <= m <= sum n_i.
      run: as :func:`kth_pair`.
      boundary: also return the threshold, the m-th (key, global id) pair.

    Returns:
      (m,) int64 ids, highest priority (smallest key) first, equal keys by id; with
      ``boundary``, (ids, (key, gid)).

    Examples:
      >>> import numpy as np
      >>> from hgjax.engine.select import top_pairs
      >>> parts = [(np.array([5, 1], np.uint64), np.array([0, 1])), (np.array([1, 9], np.uint64), np.array([2, 3]))]
      >>> ids, last = top_pairs(parts, 3, boundary=True)
      >>> ids.tolist(), last
      ([1, 2, 0], (5, 0))
    """
    run = run or run_here(parts)
    last = kth_pair(parts, m, run=run)
    kept = list(run(kept_pairs, *last))
    keys = np.concatenate([k for k, _ in kept])
    gids = np.concatenate([g for _, g in kept]).astype(np.int64)
    ids = gids[spatial.lex_order(keys, gids)]
    return (ids, last) if boundary else ids


@functools.lru_cache(maxsize=None)
def _bits_kernel():
    def one(key, hi, lo):
        return jax.random.bits(jax.random.fold_in(jax.random.fold_in(key, hi), lo), (), jnp.uint32)

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0)))


def point_bits(key, gids) -> np.ndarray:
    """32 random bits per point from ``key`` and the point's global id alone.

    Each point's bits are ``jax.random.bits`` of ``fold_in(fold_in(key, gid >> 32), gid &
    0xFFFFFFFF)``, so a point draws the same number whatever the cloud's size, the tiling or
    the order in which points are visited. Ids are drawn in fixed chunks of 65,536 through
    one compiled kernel: a new cloud size compiles nothing.

    Args:
      key: a ``jax.random`` key.
      gids: (N,) non-negative integer global ids.

    Returns:
      (N,) uint32.

    Examples:
      >>> import jax, numpy as np
      >>> from hgjax.engine.select import point_bits
      >>> a = point_bits(jax.random.key(0), np.array([7, 3]))
      >>> b = point_bits(jax.random.key(0), np.array([3]))
      >>> bool(a[1] == b[0])
      True
    """
    gids = np.asarray(gids, dtype=np.int64)
    hi, lo = (gids >> 32).astype(np.uint32), (gids & 0xFFFFFFFF).astype(np.uint32)
    out = np.empty(gids.size, dtype=np.uint32)
    kernel = _bits_kernel()
    for start in range(0, gids.size, DRAW_CHUNK):
        stop = min(start + DRAW_CHUNK, gids.size)
        pad = DRAW_CHUNK - (stop - start)
        bits = kernel(key, np.pad(hi[start:stop], (0, pad)), np.pad(lo[start:stop], (0, pad)))
        out[start:stop] = np.asarray(bits)[: stop - start]
    return out


def keyed_top(key, n: int, m: int) -> np.ndarray:
    """The m of ids 0..n-1 with the largest :func:`point_bits` (ties by id), largest first.

    A uniformly random subset without replacement in draw order (the Gumbel-top-k order
    of equal weights); each id's draw depends on the key and the id only.
    """
    parts = []
    for start in range(0, n, DRAW_PART):
        gids = np.arange(start, min(start + DRAW_PART, n), dtype=np.int64)
        parts.append((np.uint64(0xFFFFFFFF) - point_bits(key, gids).astype(np.uint64), gids))
    return top_pairs(parts, m)


def point_gumbel(key, gids) -> np.ndarray:
    """(N,) float64 standard Gumbel noise per point from :func:`point_bits`: -log(-log(u)), u in (0, 1)."""
    u = (point_bits(key, gids).astype(np.float64) + 0.5) / 2.0**32
    return -np.log(-np.log(u))


def weighted_sample(key: jax.Array, weights, m: int) -> np.ndarray:
    """Draw m distinct indices with probability proportional to ``weights``, in draw order.

    Sampling without replacement by the Gumbel-top-k trick: the order of log w + Gumbel
    noise has exactly the law of sequential draws without replacement. Point i's noise
    comes from the key and i alone (:func:`point_gumbel`), so the draw of a point does not
    depend on N. Points with zero weight are drawn only after every positive-weight point.

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
      >>> from hgjax.engine.select import weighted_sample
      >>> idx = weighted_sample(jax.random.key(0), np.array([0.0, 1.0, 1.0]), 2)
      >>> sorted(idx.tolist())
      [1, 2]
    """
    w = _validate.check_scores(weights, "weights")
    if (w < 0).any() or not np.isfinite(w).all() or not (w > 0).any():
        raise ValueError("weights must be finite, >= 0 and not all zero")
    if key is None:
        raise ValueError("key must be a jax.random key, e.g. jax.random.key(0); got None")
    # Zero-weight points come last, in index order (stable).
    return top_k(gumbel_log_weights(key, w, np.arange(w.shape[0])), m, largest=True)


def gumbel_log_weights(key, weights: np.ndarray, gids: np.ndarray) -> np.ndarray:
    """(N,) float64 log w + Gumbel noise of each point's id (:func:`point_gumbel`); -inf where w = 0.

    The largest m of them are a weighted sample without replacement (Gumbel-top-k).
    """
    with np.errstate(divide="ignore"):
        return np.where(weights > 0, np.log(np.asarray(weights, dtype=np.float64)) + point_gumbel(key, gids), -np.inf)


@jax.custom_jvp
def _threshold(scores, valid, temperature, target):
    """theta with sum over ``valid`` of sigmoid((scores - theta) / temperature) = target, by bisection."""
    span = 40 * temperature

    def step(_, bounds):
        lo, hi = bounds
        mid = (lo + hi) / 2
        above = jnp.sum(jnp.where(valid, jax.nn.sigmoid((scores - mid) / temperature), 0)) > target
        return jnp.where(above, mid, lo), jnp.where(above, hi, mid)

    lo = jnp.min(jnp.where(valid, scores, jnp.inf)) - span
    hi = jnp.max(jnp.where(valid, scores, -jnp.inf)) + span
    lo, hi = jax.lax.fori_loop(0, BISECTION_STEPS, step, (lo, hi))
    return (lo + hi) / 2


@_threshold.defjvp
def _threshold_jvp(primals, tangents):
    scores, valid, temperature, target = primals
    ds, _, dt, dm = tangents
    theta = _threshold(scores, valid, temperature, target)
    z = (scores - theta) / temperature
    w = jax.nn.sigmoid(z)
    g = jnp.where(valid, w * (1 - w), 0)  # derivative of the sigmoid; 0 on absent rows
    # Implicit function theorem on F = sum sigmoid(z) - target = 0.
    num = jnp.sum(jnp.where(valid, g * ds, 0)) - jnp.sum(jnp.where(valid, g * z, 0)) * dt - temperature * dm
    return theta, _common.safe_div(num, jnp.sum(g), 0.0)


def soft_select(scores, ratio, *, temperature=0.05, largest: bool = True, valid=None):
    """Soft top-k: keep weights in [0, 1] that sum to ratio * N.

    w_i = sigmoid((s_i - theta) / temperature) (or of theta - s_i with ``largest=False``),
    theta found by 64 bisection steps so that sum(w) = ratio * N, and differentiated by the
    implicit function theorem: d theta = sum_i g_i ds_i / sum_i g_i with g the sigmoid
    slopes. As temperature -> 0 the weights tend to the hard top-k mask (ties share).
    With ``valid``, only the valid scores take part: N is their number, and the others
    (the padding rows of :func:`hgjax.stack_neighbourhoods`, ``valid=nb.row_mask``) weigh
    exactly 0 and get zero gradients.

    Args:
      scores: (N,) float scores without NaN (traced).
      ratio: fraction alpha in (0, 1] (traced: a new value does not recompile).
      temperature: > 0, in the units of the scores (traced).
      largest: keep the largest scores (True) or the smallest (static).
      valid: (N,) bool, the scores that take part (traced), or None for all of them.

    Returns:
      (N,) weights in [0, 1] in the dtype of ``scores``; their sum is ratio * N (N the
      number of valid scores) up to the bisection's precision (and < N when ratio = 1, each
      weight then being about 1); 0 where ``valid`` is False.

    Raises:
      ValueError: if ``scores`` is not one-dimensional, ``valid`` not a bool array of its
        shape, or a concrete ``ratio`` or ``temperature`` is out of range (NaN, 0 or below).
      jax.errors.JaxRuntimeError: a traced ``ratio`` out of (0, 1] where the program runs
        (jit, vmap, grad), with the same message.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> w = hgjax.soft_select(jnp.array([0.1, 0.9, 0.5, 0.7]), 0.5, temperature=1e-3)
      >>> [round(float(x), 3) for x in w]
      [0.0, 1.0, 0.0, 1.0]
      >>> w = hgjax.soft_select(jnp.array([0.1, 0.9, 0.5, 0.7]), 0.5, temperature=1e-3,
      ...                       valid=jnp.array([True, True, True, False]))
      >>> [round(float(x), 3) for x in w]
      [0.0, 1.0, 0.5, 0.0]
    """
    scores = jnp.asarray(scores)
    if scores.ndim != 1:
        raise ValueError(f"scores must have shape (N,); got {scores.shape}")
    ratio = _validate.check_traced_ratio(ratio)
    temperature = _validate.check_traced_positive(temperature, "temperature")
    if valid is None:
        valid, n = jnp.ones(scores.shape, bool), scores.shape[0]
    else:
        valid = jnp.asarray(valid)
        if valid.shape != scores.shape or valid.dtype != bool:
            raise ValueError(f"valid must be None or a bool array of the scores' shape {scores.shape};"
                             f" got {valid.dtype} {valid.shape}")
        n = jnp.sum(valid).astype(scores.dtype)
    return _weights(scores, ratio, temperature, valid, n, largest=largest)


@functools.partial(jax.jit, static_argnames="largest")  # eager callers: one program, not one per operation
def _weights(scores, ratio, temperature, valid, n, *, largest: bool):
    """:func:`soft_select`'s weights of validated inputs."""
    if not largest:
        scores = -scores
    temperature = jnp.asarray(temperature, scores.dtype)
    target = jnp.asarray(ratio, scores.dtype) * n
    theta = _threshold(scores, valid, temperature, target)
    return jnp.where(valid, jax.nn.sigmoid((scores - theta) / temperature), 0)
