"""Graph filtering resampling (GFR) baseline: Chen et al., "Fast resampling of
three-dimensional point clouds via graphs", IEEE TSP 66(3), 2018.

The score is the response of a graph high-pass filter, score_i = ||(L P)_i||_2 with the
graph Laplacian L = D - W (Chen et al., Sec. IV), on the radius graph that the authors'
C++ implementation builds (REFERENCE.md, "GFR baseline"):

1. minNN, maxNN = min and max over points of the distance to the nearest other point;
   radius = min(10 minNN, 2 maxNN).
2. Each point links to the points at distance in (0, radius] (itself and its exact
   duplicates excluded), at most ``max_nn`` = 100 of them, the nearest when there are more.
3. An edge with squared length q weighs w = exp(-q^2 / (2 v)), v the (population) variance
   of q over all these one-directional edges; W = W0 + W0^T.

No N x N matrix is formed: the neighbour lists are fixed-capacity (C, K) chunks and
(L P)_i = sum_j W_ij (p_i - p_j) is accumulated chunk by chunk, the W0 part as a row sum and
the W0^T part as a segment sum (scatter-add) onto the neighbours. The order of that sum
is the global (row, column) order whatever the chunk size, so scores are bitwise
independent of chunking on CPU (a GPU's atomic scatter-add may reorder at rounding level).

Degenerate clouds: minNN and maxNN are taken over distances to the nearest *distinct*
point, so exact duplicates do not shrink the radius to 0 (on clouds without duplicates this
is exactly the reference). With no edges (all points equal, N = 1) every score is 0; with
v = 0 (every edge the same length) the weights are exp(-inf) = 0, the limit of the formula,
and every score is 0 too.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbourhoods import SpatialIndex
from hgjax.scores import _common

__all__ = ["gfr", "gfr_neighbourhood"]

GFR_VARIANTS = ("reference",)
MAX_NN = 100


def gfr_neighbourhood(centre, nbrs, valid, two_var):
    """Weighted offsets w_ij (p_j - p_i) of one point's one-directional edges.

    Args:
      centre: (3,) the point p_i.
      nbrs: (K, 3) its graph neighbours, padding rows masked by ``valid`` (K,).
      two_var: 2 v, twice the variance of the squared edge lengths (scalar).

    Returns:
      (K, 3) w_ij (p_j - p_i) with w_ij = exp(-q^2 / (2 v)), q = ||p_j - p_i||^2; zero rows
      for padding.

    Examples:
      >>> import jax.numpy as jnp, hgjax
      >>> nbrs = jnp.array([[1.0, 0, 0], [0, 0, 0]])
      >>> hgjax.scores.gfr_neighbourhood(jnp.zeros(3), nbrs, jnp.array([True, False]), 2.0).tolist()
      [[0.6065306597126334, 0.0, 0.0], [0.0, 0.0, 0.0]]
    """
    d = nbrs - centre[None, :]
    q = jnp.sum(d * d, axis=1)
    w = jnp.exp(-_common.safe_div(q * q, two_var, jnp.inf))
    return jnp.where(valid[:, None], w[:, None] * d, 0)


@functools.partial(jax.jit, donate_argnums=(0,))
def _accumulate(acc_t, points_ext, rows, idx, two_var):
    """One chunk of L P: its W0 rows, and its W0^T edges added into acc_t (N + 1, 3).

    The W0 part sum_j w_ij (p_i - p_j) is row-local and returned per row. The W0^T part is a
    scatter-add whose updates XLA applies one at a time in (row, column) order, so every
    row of acc_t receives its terms in the same global order whatever the chunking: the
    scores are bitwise independent of the chunk size. Row N is a sink for padding.
    """
    c = _common.map_neighbourhoods(gfr_neighbourhood)(points_ext, rows, idx, two_var)  # (C, K, 3)
    acc_t = acc_t.at[idx.reshape(-1)].add(c.reshape(-1, 3))  # w_ij (p_j - p_i) onto row j
    return acc_t, -jnp.sum(c, axis=1)


def _radius(index: SpatialIndex, chunk_size: int) -> float:
    """min(10 minNN, 2 maxNN) over nearest-distinct distances; 0 when no point has one."""
    nearest = np.concatenate([index.ball(np.inf, rows, max_nn=1, capacity=2)[1].ravel()
                              for rows in index.chunks(chunk_size)])
    nearest = nearest[np.isfinite(nearest)]
    if nearest.size == 0:
        return 0.0
    return float(min(10 * nearest.min(), 2 * nearest.max()))


def _graph(index: SpatialIndex, radius: float, max_nn: int, chunk_size: int):
    """Neighbour chunks (sorted frame) and the variance of the squared edge lengths."""
    chunks, count, mean, m2, capacity = [], 0, 0.0, 0.0, 16
    for rows in index.chunks(chunk_size):
        idx, dist = index.ball(radius, rows, max_nn=max_nn, capacity=capacity)
        capacity = max(16, 1 << idx.shape[1].bit_length())  # spatial order: the next chunk is alike
        chunks.append(idx)
        # Chan et al.'s pairwise update of (count, mean, sum of squared deviations), block by
        # block of _stream.BLOCK rows: the same sequence of updates whatever the chunk size.
        for start in range(0, idx.shape[0], _stream.BLOCK):
            sub = slice(start, start + _stream.BLOCK)
            q = dist[sub][idx[sub] < index.n] ** 2
            if q.size:
                qm = q.mean()
                delta, total = qm - mean, count + q.size
                m2 += np.sum((q - qm) ** 2) + delta * delta * count * q.size / total
                mean += delta * q.size / total
                count = total
    return chunks, (m2 / count if count else 0.0)


def gfr(points, *, variant: str = "reference", max_nn: int = MAX_NN, radius: float | None = None,
        chunk_size: int | None = None, progress: bool = False) -> np.ndarray:
    """GFR high-pass score ||(L P)_i||_2 per point (Chen et al. 2018); higher is sharper.

    Args:
      points: (N, 3) float32 or float64.
      variant: ``"reference"``, the graph of the authors' implementation (the only variant;
        the argument keeps the score API uniform).
      max_nn: the most neighbours per point in W0 (reference: 100). Static: it sets the
        kernel's neighbour capacity, so a new value may compile a new kernel.
      radius: graph radius overriding the reference rule min(10 minNN, 2 maxNN). On clouds
        sampled uniformly at random, minNN is far below the typical spacing and the
        reference graph is nearly empty (most scores 0); pass e.g. ``2 *
        hgjax.intrinsic_resolution(points)`` for a connected graph.
      chunk_size: points per chunk (default: automatic). Does not change results.
      progress: show a progress bar on stderr for long runs.

    Returns:
      (N,) scores >= 0 in the dtype of ``points`` (all 0 when the graph has no edge). The
      variance v is computed in float64 on the host from the tree's distances.

    Raises:
      TypeError, ValueError: invalid points, max_nn, radius or chunk_size, unknown variant.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = np.random.default_rng(0).random((200, 3))
      >>> s = hgjax.scores.gfr(pts)
      >>> s.shape, bool((s >= 0).all())
      ((200,), True)
    """
    pts = _validate.check_points(points)
    _validate.check_choice(variant, "variant", GFR_VARIANTS)
    max_nn = _validate.check_int(max_nn, "max_nn", minimum=1)
    index = SpatialIndex(pts)
    n = index.n
    chunk = _common.chunk_size_or_auto(chunk_size, n, 8 * 3 * 8 * 16)
    radius = _radius(index, chunk) if radius is None else _validate.check_positive(radius, "radius")
    if radius == 0:
        return np.zeros(n, dtype=pts.dtype)
    chunks, var = _graph(index, radius, max_nn, chunk)
    k = -(-max(1, max(c.shape[1] for c in chunks)) // 8) * 8  # few capacities, few compilations
    dtype = _stream.working_dtype(pts.dtype)
    points_ext = jnp.asarray(np.concatenate([index.points, np.zeros((1, 3), pts.dtype)]), dtype=dtype)
    two_var = jnp.asarray(2 * var, dtype=dtype)
    acc_t, row_parts = jnp.zeros((n + 1, 3), dtype=dtype), []
    bar = _stream._progress(n, progress and len(chunks) > 4)
    for rows, idx in zip(index.chunks(chunk), chunks):
        ids = _stream._pad_rows(np.arange(rows.start, rows.stop, dtype=np.int32), chunk, n)
        idx = np.pad(idx, ((0, chunk - idx.shape[0]), (0, k - idx.shape[1])), constant_values=n)
        acc_t, row_part = _accumulate(acc_t, points_ext, ids, idx, two_var)
        row_parts.append(row_part)
        if bar is not None:
            bar.update(rows.stop - rows.start)
    if bar is not None:
        bar.close()
    lp = jnp.concatenate(row_parts)[:n] + acc_t[:n]  # (L P) = W0 rows + W0^T rows
    score = jnp.sqrt(jnp.sum(lp * lp, axis=1))
    return _common.finish(index, score, pts.dtype)
