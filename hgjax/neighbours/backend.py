"""Which neighbour search runs (``search="host"`` or ``"jax"``), and the traced search's overflow guard.

The traced search returns the same :class:`hgjax.Neighbourhoods` as the host builders, in pure
JAX: under ``jax.jit`` (static N, k and columns), ``jax.vmap`` and inside ``jax.grad`` (the choice
of neighbours is discrete, so no gradient flows through it; the points returned are a smooth
function of the input). The k-nearest search has no capacity: it reads every candidate a
query's cells hold, so nothing is ever truncated and nothing needs sizing. What can still
overflow (a ball or a graph row wider than its static columns) stops the program:
:func:`guard` raises eagerly, and under ``jit`` the compiled program raises when it runs,
naming the ``capacity`` needed, instead of returning a truncated result.

The traced builds move the points to the host's local frame (:func:`traced_frame`: the
bounding-box centre subtracted) with the centre carried exactly (TwoSum), so the float32
coordinates equal the host's float64 subtraction rounded once, up to a double rounding at an
exact midpoint; under x64 the subtraction is the host's own.

A tiled run (:mod:`hgjax.engine`) builds each tile by either search: with ``search="jax"`` every
kind's tile build (k nearest, cubes and balls, GFR's graph) runs the traced search on the tile's
host index (:func:`index_search`), whose rows are the host's bit for bit, so a core point's
neighbourhood and score do not depend on the search nor on the tile that holds it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from hgjax import _exact, _stream, _validate
from hgjax.neighbours import cells, spatial

__all__ = ["CELL_SLOTS", "SEARCHES", "check", "checked_points", "default_search", "guard", "host_frame", "index_search",
           "traced_frame", "with_search"]

CELL_SLOTS = cells.SLOTS
"""Candidates a query of the traced search reads per step (static; a speed setting, never a limit)."""
SEARCHES = ("host", "jax")
"""The neighbour searches: SciPy's k-d tree on the host, or the traced search."""


def checked_points(points, search: str = "jax"):
    """``points`` validated for a build by ``search``: with the traced search a tracer's shape and dtype
    (:func:`hgjax._validate.check_traced_points`: its values do not exist yet), anything else in full
    (:func:`hgjax._validate.check_points`)."""
    if search == "jax" and _stream.is_traced(points):
        return _validate.check_traced_points(points)
    return _validate.check_points(points)


def traced_frame(points) -> tuple[jax.Array, jax.Array | None]:
    """(hi, lo): (N, 3) ``points`` minus the centre of their bounding box, traced, as the host's
    :func:`hgjax.neighbours.spatial.split_frame` of its float64 local frame.

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
    """(hi, lo) of concrete ``points``: the host's local frame (:func:`hgjax.neighbours.spatial.local_frame`) split
    in its working dtype (:func:`hgjax.neighbours.spatial.split_frame`; float64 input keeps its bits until then)."""
    host = np.asarray(points)
    hi, lo = spatial.split_frame(spatial.local_frame(host)[0], spatial.working_dtype(host.dtype))
    return jnp.asarray(hi), None if lo is None else jnp.asarray(lo)


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


def with_search(build: dict, params: dict) -> dict:
    """``build`` with ``"search": "jax"`` when the run's tiles build with the traced search (``params``
    as :func:`hgjax.engine.searched` validated them); the host search is recorded by no key, so a host
    run's plan is what it always was."""
    return {**build, "search": "jax"} if params.get("search") == "jax" else build


def default_search() -> str:
    """The search a run uses when none is named: ``"jax"`` on a GPU/TPU backend, ``"host"`` on CPU.

    On a CPU SciPy's k-d tree is faster than the traced search (``bench/results/device_search.md``);
    on an accelerator the traced search runs where the scores run (``device_search_gpu.md``).
    """
    return "host" if jax.default_backend() == "cpu" else "jax"


def index_search(index: spatial.SpatialIndex, query, *args, radius=None, **kwargs) -> cells.Found:
    """``query`` (:func:`hgjax.neighbours.cells.traced_knn` or :func:`hgjax.neighbours.cells.within`) over every row of a
    tile's host index, grown until nothing overflows (:func:`hgjax.neighbours.cells.grown`): a tiled run's build.

    The search runs on the index's own float64 coordinates with x64 enabled for this call only
    (``frame=False``: the host's frame, its distances the k-d tree's), ties by the index's global
    ids, so the neighbourhoods are the host's bit for bit. The index is padded to a power of two
    (:func:`hgjax.neighbours.spatial.bucket`): one program per size class.

    Args:
      index: the tile's index.
      query, *args, **kwargs: the query and its arguments (``k`` or ``columns``, ``metric``, ...).
      radius: the query's radius, a scalar or one per row of the index (n,), or None.

    Returns:
      :class:`hgjax.neighbours.cells.Found` of NumPy arrays, its rows the index's n rows (indices
      into them, padded with n), distances and reaches float64.

    Raises:
      ValueError: global ids beyond int32 (the traced search's tie key).
    """
    if index.gid_span > np.iinfo(np.int32).max:
        raise ValueError(f"search='jax' breaks ties by int32 global ids; this cloud's go up to {index.gid_span - 1}:"
                         " use search='host'")
    n = index.n
    pad = spatial.bucket(n) - n
    if radius is not None:
        kwargs["radius"] = np.pad(np.broadcast_to(np.asarray(radius, np.float64), (n,)), (0, pad))
    with jax.enable_x64(True):
        found = cells.grown(query, np.pad(index.points, ((0, pad), (0, 0))), *args,
                            gid=np.pad(index.gid[:n], (0, pad)).astype(np.int32), count=n, frame=False, **kwargs)
        found = jax.tree.map(np.asarray, found)
    return dataclasses.replace(found, idx=np.minimum(found.idx[:n], n), dist=found.dist[:n], reach=found.reach[:n])
