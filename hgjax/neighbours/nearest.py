"""k-nearest neighbourhoods (EA, PCA-AC, LHF, MSS) by either search, and their tiled builds.

:func:`knn` is the host's (a k-d tree; :class:`hgjax.neighbours.spatial.SpatialIndex`), :func:`traced`
the traced search's (:func:`hgjax.neighbours.cells.traced_knn`: pure JAX, under ``jax.jit`` with static N,
k and columns, ``jax.vmap`` and inside ``jax.grad``; the choice of neighbours is discrete, so no
gradient flows through it), :func:`build` the one dispatch on ``search``. The traced search has
no capacity: it reads every candidate a query's cells hold, so nothing is truncated and nothing
needs sizing. Both give the same neighbourhoods: the point itself first, then its neighbours by
increasing distance, ties by index in the spatially sorted frame.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from hgjax import _stream, _validate
from hgjax.neighbours import backend, cells, spatial
from hgjax.neighbours.container import Neighbourhoods, record

__all__ = ["build", "build_params", "index_knn", "knn", "reach", "tile_rows", "traced"]


def knn(points, k: int, *, dedupe: bool = False, capacity: int | None = None) -> Neighbourhoods:
    """k-nearest neighbourhoods, the point itself first.

    Args:
      points: (N, 3) float32 or float64.
      k: neighbourhood size, counting the point itself (1 <= k <= N).
      dedupe: count exact duplicates once (each copy gets its location's neighbourhood).
      capacity: columns of ``idx`` (default k); must be >= k.

    Returns:
      Neighbourhoods with ``idx`` (N, K) int32 in the caller's order; ``idx[:, 0]`` is the
      point itself (with ``dedupe``, the first copy of its location), then neighbours by
      increasing distance. Rows are padded with N only when there are fewer than k distinct
      locations (``dedupe``) or K > k.

    Raises:
      TypeError, ValueError: for invalid points, k or capacity.

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.knn(np.eye(3), 2)
      >>> nb.idx[:, 0].tolist()
      [0, 1, 2]
    """
    pts = _validate.check_points(points)
    k = _validate.check_int(k, "k", minimum=1)
    _validate.check_min_points(pts.shape[0], k, f"k={k} nearest neighbours")
    cap = k if capacity is None else _validate.check_int(capacity, "capacity", minimum=k)
    dedupe = _validate.check_bool(dedupe, "dedupe")
    index = spatial.SpatialIndex(spatial.local_frame(pts)[0], dedupe=dedupe)
    parts = (idx for _, idx, _ in spatial.knn_batches(index, k, np.arange(index.n)))
    idx = spatial.caller_rows(index, parts, cap, what="k-nearest neighbourhood")
    return spatial.assemble(pts, index, idx, params={"k": k, "dedupe": dedupe})



def build(points, k: int, *, dedupe: bool, capacity: int | None, search: str = "host",
              cell_slots: int | None = None, cell_edge=None) -> Neighbourhoods:
    """The k-nearest neighbourhoods of the k-nearest methods (EA, PCA-AC, LHF, MSS) by either search.

    Args:
      points: (N, 3) float32 or float64; may be a tracer with ``search="jax"``.
      k, dedupe, capacity: as :func:`knn`.
      search: ``"host"`` (:func:`knn`, SciPy; not jittable) or ``"jax"``
        (:func:`traced`: jit, vmap, grad; the same neighbourhoods, exact for any cloud with no
        sizes passed).
      cell_slots: candidates the traced search reads per step (static; default
        :data:`CELL_SLOTS`): a speed setting, never a limit.
      cell_edge: the traced search's first cell edge (traced), or None for one from the data;
        rows it misses are searched again at a wider edge, so it too sets only the speed.

    Raises:
      TypeError, ValueError: invalid arguments.
    """
    search = _validate.check_choice(search, "search", backend.SEARCHES)
    if search == "host":
        return knn(points, k, dedupe=dedupe, capacity=capacity)
    pts = backend.checked_points(points)
    k = _validate.check_int(k, "k", minimum=1)
    _validate.check_min_points(pts.shape[0], k, f"k={k} nearest neighbours")
    cap = k if capacity is None else _validate.check_int(capacity, "capacity", minimum=k)
    dedupe = _validate.check_bool(dedupe, "dedupe")
    slots = backend.CELL_SLOTS if cell_slots is None else _validate.check_int(cell_slots, "cell_slots", minimum=1)
    return traced(pts, k, dedupe=dedupe, capacity=cap, cell_slots=slots, cell_edge=cell_edge,
               params={"k": k, "dedupe": dedupe})


def traced(points, k: int, *, dedupe: bool, capacity: int | None, cell_slots: int = backend.CELL_SLOTS, cell_edge=None,
        params: dict) -> Neighbourhoods:
    """k-nearest neighbourhoods as :func:`knn` builds them, by the traced search.

    Args:
      points: (N, 3) float32 or float64 (a tracer under ``jit``).
      k: neighbourhood size, counting the point itself (static).
      dedupe: count exact duplicates once (static).
      capacity: columns of ``idx`` (static, >= k), default k.
      cell_slots: candidates read per step (static).
      cell_edge: the first cell edge (traced), or None for one from the data.
      params: the build parameters recorded on the result (``search`` added).

    Returns:
      :class:`hgjax.Neighbourhoods` with the host's ``idx`` (N, K) int32, padded with N.

    Raises:
      ValueError: eagerly, or when the compiled program runs, a search that could not cover
        some row (:func:`guard`).
    """
    p = jnp.asarray(points)
    n = p.shape[0]
    if _stream.is_traced(p):
        local, lo = backend.traced_frame(p)
        found = cells.traced_knn(p, k, dedupe=dedupe, slots=cell_slots, edge=cell_edge)
    else:
        local, lo = backend.host_frame(points)
        found = cells.grown(cells.traced_knn, p, k, dedupe=dedupe, slots=cell_slots, edge=cell_edge)
    overflow = backend.guard(jnp.where(found.overflow, -1, 0).astype(jnp.int32))
    idx = found.idx.astype(jnp.int32)
    cap = k if capacity is None else capacity
    if cap > k:
        idx = jnp.concatenate([idx, jnp.full((n, cap - k), n, jnp.int32)], axis=1)
    return Neighbourhoods(local, idx, params=record({**params, "search": "jax"}), overflow=overflow, points_lo=lo)


def index_knn(index: spatial.SpatialIndex, k: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`hgjax.neighbours.spatial.SpatialIndex.neighbours` of sorted-frame ``rows`` by the traced search (a
    tile's build, :func:`hgjax.neighbours.backend.index_search`: the host's neighbourhoods bit for bit).

    Returns:
      (idx, reach): idx (R, k) int32 sorted-frame rows, column 0 the point itself, padded
      with n when the index holds fewer than k points; reach (R,) float64 the k-th
      distance (inf when the index holds fewer than k points).

    Raises:
      ValueError: global ids beyond int32 (the traced search's tie key).
    """
    n, k_eff = index.n, min(k, index.n)
    found = backend.index_search(index, cells.traced_knn, k_eff)
    idx, reach = found.idx[rows], found.reach[rows]
    idx = np.pad(idx, ((0, 0), (0, k - k_eff)), constant_values=n)
    return idx, (reach if k_eff == k else np.full(reach.shape, np.inf))


def build_params(n: int, k: int, params: dict) -> dict:
    """Build parameters ``{"k", "dedupe"}`` of a k-nearest method for ``n`` points (and
    ``"search": "jax"`` when its tiles build with the traced search).

    Raises:
      TypeError, ValueError: invalid ``dedupe`` or ``capacity`` (an integer >= k, as
        :func:`hgjax.knn` takes it), or fewer than k points.
    """
    build = {"k": k, "dedupe": _validate.check_bool(params.get("dedupe", True), "dedupe")}
    _validate.check_capacity_param(params, k)
    _validate.check_min_points(n, k, f"k={k} nearest neighbours")
    return backend.with_search(build, params)


def tile_rows(index, rows, build: dict, dtype):
    """(part, idx, (), reach) per batch: the k-nearest neighbourhoods of ``rows`` (:func:`hgjax.neighbours.spatial.knn_batches`,
    or one batch of :func:`index_knn` with ``build["search"] == "jax"``)."""
    del dtype  # no per-row arguments
    if build.get("search") == "jax":
        idx, reach = index_knn(index, build["k"], rows)
        yield slice(0, rows.size), idx, (), reach
        return
    for part, idx, reach in spatial.knn_batches(index, build["k"], rows):
        yield part, idx, (), reach


def reach(build: dict) -> tuple[int, int]:
    """(k, 1): a k-nearest neighbourhood reaches its own k-nearest radius (:attr:`hgjax.Method.tiling`)."""
    return build["k"], 1
