"""Neighbourhoods from the traced search (``search="jax"``): :mod:`hgjax._search_jax` made into a :class:`hgjax.Neighbourhoods`.

The same pytree as the host builders (:func:`hgjax.spatial.knn`), built in pure JAX: under
``jax.jit`` (static N, k and columns), ``jax.vmap`` and inside ``jax.grad`` (the choice of
neighbours is discrete, so no gradient flows through it; the points returned are a smooth
function of the input). The k-nearest search has no capacity: it reads every candidate a
query's cells hold, so nothing is ever truncated and nothing needs sizing. What can still
overflow (a ball or a graph row wider than its static columns) stops the program:
:func:`guard` raises eagerly, and under ``jit`` the compiled program raises when it runs,
naming the ``capacity`` needed, instead of returning a truncated result.

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

__all__ = ["CELL_SLOTS", "SEARCHES", "build_knn", "check", "default_search", "guard", "host_frame", "index_knn",
           "knn", "local_frame"]

CELL_SLOTS = _search_jax.SLOTS
"""Candidates a query of the traced search reads per step (static; a speed setting, never a limit)."""
SEARCHES = ("host", "jax")
"""The neighbour searches: SciPy's k-d tree on the host, or the traced search."""


def build_knn(points, k: int, *, dedupe: bool, capacity: int | None, search: str = "host",
              cell_slots: int | None = None, cell_edge=None) -> spatial.Neighbourhoods:
    """The k-nearest neighbourhoods of the k-nearest methods (EA, PCA-AC, LHF, MSS) by either search.

    Args:
      points: (N, 3) float32 or float64; may be a tracer with ``search="jax"``.
      k, dedupe, capacity: as :func:`hgjax.spatial.knn`.
      search: ``"host"`` (:func:`hgjax.spatial.knn`, SciPy; not jittable) or ``"jax"``
        (:func:`knn`: jit, vmap, grad; the same neighbourhoods, exact for any cloud with no
        sizes passed).
      cell_slots: candidates the traced search reads per step (static; default
        :data:`CELL_SLOTS`): a speed setting, never a limit.
      cell_edge: the traced search's first cell edge (traced), or None for one from the data;
        rows it misses are searched again at a wider edge, so it too sets only the speed.

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
    slots = CELL_SLOTS if cell_slots is None else _validate.check_int(cell_slots, "cell_slots", minimum=1)
    return knn(pts, k, dedupe=dedupe, capacity=cap, cell_slots=slots, cell_edge=cell_edge,
               params={"k": k, "dedupe": dedupe})


def local_frame(points) -> tuple[jax.Array, jax.Array | None]:
    """(hi, lo): (N, 3) ``points`` minus the centre of their bounding box, traced, as the host's
    :func:`hgjax.spatial.split_frame` of its float64 local frame.

    float64 under x64: the frame itself, lo None. In float32, the centre (lo + hi) / 2 is
    carried as an exact pair (s + e) / 2 and subtracted in two steps; hi is the frame rounded
    once and lo what it rounds off (:attr:`hgjax.Neighbourhoods.points_lo`).
    """
    p = jnp.asarray(points)
    if p.dtype == jnp.float64:
        lo, hi = p.min(axis=0, keepdims=True), p.max(axis=0, keepdims=True)
        return p - (lo + hi) / 2, None
    p = p.astype(jnp.float32)
    lo, hi = p.min(axis=0, keepdims=True), p.max(axis=0, keepdims=True)
    s, e = _exact.two_sum(lo, hi)  # lo + hi == s + e exactly
    a, err = _exact.two_sum(p, -s / 2)  # p - s / 2 == a + err exactly
    return _exact.fast_two_sum(a, err - e / 2)


def host_frame(points) -> tuple[jax.Array, jax.Array | None]:
    """(hi, lo) of concrete ``points``: the host's local frame (:func:`hgjax.spatial.local_frame`) split
    in its working dtype (:func:`hgjax.spatial.split_frame`; float64 input keeps its bits until then)."""
    host = np.asarray(points)
    hi, lo = spatial.split_frame(spatial.local_frame(host)[0], spatial.working_dtype(host.dtype))
    return jnp.asarray(hi), None if lo is None else jnp.asarray(lo)


def knn(points, k: int, *, dedupe: bool, capacity: int | None, cell_slots: int = CELL_SLOTS, cell_edge=None,
        params: dict) -> spatial.Neighbourhoods:
    """k-nearest neighbourhoods as :func:`hgjax.spatial.knn` builds them, by the traced search.

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
        local, lo = local_frame(p)
        found = _search_jax.knn(p, k, dedupe=dedupe, slots=cell_slots, edge=cell_edge)
    else:
        local, lo = host_frame(points)
        found = _search_jax.grown(_search_jax.knn, p, k, dedupe=dedupe, slots=cell_slots, edge=cell_edge)
    overflow = guard(jnp.where(found.overflow, -1, 0).astype(jnp.int32))
    idx = found.idx.astype(jnp.int32)
    cap = k if capacity is None else capacity
    if cap > k:
        idx = jnp.concatenate([idx, jnp.full((n, cap - k), n, jnp.int32)], axis=1)
    record = spatial.record({**params, "search": "jax"})
    return spatial.Neighbourhoods(local, idx, params=record, overflow=overflow, points_lo=lo)


def _raise_overflow(overflow) -> None:
    """Raise for an overflow report (0, the columns needed, or -1 for a row its cells never covered), saying what to do."""
    worst = np.asarray(overflow)
    if not (worst != 0).any():
        return
    needed = int(worst.max())
    how = (f"capacity={needed} (or capacity=None outside jit, which sizes it)" if needed > 0 else
           "points whose coordinates are finite (a row's neighbours were not found within the search's passes)")
    raise ValueError(f"the traced neighbour search overflowed: some neighbourhoods would be truncated; rebuild them"
                     f" with {how}")


def guard(overflow):
    """``overflow`` (an int32 report: 0, the columns needed, or -1), checked: a non-zero report raises.

    Eagerly it raises ValueError at once. Traced (under ``jit``, ``vmap``, ``grad``) the same
    ValueError is raised where the compiled program runs (:func:`hgjax._validate.fail_where`),
    so the caller's call fails (as a ``jax.errors.JaxRuntimeError`` carrying the message)
    instead of returning a truncated neighbourhood.
    """
    if _stream.is_traced(overflow):
        _validate.fail_where(overflow != 0, _raise_overflow, overflow)
    else:
        _raise_overflow(overflow)
    return overflow


def check(nb: spatial.Neighbourhoods) -> None:
    """Raise ValueError when neighbourhoods of the traced search overflowed (never score a truncated one)."""
    overflow = getattr(nb, "overflow", None)  # anything but Neighbourhoods is refused by the caller's checks
    if overflow is not None:
        guard(overflow)


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
                                  frame=False)
        idx, reach = np.asarray(found.idx)[rows], np.asarray(found.reach, np.float64)[rows]
    idx = np.pad(np.minimum(idx, n), ((0, 0), (0, k - k_eff)), constant_values=n)
    return idx, (reach if k_eff == k else np.full(reach.shape, np.inf))
