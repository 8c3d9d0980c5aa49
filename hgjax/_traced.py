"""Neighbourhoods from the traced search (``search="jax"``): :mod:`hgjax._search_jax` made into a :class:`hgjax.Neighbourhoods`.

The same pytree as the host builders (:func:`hgjax.spatial.knn`), built in pure JAX: under
``jax.jit`` (static N, k and capacities), ``jax.vmap`` and inside ``jax.grad`` (the choice of
neighbours is discrete, so no gradient flows through it; the points returned are a smooth
function of the input). Called eagerly, a search that overflows its cell capacity or edge is
run again with what it reports needed (:func:`hgjax._search_jax.grown`); under ``jit`` the
overflow is recorded on the result (:attr:`hgjax.Neighbourhoods.overflow`) and
:func:`hgjax.score` refuses it eagerly.

The points are moved to the host's local frame (the bounding-box centre subtracted) with
the centre carried exactly (TwoSum), so the float32 coordinates equal the host's float64
subtraction rounded once, up to a double rounding at an exact midpoint; under x64 the
subtraction is the host's own.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _exact, _search_jax, _stream, _validate, spatial

__all__ = ["CELL_CAPACITY", "SEARCHES", "build_knn", "check", "default_search", "index_knn", "knn", "local_frame"]

CELL_CAPACITY = 128
"""Candidate slots per query of the traced search (points its 27-cell block may hold; static)."""
SEARCHES = ("host", "jax")
"""The neighbour searches: SciPy's k-d tree on the host, or the traced search."""


def build_knn(points, k: int, *, dedupe: bool, capacity: int | None, search: str = "host",
              cell_capacity: int | None = None, cell_edge=None) -> spatial.Neighbourhoods:
    """The k-nearest neighbourhoods of the k-nearest methods (EA, PCA-AC, LHF, MSS) by either search.

    Args:
      points: (N, 3) float32 or float64; may be a tracer with ``search="jax"``.
      k, dedupe, capacity: as :func:`hgjax.spatial.knn`.
      search: ``"host"`` (:func:`hgjax.spatial.knn`, SciPy; not jittable) or ``"jax"``
        (:func:`knn`: jit, vmap, grad; the same neighbour sets).
      cell_capacity: the traced search's candidate slots per query (static; default
        :data:`CELL_CAPACITY`; eagerly it grows until nothing overflows).
      cell_edge: the traced search's cell edge (traced), or None for one from the data.
        An eager build records the capacity and edge it ended with (``nb.params``), to pass
        to the same search inside ``jit`` (jax-md's allocate, then update).

    Raises:
      TypeError, ValueError: invalid arguments.
    """
    search = _validate.check_choice(search, "search", SEARCHES)
    if search == "host":
        return spatial.knn(points, k, dedupe=dedupe, capacity=capacity)
    traced = _stream.is_traced(points)
    pts = _validate.check_traced_points(points) if traced else _validate.check_points(points)
    k = _validate.check_int(k, "k", minimum=1)
    _validate.check_min_points(pts.shape[0], k, f"k={k} nearest neighbours")
    cap = k if capacity is None else _validate.check_int(capacity, "capacity", minimum=k)
    dedupe = _validate.check_bool(dedupe, "dedupe")
    cells = CELL_CAPACITY if cell_capacity is None else _validate.check_int(cell_capacity, "cell_capacity", minimum=1)
    return knn(pts, k, dedupe=dedupe, capacity=cap, cell_capacity=cells, cell_edge=cell_edge,
               params={"k": k, "dedupe": dedupe})


def local_frame(points) -> jax.Array:
    """(N, 3) ``points`` minus the centre of their bounding box, in the working dtype, traced.

    float64 under x64 (as :func:`hgjax.spatial.local_frame`); in float32, the centre
    (lo + hi) / 2 is carried as an exact pair (s + e) / 2 and subtracted in two steps.
    """
    p = jnp.asarray(points)
    if p.dtype == jnp.float64:
        lo, hi = p.min(axis=0, keepdims=True), p.max(axis=0, keepdims=True)
        return p - (lo + hi) / 2
    p = p.astype(jnp.float32)
    lo, hi = p.min(axis=0, keepdims=True), p.max(axis=0, keepdims=True)
    s, e = _exact.two_sum(lo, hi)  # lo + hi == s + e exactly
    a, err = _exact.two_sum(p, -s / 2)  # p - s / 2 == a + err exactly
    return a + (err - e / 2)


def knn(points, k: int, *, dedupe: bool, capacity: int | None, cell_capacity: int = CELL_CAPACITY, cell_edge=None,
        params: dict) -> spatial.Neighbourhoods:
    """k-nearest neighbourhoods as :func:`hgjax.spatial.knn` builds them, by the traced search.

    Args:
      points: (N, 3) float32 or float64 (a tracer under ``jit``).
      k: neighbourhood size, counting the point itself (static).
      dedupe: count exact duplicates once (static).
      capacity: columns of ``idx`` (static, >= k), default k.
      cell_capacity: the traced search's candidate slots per query (static); eagerly, only
        the first round's: it grows until nothing overflows.
      cell_edge: the cell edge (traced), or None for one from the data.
      params: the build parameters recorded on the result (``search`` added; eagerly also the
        ``cell_capacity`` and ``cell_edge`` the search ended with).

    Returns:
      :class:`hgjax.Neighbourhoods` with the host's ``idx`` (N, K) int32, padded with N;
      ``overflow`` 0 unless a traced call overflowed (then the capacity it needs, or -1).
    """
    p = jnp.asarray(points)
    n = p.shape[0]
    if _stream.is_traced(p):
        local = local_frame(p)
        found = _search_jax.knn(p, k, dedupe=dedupe, capacity=cell_capacity, edge=cell_edge)
        needed = jnp.maximum(found.needed, cell_capacity)
        overflow = jnp.where(found.overflow, jnp.where(found.uncovered, -1, needed), 0).astype(jnp.int32)
    else:  # concrete: the host's own local frame (float64 input keeps its bits until the cast)
        host = np.asarray(points)
        local = jnp.asarray(spatial.local_frame(host)[0].astype(spatial.working_dtype(host.dtype)))
        found = _search_jax.grown(_search_jax.knn, p, k, dedupe=dedupe, capacity=cell_capacity, edge=cell_edge)
        overflow = jnp.zeros((), jnp.int32)
        params = {**params, "cell_capacity": found.capacity, "cell_edge": float(found.edge)}
    idx = found.idx.astype(jnp.int32)
    cap = k if capacity is None else capacity
    if cap > k:
        idx = jnp.concatenate([idx, jnp.full((n, cap - k), n, jnp.int32)], axis=1)
    record = spatial.record({**params, "search": "jax"})
    return spatial.Neighbourhoods(local, idx, params=record, overflow=overflow)


def check(nb: spatial.Neighbourhoods) -> None:
    """Raise ValueError when concrete neighbourhoods of the traced search overflowed (never run on a truncated one)."""
    overflow = getattr(nb, "overflow", None)  # anything but Neighbourhoods is refused by the caller's checks
    if overflow is None or _stream.is_traced(overflow):
        return
    worst = np.asarray(overflow)
    if (worst != 0).any():
        needed = int(worst.max())
        how = (f"cell_capacity={needed}" if needed > 0 else "a wider cell edge or more columns (capacity) (build"
               " it outside jit: an eager hgjax.neighbourhoods(..., search='jax') grows them and records them in"
               " nb.params)")
        raise ValueError(f"nb overflowed the traced search's capacity: some neighbourhoods may be truncated; rebuild"
                         f" them with {how}")


def default_search() -> str:
    """The search a run uses when none is named: ``"jax"`` on a GPU/TPU backend, ``"host"`` on CPU.

    On a CPU SciPy's k-d tree is faster than the traced search (``bench/results/device_search.md``);
    on an accelerator the traced search runs where the scores run (``device_search_gpu.md``).
    """
    return "host" if jax.default_backend() == "cpu" else "jax"


def index_knn(index: spatial.SpatialIndex, k: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`hgjax.spatial.SpatialIndex.knn` of sorted-frame ``rows`` by the traced search (a tile's build).

    The search runs on the index's own float64 coordinates with x64 enabled for this call only
    (``frame=False``: the host's frame, its distances the k-d tree's), ties by the index's
    global ids, so the neighbourhoods are the host's bit for bit.

    Returns:
      (idx, reach): idx (R, k) int32 sorted-frame rows, column 0 the point itself, padded
      with n when the index holds fewer than k points; reach (R,) float64 the k-th
      distance (inf when the index holds fewer than k points).

    Raises:
      ValueError: global ids beyond int32 (the traced search's tie key).
    """
    if index.gid_span > np.iinfo(np.int32).max:
        raise ValueError(f"search='jax' breaks ties by int32 global ids; this cloud's go up to {index.gid_span - 1}:"
                         " use search='host'")
    n, k_eff = index.n, min(k, index.n)
    rows_in = _search_jax.bucket(n)  # the tile padded to a power of two: one program per size class
    with jax.enable_x64(True):
        found = _search_jax.grown(_search_jax.knn, np.pad(index.points, ((0, rows_in - n), (0, 0))), k_eff,
                                  gid=np.pad(index.gid[:n], (0, rows_in - n)).astype(np.int32), count=n,
                                  capacity=CELL_CAPACITY, frame=False)
        idx, reach = np.asarray(found.idx)[rows], np.asarray(found.reach, np.float64)[rows]
    idx = np.pad(np.minimum(idx, n), ((0, 0), (0, k - k_eff)), constant_values=n)
    return idx, (reach if k_eff == k else np.full(reach.shape, np.inf))
