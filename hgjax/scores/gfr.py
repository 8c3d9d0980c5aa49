"""Graph filtering resampling (GFR) baseline: Chen et al., "Fast resampling of
three-dimensional point clouds via graphs", IEEE TSP 66(3), 2018.

The score is the response of a graph high-pass filter, score_i = ||(L P)_i||_2 with the
graph Laplacian L = D - W (Chen et al., Sec. IV). The graph is built once on the host
(:func:`hgjax.neighbours.radius_graph.graph`); the score on a fixed graph (:func:`high_pass`) is pure JAX and smooth in
the points. Two graphs:

* ``"reference"``, the rules of the authors' C++ implementation (REFERENCE.md, "GFR
  baseline"), with squared distances q_ij = ||p_i - p_j||^2 in float32:

  1. A point whose nearest other point is at q <= 1e-10 (an exact or near duplicate) is
     skipped. minNN, maxNN = min and max over the other points of the distance sqrt(q) to
     their nearest other point; if minNN == maxNN then maxNN = 5 minNN.
     r = min(10 minNN, 2 maxNN), compared with SQUARED distances, so the Euclidean radius
     sqrt(r) depends on the units of the cloud.
  2. Each unordered pair with 0 < q < r is stored once, in the row of its smaller index;
     a row keeps the ``max_nn`` = 100 partners of smallest q (equal q: smaller index first).

* ``"invariant"`` (default), scale-invariant: radius R = ``radius_factor`` x resolution,
  Euclidean, with the resolution the median over points of the distance to the nearest
  DISTINCT point (exact duplicates and far outliers do not move it). Each distinct location
  links to its at most ``max_nn`` nearest other locations with 0 < ||u_a - u_b|| < R
  (equal distances: smaller first index first); a pair is stored once, between the first
  points of its two locations, in the row of the smaller index, when either end links to
  the other. Scaling, translating or reordering the cloud leaves the graph's shape
  unchanged, so the scores scale with the cloud and the ranking does not move.

Exact duplicates (invariant graph): every copy of location a is linked to every copy of a
linked location b, so a stored pair stands for c_a c_b point pairs (c the number of points
at a location) and is counted that often in v below; a location's first point sums its
partners' flows weighted by their counts, and every copy scores as its first point
(``Neighbourhoods.first``). Duplicating the whole cloud doubles every score. The work is
that of the distinct locations, however many copies there are.

Weights, both graphs: w_ij = exp(-q_ij^2 / (2 v)), v the population variance of q over the
stored pairs; W = W0 + W0^T (W0 the stored pairs), and
(L P)_i = sum_j W_ij c_j (p_i - p_j) = (row sum of W0) + (W0^T as a scatter-add onto the
partners), c = 1 without duplicates. No N x N matrix is formed.

Degenerate clouds: with no stored pair (N = 1, all points equal) or v = 0 (every stored pair
the same length) every weight is exp(-inf) = 0, the limit of the formula, and every score 0.
"""

from __future__ import annotations

import concurrent.futures
import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _method, _stream, _validate
from hgjax.engine import select
from hgjax.neighbours import backend, radius_graph, spatial, traced_graph
from hgjax.scores import _common
from hgjax.scores.eigen import DEFAULT_K

__all__ = ["high_pass", "neighbourhoods", "score", "soft_score"]

MODES = ("random", "top")  # selection: weighted sampling (needs a key) or the top scores
SCORE_ROWS = 1 << 16  # rows per host block of the streamed score (bounds its (R, K, 3) flows)


def _edge_weight(q, two_var):
    """exp(-q^2 / (2 v)), and 0 (the limit) where 2 v == 0."""
    return jnp.exp(-_common.safe_div(q * q, two_var, jnp.inf))


def inclusion(scores, total: float, n: int) -> np.ndarray:
    """(N,) float64 sampling weights pi = 0.8 score / total + 0.2 / n of GFR's default selection
    (Chen et al. 2018), uniform 1 / n when the scores sum to 0; ``total`` the exact sum of all n scores."""
    values = np.asarray(scores, dtype=np.float64)
    return 0.8 * values / total + 0.2 / n if total > 0 else np.full(values.shape[0], 1.0 / n)


def high_pass(points, idx, *, first=None, weights_dtype=None, chunk_size: int | None = None,
              progress: bool = False) -> jax.Array:
    """GFR score ||(L P)_i||_2 on a fixed graph: pure JAX under jit, vmap and grad, streamed when eager.

    q_ij = ||p_i - p_j||^2 and w_ij = exp(-q_ij^2 / (2 v)) over the stored pairs (idx < N),
    each pair counted c_i c_j times, evaluated as exp(-z^2 / (2 var(z))) with z = q / mean(q),
    the same value free of the cloud's units (so gradients stay finite at any scale). Then
    with W = W0 + W0^T, (L P)_i = sum_j W0_ij c_j (p_i - p_j) - sum_j W0_ji c_j (p_j - p_i):
    no N x N matrix is formed. Every point takes the score of ``first[i]``.

    The per-row kernels (q, then the weighted flows W0_ij (p_i - p_j)) are the same JAX
    program per chunk of rows either way (:mod:`hgjax._stream`); the reductions differ:

    * traced (inside jit, vmap or grad): v and mean(q) summed in JAX in the wider of the
      points' and the weights' dtype, the flows summed as a row sum plus a scatter-add;
    * concrete: fixed-size chunks streamed through the kernels, so a new cloud size does not
      recompile; v and mean(q) are exact sums (:func:`pair_sums`) and each point sums its
      partners' flows over the symmetric graph in float64, in global-id order, the sums a
      tiled run computes (:func:`graph_norms`).

    The two agree to rounding (1e-12 relative in float64).

    Args:
      points: (N, 3) float array.
      idx: (N, K) integer partners of each row's stored pairs, padded with N (as
        :func:`hgjax.neighbours.radius_graph.graph` returns them).
      first: (N,) integer index of the first point at each point's location (as
        :func:`hgjax.neighbours.radius_graph.graph` returns it); c_i = the number of points with first == i. None: every
        point is its own location (c = 1).
      weights_dtype: dtype of q and w (default: the points' dtype); float32 for the
        reference variant, as the authors' code keeps them.
      chunk_size: rows per streamed chunk (concrete calls only); never changes results.
      progress: progress bar on stderr for long concrete calls.

    Returns:
      (N,) scores >= 0 in the points' dtype; 0 for every point when no pair is stored or
      v = 0.

    Raises:
      TypeError, ValueError: wrong shapes or dtypes (checked before any computation).

    Examples:
      >>> import jax.numpy as jnp
      >>> from hgjax.scores.gfr import high_pass
      >>> pts = jnp.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0]])
      >>> idx = jnp.array([[1, 2], [2, 3], [3, 3]])
      >>> [round(s, 4) for s in high_pass(pts, idx).tolist()]
      [1.0279, 0.0042, 1.0321]
    """
    _validate.check_graph(points, idx, first, weights_dtype)
    if _stream.is_traced(points, idx, first):
        return _pure_high_pass(points, idx, first, weights_dtype)
    points, idx = np.asarray(points), np.asarray(idx)
    first = None if first is None else np.asarray(first)
    return jax.device_put(_streamed_high_pass(points, idx, first, weights_dtype, chunk_size, progress))


def _pure_high_pass(points, idx, first, weights_dtype) -> jax.Array:
    """:func:`high_pass` as one pure JAX program (its traced path)."""
    points, idx = jnp.asarray(points), jnp.asarray(idx)
    n = points.shape[0]
    wdtype = points.dtype if weights_dtype is None else jnp.dtype(weights_dtype)
    valid = idx < n
    # q from the points cast to wdtype first, as the authors' float32 code computes it.
    q = _stream.pure_map(_sq_length, points.astype(wdtype), idx)
    acc = jnp.promote_types(points.dtype, wdtype)
    own, partner = _multiplicities(first, idx, n, acc)
    pair = jnp.where(valid, own[:, None] * partner, 0)  # point pairs each stored pair stands for
    count = jnp.sum(pair)
    mean_q = _common.safe_div(jnp.sum(pair * q.astype(acc)), count, 0.0)
    z = _common.safe_div(q.astype(acc), mean_q, 0.0)
    mean_z = _common.safe_div(jnp.sum(pair * z), count, 0.0)
    two_var = 2 * _common.safe_div(jnp.sum(pair * (z - mean_z) ** 2), count, 0.0)
    c = _stream.pure_map(_flow_kernel(np.dtype(wdtype)), points, idx, row_args=(q,), args=(mean_q, two_var))
    lp = (jnp.sum(partner.astype(c.dtype)[..., None] * c, axis=1)
          - jnp.zeros_like(points).at[idx].add(own.astype(c.dtype)[:, None, None] * c, mode="drop"))
    score = _common.safe_sqrt(jnp.sum(lp * lp, axis=1))
    return score if first is None else score[jnp.asarray(first)]


def _streamed_high_pass(points: np.ndarray, idx: np.ndarray, first: np.ndarray | None, weights_dtype, chunk_size,
                        progress) -> np.ndarray:
    """:func:`high_pass` of concrete arrays, streamed (its concrete path), in the points' dtype."""
    n = points.shape[0]
    wdtype = np.dtype(points.dtype if weights_dtype is None else weights_dtype)
    valid = idx < n
    sym = symmetric(np.repeat(np.arange(n), valid.sum(axis=1)), idx[valid], n, np.arange(n))
    own = np.arange(n)
    counts_ext = None if first is None else np.append(np.bincount(first, minlength=n).astype(np.float64), 0.0)
    stream = {"chunk_size": chunk_size, "progress": progress}
    tie_ext = np.append(own, n)
    # q from the points cast to wdtype first, as the authors' float32 code computes it.
    low = points.astype(wdtype)
    ext_q = _stream.device_points(low, wdtype)  # every block's kernels read the points sent once
    ext = ext_q if wdtype == points.dtype else _stream.device_points(points, points.dtype)
    mean_q, two_var = moments(summed([pair_sums(low, own[b], sym[b], wdtype, counts_ext, tie_ext, ext=ext_q, **stream)
                                      for b in _blocks(n)]))
    q = [pair_lengths(low, own[b], sym[b], wdtype, ext=ext_q, **stream) if wdtype != points.dtype else None
         for b in _blocks(n)]
    lp = np.concatenate([laplacian_norms(points, own[b], sym[b], q_b, counts_ext, tie_ext, mean_q, two_var,
                                         points.dtype, wdtype, ext=ext, **stream) for q_b, b in zip(q, _blocks(n))]
                        or [np.zeros(0)])
    return (lp if first is None else lp[first]).astype(points.dtype)


def _multiplicities(first, idx, n, dtype):
    """(c_i (N,), c_j (N, K)): the points at each row's location and at each partner's (0 for
    padding); ones without ``first``."""
    own = jnp.ones(n, dtype) if first is None else jnp.zeros(n, dtype).at[jnp.asarray(first)].add(1)
    return own, jnp.concatenate([own, jnp.zeros(1, dtype)])[idx]


def _sq_length(offsets, valid):
    """(K,) squared lengths q of one point's stored pairs (0 for padding)."""
    return jnp.where(valid, offsets[:, 0] * offsets[:, 0] + offsets[:, 1] * offsets[:, 1]
                     + offsets[:, 2] * offsets[:, 2], 0)


def _flow(offsets, valid, q, mean_q, two_var, wdtype):
    """(K, 3) W0_ij (p_i - p_j) of one point's stored pairs (K,) of squared length q (in wdtype).

    w = exp(-z^2 / (2 var z)) with z = q / mean q.
    """
    z = _common.safe_div(q.astype(mean_q.dtype), mean_q, 0.0)
    w = jnp.where(valid, _edge_weight(z, two_var).astype(wdtype), 0).astype(offsets.dtype)
    return -w[:, None] * offsets


@functools.lru_cache(maxsize=None)
def _flow_kernel(wdtype):
    return functools.partial(_flow, wdtype=wdtype)


def _smallest_nonzero(size):
    """The smallest non-zero value of each column of ``size`` (K, 3) >= 0: (3,), inf where a column has none."""
    return jnp.min(jnp.where(size > 0, size, jnp.inf), axis=0)


def _summary(flow):
    """One row's flows (K, 3) as (flows (3, K), smallest non-zero |flow| (3,), inf if none; largest |flow| (3,))."""
    size = jnp.abs(flow)
    return flow.T, _smallest_nonzero(size), jnp.max(size, axis=0)


@functools.lru_cache(maxsize=None)
def _summed_flow_kernel(wdtype):
    return lambda offsets, valid, q, mean_q, two_var: _summary(_flow(offsets, valid, q, mean_q, two_var, wdtype))


def _own_summed_flow(offsets, valid, mean_q, two_var):
    """:func:`_flow` with q = :func:`_sq_length` of the same offsets (q and w in the points' dtype),
    summarised by :func:`_summary`."""
    return _summary(_flow(offsets, valid, _sq_length(offsets, valid), mean_q, two_var, offsets.dtype))


def _weights_dtype(variant: str):
    return np.dtype(np.float32) if variant == "reference" else None


def neighbourhoods(points, *, variant: str = "invariant", radius_factor: float | None = None,
                   max_nn: int = radius_graph.MAX_NN, capacity: int | None = None, search: str = "host",
                   cell_slots: int | None = None, cell_edge=None) -> spatial.Neighbourhoods:
    """The GFR graph as :class:`hgjax.Neighbourhoods`, :func:`hgjax.neighbours.radius_graph.graph` (host; jittable: ``search="jax"``).

    Args:
      points: (N, 3) float32 or float64; never modified.
      variant, radius_factor, max_nn: as :func:`hgjax.neighbours.radius_graph.graph`.
      capacity: fixed number of columns K (at least the fullest row); default the fullest
        row rounded up to a power of two. Static with ``search="jax"`` under ``jit`` (default
        there ``bucket(2 max_nn)``; a wider row stops the program, naming the capacity it needs).
      search: ``"host"`` (SciPy's k-d tree; not jittable) or ``"jax"`` (the traced search:
        jit, vmap, grad; the same graph, :mod:`hgjax.neighbours.radius_graph`).
      cell_slots, cell_edge: the traced search's candidates read per step (static) and first
        cell edge (traced, or None from the data): speed settings, never limits.

    Returns:
      Neighbourhoods whose row i lists the partners j > i of its stored pairs, padded with N,
      and ``first`` (see :func:`hgjax.neighbours.radius_graph.graph`); points in a local frame and the working dtype.

    Raises:
      TypeError, ValueError: invalid arguments, or a fixed capacity too small.

    Examples:
      >>> import numpy as np
      >>> from hgjax.scores import gfr
      >>> nb = gfr.neighbourhoods(np.random.default_rng(0).random((100, 3)))
      >>> nb.idx.shape[0], nb.scale is None
      (100, True)
    """
    if _validate.check_choice(search, "search", backend.SEARCHES) == "jax":
        return traced_graph.build(points, variant=variant, radius_factor=radius_factor, max_nn=max_nn,
                                  capacity=capacity, cell_slots=cell_slots, cell_edge=cell_edge)
    pts = _validate.check_points(points)
    local = spatial.local_frame(pts)[0]
    if capacity is not None:
        capacity = _validate.check_int(capacity, "capacity", minimum=1)

    def columns(width: int) -> int:
        if capacity is None:
            return spatial.bucket(width)
        _validate.check_capacity(capacity, width, "GFR row")
        return capacity

    idx, first = radius_graph.graph(local, variant=variant, radius_factor=radius_factor, max_nn=max_nn, columns=columns)
    dtype = spatial.working_dtype(pts.dtype, extent=spatial.frame_extent(local),
                                  spacing=lambda: spatial.pair_spacing(local, idx, first))  # warns where the cast loses detail
    return spatial.Neighbourhoods(local.astype(dtype), idx, first=first,
                                  params=spatial.record({"variant": variant, "radius_factor": radius_factor,
                                                         "max_nn": max_nn}))


def score(nb, *, variant: str = "invariant", chunk_size: int | None = None, progress: bool = False):
    """GFR score ||(L P)_i||_2 (Chen et al. 2018) of every point on its graph; higher is sharper.

    :func:`high_pass` of the graph: pure JAX when traced (inside jit, vmap or grad), two
    streamed passes of fixed-size chunks when eager (the squared pair lengths, then the
    weighted pair flows). The two paths agree to rounding (1e-12 relative in float64).

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      variant: ``"reference"`` keeps q and w in float32 as the authors' code; static.
      chunk_size: rows per streamed chunk on eager calls; never changes results.
      progress: progress bar on stderr for long eager runs.

    Returns:
      (N,) scores >= 0 in the dtype of ``nb.points`` (0 where no pair is stored).

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((200, 3)), "gfr")
      >>> s = hgjax.scores.gfr.score(nb)
      >>> s.shape, bool((s > 0).all())
      ((200,), True)
    """
    variant = _validate.check_variant(variant)
    return high_pass(nb.points, nb.idx, first=nb.first, weights_dtype=_weights_dtype(variant), chunk_size=chunk_size,
                     progress=progress)


def symmetric(a: np.ndarray, b: np.ndarray, n: int, tie: np.ndarray) -> np.ndarray:
    """(n, K) int32 partners of every node over the undirected pairs (a, b), by ``tie`` of the partner.

    Both directions of every pair, each row ordered by the partners' ``tie`` (their global
    ids), padded with n: the order in which :func:`laplacian_norms` sums a row, so a point's
    score does not depend on how the graph was cut or padded.
    """
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)  # packed keys reach n^2
    by_tie = np.argsort(tie, kind="stable")
    rank = np.empty(n, dtype=np.int64)
    rank[by_tie] = np.arange(n)
    key = np.sort(np.concatenate([a * n + rank[b], b * n + rank[a]]))  # one sort of packed (node, rank) keys
    src, dst = key // n, by_tie[key % n]
    counts = np.bincount(src, minlength=n)
    out = np.full((n, max(1, int(counts.max(initial=0)))), n, dtype=np.int32)
    out[src, np.arange(src.size) - (np.cumsum(counts) - counts)[src]] = dst
    return out


def _blocks(n: int):
    """Slices of at most SCORE_ROWS rows (bounds the host memory of (R, K, 3) flows)."""
    return [slice(s, min(s + SCORE_ROWS, n)) for s in range(0, n, SCORE_ROWS)]


def pair_lengths(points, own, nbr, wdtype, *, ext=None, chunk_size=None, progress=False) -> np.ndarray:
    """(R, K) squared pair lengths q in ``wdtype`` of the rows ``own`` (R,) with partners ``nbr`` (R, K).

    ``ext``: the points' :func:`hgjax._stream.device_points` in ``wdtype``, when the caller made them once.
    """
    return _stream.map_rows(_sq_length, points, own, nbr, dtype=wdtype, ext=ext, chunk_size=chunk_size,
                            progress=progress)


def pair_sums(points, own, nbr, wdtype, counts_ext, tie_ext, *, ext=None, chunk_size=None, progress=False) -> tuple:
    """Exact sums of c_i c_j, c_i c_j q and c_i c_j q^2 over the stored pairs (i, j) of the rows ``own``.

    ``nbr`` (R, K) holds the partners of the rows ``own`` (R,), padded with n = len(tie_ext) - 1;
    q = ||p_i - p_j||^2 in ``wdtype`` as :func:`pair_lengths` computes it (``ext`` as there);
    ``counts_ext`` (n + 1,) the c of each row and 0 for the padding, or None for one point per
    row. Sums of chunks of rows add up exactly.

    float32 q: every (row, partner) entry counts, so over a graph whose rows are each summed
    once every undirected pair counts twice, which leaves the ratios of :func:`moments`
    exactly as they are. Each row's terms (:func:`_moment_terms`, exact in float64) are
    summed on the device; where every order of adding them may not give their exact sum
    (:func:`_exact_moments`), the row's terms come back and are summed on the host.
    float64 q: the terms on the host, each undirected pair once, from its end with the
    smaller ``tie_ext``.
    """
    stream = {"ext": ext, "chunk_size": chunk_size, "progress": progress}
    c = () if counts_ext is None else (counts_ext[own][:, None] * counts_ext[nbr],)
    if np.dtype(wdtype) != np.float32:
        q = pair_lengths(points, own, nbr, wdtype, **stream)
        counted = (nbr < tie_ext.size - 1) & (tie_ext[nbr] > tie_ext[own][:, None])
        qq = q[counted].astype(np.float64)
        # q^2 = (m^2) 2^(2 e) of q = m 2^e: the bits of qq * qq (w qq * qq), without over- or underflow
        mant, exp = np.frexp(qq)
        if not c:  # c_i c_j = 1: the same sums
            return select.ExactSum.of([qq.size]), select.ExactSum.of(qq), select.ExactSum.of(mant * mant, 2 * exp)
        w = c[0][counted]
        return select.ExactSum.of(w), select.ExactSum.of(w * qq), select.ExactSum.of(w * mant * mant, 2 * exp)
    with jax.enable_x64(True):
        sums, qmin, qmax, cmax = _stream.map_rows(_moment_kernel(bool(c)), points, own, nbr, row_args=c,
                                                  dtype=wdtype, **stream)
        fast = _exact_moments(qmin, qmax, cmax, nbr.shape[1])
        slow = np.flatnonzero(~fast)
        terms = _stream.map_rows(_moment_terms, points, own[slow], nbr[slow], row_args=tuple(x[slow] for x in c),
                                 dtype=wdtype, **stream) if slow.size else np.zeros((0, 5, 1))
    count, sum_q, *sum_q2 = (np.concatenate([sums[fast, t], terms[:, t].ravel()]) for t in range(5))
    return select.ExactSum.of(count), select.ExactSum.of(sum_q), select.ExactSum.of(np.concatenate(sum_q2))


def _moment_terms(offsets, valid, *c):
    """(5, K) float64 terms of one row's pairs, each exact: 1, q, a^2, 2 a b and b^2, times
    c_i c_j (``c`` (K,), a row argument) when given; 0 for the padding.

    q (float32) = a + b, a the float32 q with the 12 low bits of its mantissa cleared, so that
    a^2, a b and b^2 hold at most 24 significant bits each and q^2 = a^2 + 2 a b + b^2.
    """
    q = _sq_length(offsets, valid)
    a = jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(q, jnp.uint32) & jnp.uint32(0xFFFFF000),
                                     jnp.float32)
    b = (q - a).astype(jnp.float64)
    a = a.astype(jnp.float64)
    terms = jnp.stack([valid.astype(jnp.float64), q.astype(jnp.float64), a * a, 2 * a * b, b * b])
    return terms * c[0][None, :] if c else terms


@functools.lru_cache(maxsize=None)
def _moment_kernel(counted: bool):
    """Per row: the sums of :func:`_moment_terms` (5,) in float64, the smallest non-zero q (inf
    if none), the largest q and the largest c_i c_j (1 unless ``counted``)."""
    def kernel(offsets, valid, *c):
        q = _sq_length(offsets, valid)
        largest_c = jnp.max(c[0]) if counted else jnp.ones((), jnp.float64)
        return (jnp.sum(_moment_terms(offsets, valid, *c), axis=1), jnp.min(jnp.where(q > 0, q, jnp.inf)),
                jnp.max(q), largest_c)

    return kernel


def _exact_moments(qmin: np.ndarray, qmax: np.ndarray, cmax: np.ndarray, width: int) -> np.ndarray:
    """(R,) whether every order of adding each row's ``width`` terms of :func:`_moment_terms`
    gives their exact float64 sum, from the row's smallest non-zero q ``qmin`` (float32), largest
    q ``qmax`` and largest c_i c_j ``cmax`` (R,) each.

    Every q of the row is a multiple of 2^e, the unit in the last place of ``qmin`` (a normal
    float32), so the five columns are multiples of 2^0, 2^e, 2^(2 e + 24), 2^(2 e + 12) and
    2^(2 e) and at most cmax times 1, qmax, qmax^2, 2^-10 qmax^2 and 2^-22 qmax^2 (|b| <
    2^-11 q): :func:`_adds_exactly` for each. Rows with a subnormal q are not.
    """
    normal = ~((qmin > 0) & (qmin < np.finfo(np.float32).tiny))
    e = _ulp_exponent(qmin)
    qmax = qmax.astype(np.float64)
    top = cmax * qmax * qmax
    bounds = [(np.zeros_like(e), cmax), (e, cmax * qmax), (2 * e + 24, top), (2 * e + 12, top / 1024),
              (2 * e, top / 2**22)]
    return normal & np.logical_and.reduce([_adds_exactly(unit, largest, width) for unit, largest in bounds])


def summed(parts) -> tuple:
    """The exact sums of :func:`pair_sums` over several chunks or tiles (three empty sums for none)."""
    return tuple(sum(column, select.ExactSum()) for column in zip(*parts)) or (select.ExactSum(),) * 3


def moments(sums) -> tuple[float, float]:
    """(mean q, 2 var z) of z = q / mean q from :func:`pair_sums` (summed over tiles); 0 without pairs.

    The sums are read scaled by powers of two that bring the sum of q near 1 (exact, so the
    bits are those of the unscaled formulas), so that the sum of q^2 and mean q^2 of a cloud
    whose q^2 over- or underflows float64 (x64, extents beyond about 1e±77) stay representable.
    """
    shift = -sums[1].exponent()
    count, sum_q, sum_q2 = sums[0].value(), sums[1].value(shift), sums[2].value(2 * shift)
    mean_q = sum_q / count if count else 0.0
    mean_z = sum_q / count / mean_q if mean_q > 0 else 0.0
    z_sq = sum_q2 / count / mean_q**2 if mean_q > 0 else 0.0
    return float(np.ldexp(mean_q, -shift)), 2 * max(z_sq - mean_z * mean_z, 0.0)


def laplacian_norms(points, own, nbr, q, counts_ext, tie_ext, mean_q, two_var, dtype, wdtype, *, ext=None,
                    chunk_size=None, progress=False) -> np.ndarray:
    """(R,) float64 ||(L P)_i|| of the rows ``own``: sum_j c_j w_ij (p_i - p_j) over ``nbr`` (R, K).

    ``q`` (R, K) the squared pair lengths of :func:`pair_lengths`, or None when ``wdtype`` is
    ``dtype``: the kernel then takes them from its own offsets (the same values).

    The flows come from one compiled kernel (on ``ext``, the points'
    :func:`hgjax._stream.device_points` when the caller made them once for several calls);
    each row is summed in float64 as if its partners were added one by one in the order
    of their ``tie_ext`` (global ids), so a point's score depends neither on how the graph
    was cut nor on the order of its columns (:func:`row_sums`). float32 flows are summed on
    the device (in float64, JAX's x64 mode on for the kernel only), where every order gives
    the exact sum; only the rows where it may not (:func:`row_sums`' bound) come back as
    flows to be added in order on the host. float64 flows are added one by one on the device
    (:func:`_ordered_sum_kernel`), each row's partners sorted by ``tie_ext`` first.
    ``counts_ext`` as :func:`pair_sums`.
    """
    acc = np.promote_types(dtype, wdtype)
    args = (np.asarray(mean_q, acc), np.asarray(two_var, acc))
    stream = {"args": args, "dtype": dtype, "ext": ext, "chunk_size": chunk_size, "progress": progress}
    q_arg = () if q is None else (q,)
    if np.dtype(acc) == np.float32:
        c = () if counts_ext is None else (counts_ext[nbr],)
        with jax.enable_x64(True):
            lp, smallest, largest = _stream.map_rows(_device_sum_kernel(q is None, counts_ext is not None), points, own,
                                                     nbr, row_args=q_arg + c, **stream)
        slow = np.flatnonzero(~_exact_in_any_order(smallest, largest, nbr.shape[1]))
        if slow.size:
            kernel = _own_summed_flow if q is None else _summed_flow_kernel(np.dtype(wdtype))
            flows = _stream.map_rows(kernel, points, own[slow], nbr[slow], row_args=tuple(a[slow] for a in q_arg),
                                     **stream)
            lp[slow] = row_sums(*flows, nbr[slow], counts_ext, tie_ext)
    else:
        # entries of a row tie only where they are equal (the same partner, or the padding n): any sort, one order
        order = np.argsort(tie_ext[nbr], axis=1)
        nbr = np.take_along_axis(nbr, order, axis=1)
        c = () if counts_ext is None else (counts_ext[nbr],)
        lp = _stream.map_rows(_ordered_sum_kernel(q is None, counts_ext is not None, np.dtype(wdtype)), points, own,
                              nbr, row_args=tuple(np.take_along_axis(a, order, axis=1) for a in q_arg) + c, **stream)
    return np.sqrt(lp[:, 0] * lp[:, 0] + lp[:, 1] * lp[:, 1] + lp[:, 2] * lp[:, 2])


def _exact_in_any_order(smallest: np.ndarray, largest: np.ndarray, width: int) -> np.ndarray:
    """(R,) whether every order of adding a row's ``width`` terms gives their exact float64 sum.

    Every term is an integer multiple of 2^e, e the exponent of the unit in the last place
    of the row's smallest non-zero flow ``smallest`` (R, 3) (c_j is an integer), so when
    ``width`` times the largest |term| ``largest`` (R, 3) is at most 2^(e + 53), every partial
    sum is a multiple of 2^e of magnitude at most 2^(e + 53): exactly a float64.
    """
    return _adds_exactly(_ulp_exponent(smallest), largest, width).all(axis=1)


def _ulp_exponent(smallest: np.ndarray) -> np.ndarray:
    """The exponent of the unit in the last place of each of ``smallest`` (in its float dtype; that
    of 1 where not finite)."""
    return np.frexp(np.where(np.isfinite(smallest), smallest, 1))[1] - (np.finfo(smallest.dtype).nmant + 1)


def _adds_exactly(unit: np.ndarray, largest: np.ndarray, width: int) -> np.ndarray:
    """Whether ``width`` integer multiples of 2^``unit``, each of magnitude at most ``largest``, add up
    exactly in float64 in every order: every partial sum is then a multiple of 2^unit of magnitude at
    most 2^(unit + 53)."""
    return largest * float(width) <= np.ldexp(1.0, unit + 53)


def _row_terms(offsets, valid, rest, q_own: bool, counted: bool, wdtype):
    """One row's flows f_ij (K, 3) (weights in ``wdtype``) and its terms c_j f_ij (K, 3) in float64, for the
    summing kernels; ``rest``: the row arguments (q (K,) unless ``q_own``, then c (K,) when ``counted``),
    mean q and 2 var z."""
    *row_args, mean_q, two_var = rest
    q = _sq_length(offsets, valid) if q_own else row_args.pop(0)
    flow = _flow(offsets, valid, q, mean_q, two_var, wdtype)
    terms = flow.astype(jnp.float64)
    return flow, (row_args[0][:, None] * terms if counted else terms)


@functools.lru_cache(maxsize=None)
def _device_sum_kernel(q_own: bool, counted: bool):
    """The float32 flow kernel of :func:`laplacian_norms` summed on the device, per row: the sum of
    c_j f_ij in float64 (3,), the smallest non-zero |f_ij| (3,) and the largest |c_j f_ij| (3,).

    Row arguments: q (K,) unless ``q_own`` (q from the offsets), then c (K,) float64 when ``counted``.
    """
    def kernel(offsets, valid, *rest):
        flow, terms = _row_terms(offsets, valid, rest, q_own, counted, offsets.dtype)
        return jnp.sum(terms, axis=0), _smallest_nonzero(jnp.abs(flow)), jnp.max(jnp.abs(terms), axis=0)

    return kernel


@functools.lru_cache(maxsize=None)
def _ordered_sum_kernel(q_own: bool, counted: bool, wdtype):
    """The flow kernel of :func:`laplacian_norms` summed on the device in the order of its columns: the
    terms c_j f_ij in float64 added one by one (3,), as :func:`row_sums` adds them on the host.

    Row arguments: q (K,) unless ``q_own`` (q from the offsets, weights in the points' dtype, else
    in ``wdtype``), then c (K,) float64 when ``counted``.
    """
    def kernel(offsets, valid, *rest):
        terms = _row_terms(offsets, valid, rest, q_own, counted, offsets.dtype if q_own else wdtype)[1]
        return jax.lax.scan(lambda total, term: (total + term, None), jnp.zeros(3, jnp.float64), terms)[0]

    return kernel


def row_sums(flows: np.ndarray, smallest: np.ndarray, largest: np.ndarray, nbr: np.ndarray, counts_ext,
             tie_ext: np.ndarray) -> np.ndarray:
    """(R, 3) float64 sums over each row of the terms c_j f_ij.

    Each sum has the bits of the terms added one by one in float64, in the order of the
    partners' ``tie_ext`` (padding columns, whose terms are 0, last). Most rows need no
    order (:func:`_exact_in_any_order`); only the others are ordered and added one by one
    (in practice about one float32 row in 1e5).

    Args:
      flows: (R, 3, K) f_ij, padding columns 0.
      smallest, largest: (R, 3) each row's smallest non-zero |f_ij| (inf if none) and largest |f_ij|.
      nbr: (R, K) partners, padded with n.
      counts_ext: (n + 1,) c_j, 0 for the padding; None: every c_j = 1.
      tie_ext: (n + 1,) the order of the partners, the padding n last.
    """
    if counts_ext is None:
        lp = np.sum(flows, axis=2, dtype=np.float64)
    else:
        c = counts_ext[nbr][:, None, :]
        flows = c * flows
        lp, largest = np.sum(flows, axis=2), largest * c.max(axis=2, initial=0.0)
    slow = np.flatnonzero(~_exact_in_any_order(smallest, largest, flows.shape[2]))
    if slow.size:
        order = np.argsort(tie_ext[nbr[slow]], axis=1, kind="stable")[:, None, :]
        lp[slow] = np.add.accumulate(np.take_along_axis(flows[slow], order, axis=2), axis=2, dtype=np.float64)[..., -1]
    return lp


def graph_rows(index: spatial.SpatialIndex, rows: np.ndarray, r: float, max_nn: int, search: str = "host"):
    """The stored partners of the ``rows`` (R,) of a deduplicated index, as
    :func:`hgjax.neighbours.radius_graph.location_rows` yields them (with ``search="jax"``
    :func:`hgjax.neighbours.radius_graph.index_location_rows`: the same partners)."""
    want = np.zeros(index.n, bool)
    want[rows] = True
    if search == "jax":
        return radius_graph.index_location_rows(index, r, max_nn, want)
    return radius_graph.location_rows(index, r, max_nn, want)


def graph_sums(index: spatial.SpatialIndex, rows: np.ndarray, r: float, max_nn: int, dtype,
               search: str = "host") -> tuple[list, tuple]:
    """The stored partners of the ``rows`` (R,) of a deduplicated index, and their exact pair sums.

    One chunk of rows at a time (:func:`graph_rows` by ``search``): the partners and the sums of
    :func:`pair_sums` (q in ``dtype``); only the partners are kept, as
    (own, sym) per chunk, for :func:`graph_norms`. A chunk's sums are taken in a background
    thread, in the caller's JAX precision and on its default device, while the next chunk's
    partners are found.
    """
    counts_ext = _counts_ext(index)
    ext = _stream.device_points(index.points, dtype)
    # this thread's settings, contexts included: a new thread has the process's
    x64, device = jax.config.jax_enable_x64, jax.config.jax_default_device

    def sums_of(own, sym):
        with jax.enable_x64(x64), jax.default_device(device):
            return pair_sums(index.points, own, sym, dtype, counts_ext, index.gid, ext=ext)

    chunks, sums = [], []
    with concurrent.futures.ThreadPoolExecutor(1) as behind:
        for own, sym in graph_rows(index, rows, r, max_nn, search):
            sums.append(behind.submit(sums_of, own, sym))
            chunks.append((own, sym))
        sums = [s.result() for s in sums]
    return chunks, summed(sums)


def graph_norms(index: spatial.SpatialIndex, chunks: list, mean_q: float, two_var: float, dtype, *,
                chunk_size=None, progress=False) -> np.ndarray:
    """(R,) float64 ||(L P)_i|| of the rows of :func:`graph_sums`' chunks, ascending rows."""
    counts_ext, out, rows = _counts_ext(index), [], []
    ext = _stream.device_points(index.points, dtype)
    for own, sym in chunks:
        out.append(laplacian_norms(index.points, own, sym, None, counts_ext, index.gid, mean_q, two_var, dtype, dtype,
                                   ext=ext, chunk_size=chunk_size, progress=progress))
        rows.append(own)
    return np.concatenate(out)[np.argsort(np.concatenate(rows))] if out else np.zeros(0)


def _counts_ext(index: spatial.SpatialIndex) -> np.ndarray | None:
    """(n + 1,) float64 points at each location of a deduplicated index and 0 for the padding n; None
    without duplicates."""
    if index.n == index.n_caller:
        return None
    return np.append(np.bincount(index.row, minlength=index.n).astype(np.float64), 0.0)


def soft_score(nb, *, variant: str = "invariant"):
    """GFR score in units of the RMS pair length, one pure JAX program: smooth on a fixed graph.

    :func:`high_pass` divided by sqrt(mean q) over the stored pairs, so the soft score (and
    the soft top-k temperature, in score units) does not depend on the cloud's units; the
    ranking is :func:`score`'s.

    Args:
      nb: :class:`hgjax.Neighbourhoods` from :func:`neighbourhoods`.
      variant: as :func:`score`.

    Returns:
      (N,) scores >= 0; higher is sharper. Gradients are finite on every cloud.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.neighbourhoods(np.random.default_rng(0).random((100, 3)), "gfr")
      >>> hgjax.scores.gfr.soft_score(nb).shape
      (100,)
    """
    variant = _validate.check_variant(variant)
    points, idx = jnp.asarray(nb.points), jnp.asarray(nb.idx)
    _validate.check_graph(points, idx, nb.first, _weights_dtype(variant))
    return _soft(points, idx, nb.first, weights_dtype=_weights_dtype(variant))


@functools.partial(jax.jit, static_argnames="weights_dtype")  # eager callers: one program, not one per operation
def _soft(points, idx, first, *, weights_dtype):
    """:func:`soft_score` of validated arrays."""
    own, partner = _multiplicities(first, idx, points.shape[0], points.dtype)
    pair = jnp.where(idx < points.shape[0], own[:, None] * partner, 0)
    mean_q = _common.safe_div(jnp.sum(pair * _stream.pure_map(_sq_length, points, idx)), jnp.sum(pair), 0.0)
    unit = _common.safe_sqrt(mean_q)  # the RMS pair length
    return _common.safe_div(_pure_high_pass(points, idx, first, weights_dtype), unit, 0.0)


def _select(scores, m: int, *, key=None, mode: str = "random") -> np.ndarray:
    """GFR selection: weighted sampling with pi = 0.8 score / sum + 0.2 / N, or the top scores.

    The random mode takes scores >= 0 (the high-pass norms are; a negative score raises
    ValueError) and, as every method's :func:`hgjax.keep`, +inf: pi is then its limit as
    those scores grow alike, the infinite scores sharing 0.8 equally (0.8 / count + 0.2 / N;
    0.2 / N for the others). Finite sums beyond float64 are scaled by a power of two first.
    """
    mode = _validate.check_choice(mode, "mode", MODES)
    if mode == "top":
        return select.top_k(scores, m, largest=True)
    check_key(key, {"mode": mode})
    values = np.asarray(scores, dtype=np.float64)
    n = values.shape[0]
    if values.min() < 0:
        raise ValueError(f"scores must be >= 0 (or +inf) for GFR's random mode, pi = 0.8 score / sum + 0.2 / N;"
                         f" got {float(values.min())!r} (mode='top' ranks any scores)")
    infinite = np.isinf(values)
    if infinite.any():
        return select.weighted_sample(key, np.where(infinite, 0.8 / infinite.sum(), 0.0) + 0.2 / n, m)
    total = select.ExactSum.of(values)
    shift = -total.exponent()  # exact: pi keeps its bits, and a sum beyond float64 stays finite
    return select.weighted_sample(key, inclusion(np.ldexp(values, shift), total.value(shift), n), m)


def _untiled(params: dict) -> tuple[str, str] | None:
    if params.get("variant") != "reference":
        return None
    return (" with variant='reference'",
            "its squared radius comes from the min and max nearest distance of the whole cloud")


def tile_params(n: int, params: dict) -> tuple[dict, dict]:
    """Validated (build, score) parameters of the invariant GFR for a tiled run (``r`` resolved later).

    Raises:
      TypeError, ValueError: invalid parameters.
    """
    del n  # any number of points
    variant, factor, max_nn = radius_graph.graph_params(params.get("variant", "invariant"), params.get("radius_factor"),
                                                  params.get("max_nn", radius_graph.MAX_NN))
    mode = _validate.check_choice(params.get("mode", "random"), "mode", MODES)
    _validate.check_capacity_param(params, 1)
    build = {"variant": variant, "radius_factor": factor, "dedupe": True, "r": None, "max_nn": max_nn}
    return backend.with_search(build, params), {"mode": mode}


def check_key(key, params: dict):
    """The validated ``key`` of the random mode (``params["mode"]``, default "random"); None in the top mode.

    Raises:
      TypeError: the random mode without a valid key.
    """
    if params.get("mode", "random") != "random":
        return None
    return _validate.check_key(key, "gfr", ' (or mode="top" for the deterministic top scores)')


def resolve_build(build: dict, stats) -> dict:
    """``build`` with the squared radius ``r`` from the seeded sample's nearest distances ``stats()``."""
    return {**build, "r": radius_graph.squared_radius(build["radius_factor"], stats())}


def tiled_select(runner, parts, plan, key=None):
    """GFR's selection over the tiles: the top scores, or Gumbel-top-k of the weights pi by global id.

    Returns:
      (parts, their order keys, {"score_sum"} in the random mode, True).
    """
    if plan.score["mode"] == "top":
        return parts, runner.each(select.part_keys, parts, True), {}, True
    total = sum(runner.gather(runner.each(_exact_sum, parts)), select.ExactSum()).value()
    keyed = runner.each(_gumbel_keys, parts, total, plan.n, np.asarray(jax.random.key_data(key)))
    return parts, keyed, {"score_sum": total}, True


def _exact_sum(part) -> select.ExactSum:
    return select.ExactSum.of(part[1])


def _gumbel_keys(part, total: float, n: int, key_data: np.ndarray):
    """GFR's Gumbel-top-k keys: log pi + Gumbel(key, gid), pi = 0.8 s / sum(s) + 0.2 / N (Chen et al.)."""
    gids, s = part
    perturbed = select.gumbel_log_weights(key_data, inclusion(s, total, n), gids)
    return select.order_keys(perturbed, largest=True), gids


def _tile_graph(index: spatial.SpatialIndex, rows: np.ndarray, plan_) -> dict:
    """The first pass of a tile: GFR's graph around its core locations ``rows`` and its exact pair sums
    (Chen et al. 2018), on a halo verified to hold :func:`_graph_reach` around every core location.

    A core location's stored pairs are those it ranks or that rank it, so every location
    within the radius R of it must see its whole R-ball: the halo holds 2R.
    """
    b = plan_.build
    chunks, sums = graph_sums(index, rows, b["r"], b["max_nn"], plan_.dtype, b.get("search", "host"))
    return {"chunks": chunks, "sums": sums}


def _graph_reach(build: dict) -> float:
    """How far around a core location GFR's tile must hold every point: twice the pair query's bound
    (its partners' partners), for the squared radius ``build["r"]``."""
    return 2 * np.sqrt(build["r"]) * (1 + 1e-5)


def _tile_sums(graph: dict) -> tuple:
    return graph["sums"]


def _moments(sums: list) -> tuple[float, float]:
    """(mean q, 2 var q) of the whole cloud's stored pairs, from every tile's pair sums."""
    return moments(summed(sums))


def _tile_norms(index: spatial.SpatialIndex, rows: np.ndarray, graph: dict, plan_, total: tuple, stream: dict):
    """The second pass of a tile: ||(L P)_i|| of its core ``rows``, given the global weight statistics."""
    mean_q, two_var = total
    return graph_norms(index, graph["chunks"], mean_q, two_var, plan_.dtype, **stream).astype(plan_.dtype)


def _reach(build: dict) -> tuple[int, int]:
    """(DEFAULT_K, 1): the sample statistics' reach; the graph's own is :func:`_graph_reach`."""
    del build
    return DEFAULT_K, 1


METHOD = _method.Method(
    "gfr", "graph", largest=True, needs_key=True,
    summary='graph filtering baseline: sample by the graph high-pass ||(L P)_i|| (needs key, or mode="top")',
    citation="Chen, Tian, Feng, Vetro, Kovacevic, IEEE TSP 66(3), 2018", build=neighbourhoods, score=score,
    soft_score=soft_score,
    select=_select, check_key=check_key, keeps_top={"mode": "top"}, traced_columns=radius_graph.traced_columns,
    bytes_per_sample=4096,
    tiling=_method.Tiling(params=tile_params, reach=_reach, resolve=resolve_build,
                          passes=_method.Passes(reach=_graph_reach, first=_tile_graph, summary=_tile_sums,
                                                reduce=_moments, second=_tile_norms),
                          select=tiled_select, refused=_untiled))
