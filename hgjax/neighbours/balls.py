"""Cube and ball neighbourhoods: the region of interest of HKC and HKF (paper Fig. 2), by either search.

:func:`build` is the one dispatch on ``search``: the host's build (:func:`row_batches` on a
:class:`hgjax.neighbours.spatial.SpatialIndex`) or the traced search's (:func:`traced`, pure JAX
under ``jax.jit``, ``jax.vmap`` and ``jax.grad``). :func:`cube` is the plain axis-aligned cube query
of a fixed half-width (:func:`hgjax.cube`). Every whole-cloud decision (:func:`resolve`: the d
factor from the sampling irregularity, the reference resolution) is made here, on the host or
traced.

The cube of half-width k d_i / 2 around every point (or, turned into the point's local frame,
the ball of radius sqrt(3) k d_i / 2 that holds it in every orientation), with the voxel
spacing d_i decided as the host decides it (:func:`hgjax.neighbours.balls.resolve`), all traced:

* ``spacing="local"``: d_i = f x the point's local spacing (:func:`hgjax.neighbours.spatial.local_spacing`
  of its ``local_k`` nearest locations: :func:`local_spacing` of a
  (local_k + 1)-nearest search);
* ``spacing="mean_other"``: d = f x the mean distance from the seeded sample
  (:func:`hgjax.neighbours.spatial.sample_ids`: N is static, so the sample is static NumPy) to each
  sampled point's nearest other point (1.0 when that mean is 0);
* a number: d = f x that fixed spacing;

and f either fixed or from the sample's irregularity (std / mean of the nearest distinct
distances, :meth:`hgjax.neighbours.spatial.SampleStats.irregularity`) through a linear ramp (``ramp``).

Arithmetic (:mod:`hgjax._exact`): under x64 every float64 operation of the host is done in the
host's order (NumPy's pairwise sums, no fused multiply-add, no reciprocal for a division), so
the spacing, the radius and ``scale`` are the host's bits and the neighbour sets the host's.
Without x64 the distances, means, spacing and radius are carried as float32 pairs (about 46
bits) and ``scale`` is the pair rounded once to float32: a point is listed as the host lists it
unless its distance lies within the pairs' precision of the radius (relative 2^-44; a radius
rounded to float32 instead missed 1 point of 1e6 on the box surface, 7e-9 inside it), and a
ball shrunk by ``max_count`` has its ``scale`` from the float32 distance of its
``max_count``-th point (within an ulp of the host's). The order inside a row is the pairs'
(:mod:`hgjax.neighbours.cells`): the host's, except where two distances differ by less than the
pairs' precision or float64's rounding makes them equal (a 1200-point cloud rounded to a 5 cm
grid: 5 rows of long balls listed two tied points in the other order; the same sets).

Search settings: every search of one build (the spacing's k-nearest, the sample's nearest, the
cube) reads its cells ``cell_slots`` candidates at a time and starts from ``cell_edge`` or its
own default (a ball's: 1.1 x the 90th percentile of the radii; the rows it misses are searched
again at a wider edge): both set the speed only. What can overflow is a ball wider than its
static columns (``capacity``): eagerly the columns are the host's (the fullest row rounded up),
counted before the traced program runs, so each size compiles once; under ``jit`` a wider ball
stops the program, naming the columns it needs (:func:`hgjax.neighbours.backend.guard`).

Degenerate clouds: fewer than ``local_k + 1`` locations lower the spacing's k to the number
of other locations, as the host does (under ``jit`` the count is traced, and a ``lax.switch``
picks the k); a single location gets spacing 1 and irregularity 0.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from hgjax import _exact, _stream, _validate
from hgjax.neighbours import backend, cells, spatial
from hgjax.neighbours.cells import _pair_keys
from hgjax.neighbours.container import Neighbourhoods

__all__ = ["COLUMNS", "build", "build_params", "cube", "default_d_factor", "index_balls", "linear_ramp", "local_spacing",
           "resolve", "row_batches", "tile_batches", "traced"]

COLUMNS = 128
"""Columns of a traced cube's ``idx`` under ``jit`` when neither ``capacity`` nor ``max_count`` sets them."""
FIRST_COLUMNS = 32  # columns of a tile's traced reference search's first round (grown to the fullest row's bucket)
EDGE_QUANTILE = 90  # percent: a ball's default cell edge covers this share of the radii (the rest spill)


REFERENCE_D_FACTOR = 1.3  # d = 1.3 x resolution (REFERENCE.md)
# The default variant's d = f x local spacing, f from the sampling irregularity c (the
# coefficient of variation of nearest-neighbour distances): REGULAR_D_FACTOR for lattices
# (c <= 0.25: grids up to noise p = 0.2 spacings), IRREGULAR_D_FACTOR for random samples
# (c >= 0.45), linear in between. Measured on the edge benchmark in both regimes
# (bench/results/edge_defaults.md).
REGULAR_D_FACTOR, IRREGULAR_D_FACTOR = 1.1, 1.6
IRREGULARITY_RANGE = (0.25, 0.45)
LOCAL_K = 16  # neighbours from which the default variant's local spacing is estimated
MAX_COUNT = 256  # the default variant's cube shrinks to hold fewer points than this


def default_d_factor(irregularity: float) -> float:
    """The default variant's d factor for a cloud of this sampling irregularity.

    Args:
      irregularity: std / mean of the nearest-neighbour distances
        (:func:`hgjax.neighbours.spatial.irregularity`).

    Returns:
      1.1 up to 0.25 (lattice-like sampling), 1.6 from 0.45 (random sampling), linear
      in between.

    Examples:
      >>> from hgjax.neighbours import balls
      >>> balls.default_d_factor(0.0), balls.default_d_factor(0.52)
      (1.1, 1.6)
    """
    lo, hi = IRREGULARITY_RANGE
    t = min(max((irregularity - lo) / (hi - lo), 0.0), 1.0)
    return REGULAR_D_FACTOR + t * (IRREGULAR_D_FACTOR - REGULAR_D_FACTOR)

def build_params(*, variant: str = "invariant", d_factor: float | None = None, kernel_size: int = 3,
                 resolution: float | None = None, dedupe: bool | None = None) -> dict:
    """Validated build parameters of HKC/HKF; ``d_factor`` and a reference ``resolution`` may still be None.

    Raises:
      TypeError, ValueError: invalid arguments.
    """
    variant = _validate.check_variant(variant)
    return {
        "variant": variant,
        "d_factor": None if d_factor is None else _validate.check_positive(d_factor, "d_factor"),
        "kernel_size": _validate.check_kernel_size(kernel_size),
        "resolution": None if resolution is None else _validate.check_positive(resolution, "resolution"),
        "dedupe": variant == "invariant" if dedupe is None else _validate.check_bool(dedupe, "dedupe"),
    }

def needs_stats(params: dict) -> bool:
    """Whether resolving ``params`` needs the cloud's :class:`hgjax.neighbours.spatial.SampleStats`."""
    return params["d_factor"] is None or (params["variant"] == "reference" and params["resolution"] is None)

def resolve(params: dict, stats: spatial.SampleStats | None) -> dict:
    """Build parameters with every whole-cloud decision made: d_factor, and the reference resolution.

    The invariant variant's d factor comes from the sample's irregularity
    (:func:`default_d_factor`); the reference variant's resolution is the sample's mean
    nearest-other distance (1.0 when the cloud has a single location) and its factor 1.3.
    """
    out = dict(params)
    if out["d_factor"] is None:
        out["d_factor"] = REFERENCE_D_FACTOR if out["variant"] == "reference" else default_d_factor(stats.irregularity())
    if out["variant"] == "reference" and out["resolution"] is None:
        out["resolution"] = stats.resolution(robust=False) or 1.0
    return out

def row_batches(index: spatial.SpatialIndex, rows: np.ndarray, params: dict):
    """Cube neighbourhoods of sorted ``rows`` (R,) with resolved ``params`` (see :func:`resolve`), batch by batch.

    Batches are :func:`hgjax.neighbours.spatial.batches` of the rows; each is built as soon as the
    previous one is consumed, reusing what the previous ones found (spacings of shared
    neighbours, the typical row width).

    Yields:
      (part, idx, scale, reach) per batch: part a slice of ``rows``; idx (r, W) int32
      sorted-frame indices by increasing distance (Chebyshev for "reference", Euclidean for
      "invariant"), padded with n, W the batch's fullest row; scale (r,) float64 voxel
      spacing d; reach (r,) the distance per axis within which every point the row used
      lies (cube or ball, and spacing estimate), inf where ``index`` holds LOCAL_K locations
      or fewer (no radius short of the whole cloud holds the estimate's neighbours).
    """
    rows = np.asarray(rows, dtype=np.int64)
    k = params["kernel_size"]
    invariant = params["variant"] == "invariant"
    # The invariant variant turns its cube into the point's local frame, so it queries the
    # ball that holds the cube in every orientation (radius sqrt(3) x the half-width).
    widen = np.sqrt(3.0) if invariant else 1.0
    factor = widen * k / 2 * params["d_factor"]
    max_count = MAX_COUNT if invariant else None
    norm = 2 if invariant else np.inf
    adaptive = params["resolution"] is None
    rk = np.full(index.n, np.nan) if adaptive else None
    start = 64 if adaptive else 32
    for part in spatial.batches(rows.size):
        if adaptive:
            # One query per batch serves the spacing (its first LOCAL_K + 1 columns) and the
            # ball (a prefix of each row; rows whose ball is longer are queried again).
            nearest = index.nearest(rows[part], min(max(start, LOCAL_K + 2), index.n))
            res, reach = spatial.local_spacing(index, rows[part], LOCAL_K, query=nearest, rk=rk)
            if index.n <= LOCAL_K:  # the estimate read fewer neighbours than the whole cloud may hold
                reach = np.full(reach.shape, np.inf)
        else:
            nearest, res, reach = None, params["resolution"], 0.0
        half = np.broadcast_to(factor * res, rows[part].shape)
        reach = np.maximum(reach, half)
        idx, half = index.cube(half, rows[part], capacity=start, max_count=max_count, norm=norm,
                               query=nearest if invariant else None)
        # Rows are in spatial order, so the next batch is alike: start it at this one's 95th
        # percentile count instead of doubling up from 32 again.
        start = int(np.percentile((idx < index.n).sum(axis=1), 95)) + 2
        yield part, idx, 2 / k * half / widen, reach

def tile_batches(index: spatial.SpatialIndex, rows: np.ndarray, params: dict):
    """:func:`row_batches` by the build's search: the host's, or with ``params["search"] == "jax"`` one
    batch of :func:`index_balls` (a tiled run's build)."""
    if params.get("search") == "jax":
        return iter([(slice(0, len(rows)), *index_balls(index, rows, params))])
    return row_batches(index, rows, params)


def index_balls(index: spatial.SpatialIndex, rows: np.ndarray, params: dict):
    """The cube neighbourhoods of sorted ``rows`` (R,) that :func:`row_batches` yields, by the traced search.

    The local spacing's (LOCAL_K + 1)-nearest search and the cube (or ball) query run over the
    whole index (:func:`hgjax.neighbours.backend.index_search`: the host's neighbour sets and
    distances bit for bit), and the spacing is :func:`hgjax.neighbours.spatial.spacing_of` of
    those distances, in the host's float64 operations: the rows, scales and reaches are the host's.

    Returns:
      (idx, scale, reach) as one batch of :func:`row_batches`: idx (R, W) int32, W the fullest row.
    """
    rows = np.asarray(rows, dtype=np.int64)
    n, k = index.n, params["kernel_size"]
    invariant = params["variant"] == "invariant"
    widen = np.sqrt(3.0) if invariant else 1.0
    factor = widen * k / 2 * params["d_factor"]
    if params["resolution"] is None:
        local_k = min(LOCAL_K, n - 1)
        if local_k < 1:
            res, reach = np.ones(n), np.zeros(n)
        else:
            near = backend.index_search(index, cells.traced_knn, local_k + 1)
            res, reach = spatial.spacing_of(near.reach[near.idx], near.reach)
        if n <= LOCAL_K:  # the estimate read fewer neighbours than the whole cloud may hold
            reach = np.full(n, np.inf)
    else:
        res, reach = params["resolution"], np.zeros(n)
    half = np.broadcast_to(factor * res, (n,))
    typical = np.sort(half[rows])[(rows.size - 1) * EDGE_QUANTILE // 100]
    max_count = MAX_COUNT if invariant else None
    found = backend.index_search(index, cells.within, radius=half, columns=max_count or FIRST_COLUMNS,
                                 metric="l2" if invariant else "linf", max_count=max_count,
                                 edge=cells.EDGE_MARGIN * typical)
    idx = found.idx[rows]
    idx = idx[:, :max(1, int((idx < n).sum(axis=1).max(initial=1)))]
    return idx, 2 / k * found.reach[rows] / widen, np.maximum(reach, half)[rows]


def build(points, *, variant: str = "invariant", d_factor: float | None = None, kernel_size: int = 3,
          resolution: float | None = None, dedupe: bool | None = None,
          capacity: int | None = None, search: str = "host", cell_slots: int | None = None,
          cell_edge=None) -> Neighbourhoods:
    """Cube neighbourhoods of HKC/HKF and the voxel spacing d of each point (host; jittable with ``search="jax"``).

    The ROI of point i is the axis-aligned cube of half-width k d_i / 2 (Fig. 2), with

    * ``variant="reference"``: d_i = 1.3 x the intrinsic resolution (REFERENCE.md: mean
      distance to the nearest other point), duplicates kept;
    * ``variant="invariant"`` (default): d_i = f x the point's local spacing s_i =
      1 / sqrt(areal density) estimated from its 16 nearest distinct points
      (:func:`hgjax.neighbours.spatial.local_spacing`), exact duplicates counted once, and f from
      the cloud's sampling irregularity (:func:`default_d_factor`: 1.1 on lattice-like
      clouds, 1.6 on random samples). The spacing, unlike the nearest-neighbour distance,
      means the same on grids and on random samples, and where the density changes the
      kernel follows it. Where a cube would still hold 256 points or more (a sparse point next
      to a much denser region), it shrinks to the Chebyshev distance of the point's 256th
      nearest point: every cube holds all its points (no truncation) and at most 255, so
      mixed densities never raise a capacity error. Exact duplicates and far outliers
      change nothing.

    Args:
      points: (N, 3) float32 or float64, N >= 2.
      variant: ``"invariant"`` or ``"reference"``.
      d_factor: d = d_factor x resolution (default: :func:`default_d_factor` for
        "invariant", 1.3 for "reference").
      kernel_size: odd k of the k x k x k kernel.
      resolution: a fixed resolution (spacing) for every point instead of the computed one.
      dedupe: count exact duplicates once (default: True for "invariant", False for
        "reference").
      capacity: fixed number of columns K (see :func:`hgjax.cube`); default automatic. With
        ``search="jax"`` under ``jit`` it sets a static shape: pass :func:`hgjax.capacity` of
        the cloud (or an eager build's ``idx.shape[-1]``); without it, 256 columns for
        "invariant" (a cube never holds more) and 128 for "reference" (a wider cube stops
        the program, naming the capacity it needs).
      search: ``"host"`` (SciPy's k-d tree; not jittable) or ``"jax"`` (the traced search,
        :func:`traced`: jit, vmap; the host's neighbour sets and ``scale``,
        every whole-cloud decision (d factor, resolution) traced too).
      cell_slots, cell_edge: the traced search's candidates read per step (static) and first
        cell edge (traced, or None from the data): speed settings, never limits.

    Returns:
      :class:`hgjax.Neighbourhoods` with ``scale`` = (N,) voxel spacing d_i.

    Raises:
      TypeError, ValueError: invalid arguments, N < 2, or a fixed capacity too small.

    Examples:
      >>> import numpy as np
      >>> from hgjax.neighbours import balls
      >>> nb = balls.build(np.random.default_rng(0).random((300, 3)))
      >>> nb.scale.shape, bool((nb.idx[:, 0] == np.arange(300)).all())
      ((300,), True)
    """
    search = _validate.check_choice(search, "search", backend.SEARCHES)
    if search == "jax":
        return _traced_build(points, build_params(variant=variant, d_factor=d_factor, kernel_size=kernel_size,
                                                           resolution=resolution, dedupe=dedupe),
                                      capacity, cell_slots, cell_edge)
    pts = _validate.check_points(points)
    params = build_params(variant=variant, d_factor=d_factor, kernel_size=kernel_size, resolution=resolution,
                          dedupe=dedupe)
    _validate.check_min_points(pts.shape[0], 2, "HKC/HKF")
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    index = spatial.SpatialIndex(spatial.local_frame(pts)[0], dedupe=params["dedupe"])
    resolved = resolve(params, spatial.sample_stats(index) if needs_stats(params) else None)
    scales = []

    def rows():
        for _, idx, scale, _ in row_batches(index, np.arange(index.n), resolved):
            scales.append(scale)
            yield idx

    idx = spatial.caller_rows(index, rows(), cap, what="cube")
    return spatial.assemble(pts, index, idx, np.concatenate(scales), params=params)


def cube(points, half_width, *, dedupe: bool = False, capacity: int | None = None) -> Neighbourhoods:
    """Axis-aligned cube neighbourhoods (Chebyshev distance < half_width), the ROI of HKC/HKF.

    Args:
      points: (N, 3) float32 or float64.
      half_width: half the cube side, > 0: a scalar or one per point (N,).
      dedupe: count exact duplicates once.
      capacity: columns of ``idx``. Default: the fullest cube's count rounded up to a power
        of two (at least 8), so nothing is ever truncated.

    Returns:
      Neighbourhoods with ``idx`` (N, K) int32 in the caller's order, padded with N, each
      row by increasing Chebyshev distance (the point itself first).

    Raises:
      ValueError: for invalid input, or when a cube holds more than a fixed ``capacity``
        (the message names the capacity needed).

    Examples:
      >>> import numpy as np, hgjax
      >>> nb = hgjax.cube(np.array([[0., 0, 0], [1, 0, 0], [5, 0, 0]]), 1.5)
      >>> (nb.idx < 3).sum(axis=1).tolist()
      [2, 2, 1]
    """
    pts = _validate.check_points(points)
    half = _validate.check_positive_array(half_width, "half_width", pts.shape[0])
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    index = spatial.SpatialIndex(spatial.local_frame(pts)[0], dedupe=dedupe)
    half_sorted = np.broadcast_to(half, (pts.shape[0],))[index.order]
    parts = (index.cube(half_sorted[part], part)[0] for part in spatial.batches(index.n))
    return spatial.assemble(pts, index, spatial.caller_rows(index, parts, cap, what="cube"))


def traced(points, *, metric: str, widen: float, kernel_size: int, d_factor, ramp, spacing, local_k: int,
         max_count: int | None, dedupe: bool, capacity: int | None, cell_slots: int | None, cell_edge,
         params: dict) -> spatial.Neighbourhoods:
    """Cube (``metric="linf"``) or ball (``"l2"``) neighbourhoods and their voxel spacing, traced.

    Args:
      points: (N, 3) float32 or float64 (a tracer under ``jit``), N >= 2.
      metric: ``"linf"`` (the axis-aligned cube) or ``"l2"`` (the ball) (static).
      widen: the radius is widen x k / 2 x d (static float; sqrt(3) for the ball).
      kernel_size: k (static).
      d_factor: d = d_factor x spacing: a float, or None for ``ramp`` of the irregularity.
      ramp: ((x0, x1), (y0, y1)): the factor y0 up to irregularity x0, y1 from x1, linear
        in between (:func:`hgjax.neighbours.balls.default_d_factor`).
      spacing: ``"local"``, ``"mean_other"`` or a fixed float (see the module docstring).
      local_k: neighbours of the local spacing (static).
      max_count: a row that holds this many points or more shrinks (static; None: never).
      dedupe: count exact duplicates once (static).
      capacity: columns K of ``idx`` (static) or None: eagerly the host's (the fullest row
        rounded up to a power of two, at least 8), under ``jit`` ``max_count`` or :data:`COLUMNS`.
      cell_slots: candidates the traced searches read per step (static; default
        :data:`hgjax.neighbours.backend.CELL_SLOTS`): speed only.
      cell_edge: their first cell edge (traced), or None for one from the data: speed only.
      params: build parameters recorded on the result (``search`` added); eagerly also the host
        build's parameters that count the columns. The columns are ``idx.shape[-1]``, not a
        parameter, so two eager builds stack (:func:`hgjax.stack_neighbourhoods`).

    Returns:
      :class:`hgjax.Neighbourhoods` with the host's ``idx`` (N, K) int32 padded with N,
      ``scale`` (N,) the voxel spacing d_i, ``overflow`` 0.

    Raises:
      ValueError: a fixed ``capacity`` smaller than the fullest row (as the host); under
        ``jit`` when the compiled program runs (:func:`hgjax.neighbours.backend.guard`).
    """
    p = jnp.asarray(points)
    n = p.shape[0]
    slots = backend.CELL_SLOTS if cell_slots is None else cell_slots
    statics = dict(metric=metric, widen=widen, kernel_size=kernel_size, d_factor=d_factor, ramp=ramp, spacing=spacing,
                   local_k=local_k, max_count=max_count, dedupe=dedupe, slots=slots)
    if _stream.is_traced(p):
        columns = capacity if capacity is not None else (max_count or COLUMNS)
        idx, scale, overflow, _ = _balls(p, cell_edge, columns=columns, spacing_k=None, **statics)
        local, lo = backend.traced_frame(p)
        return spatial.Neighbourhoods(local, idx, scale.astype(local.dtype), params=spatial.record({**params, "search": "jax"}),
                                      overflow=backend.guard(overflow), points_lo=lo)
    # Eagerly the same program, jitted once per setting: the spacing's k from the host's count of locations
    # (no switch over every k); the columns counted before it runs: max_count bounds a shrinking ball, else
    # the host's fullest cube (the same sets) does. Only a traced row wider than that would grow them.
    locations = len(np.unique(np.asarray(p), axis=0)) if dedupe else n  # as the search sees the points
    spacing_k = min(local_k, locations - 1) if isinstance(spacing, str) and spacing == "local" else None
    columns = capacity if capacity is not None else (max_count or build(points, **params).idx.shape[1])
    while True:
        idx, scale, overflow, width = _jitted_balls(columns=columns, spacing_k=spacing_k, **statics)(p, cell_edge)
        needed = int(overflow)
        if needed < 0:
            raise RuntimeError("the traced search could not cover some row within its passes")
        if needed == 0:
            break
        _validate.check_capacity(capacity, needed, "cube")
        columns = spatial.bucket(needed)
    width = int(width)
    _validate.check_capacity(capacity, width, "cube")
    cols = spatial.bucket(width) if capacity is None else capacity
    idx = np.asarray(idx)[:, :cols]
    idx = jnp.asarray(np.pad(idx, ((0, 0), (0, cols - idx.shape[1])), constant_values=n))
    local, lo = backend.host_frame(points)
    return spatial.Neighbourhoods(local, idx, scale.astype(local.dtype),
                                  params=spatial.record({**params, "search": "jax"}),
                                  overflow=jnp.zeros((), jnp.int32), points_lo=lo)


def _traced_build(points, params: dict, capacity, cell_slots, cell_edge) -> Neighbourhoods:
    """:func:`neighbourhoods` by the traced search: the cube (or ball) with every decision of :func:`resolve` traced."""
    pts = backend.checked_points(points)
    _validate.check_min_points(pts.shape[0], 2, "HKC/HKF")
    cap = None if capacity is None else _validate.check_int(capacity, "capacity", minimum=1)
    slots = None if cell_slots is None else _validate.check_int(cell_slots, "cell_slots", minimum=1)
    invariant = params["variant"] == "invariant"
    if params["resolution"] is not None:
        spacing = params["resolution"]
    else:
        spacing = "local" if invariant else "mean_other"
    d_factor = params["d_factor"]
    if d_factor is None and not invariant:
        d_factor = REFERENCE_D_FACTOR
    return traced(
        pts, metric="l2" if invariant else "linf", widen=np.sqrt(3.0) if invariant else 1.0,
        kernel_size=params["kernel_size"], d_factor=d_factor,
        ramp=(IRREGULARITY_RANGE, (REGULAR_D_FACTOR, IRREGULAR_D_FACTOR)), spacing=spacing, local_k=LOCAL_K,
        max_count=MAX_COUNT if invariant else None, dedupe=params["dedupe"], capacity=cap, cell_slots=slots,
        cell_edge=cell_edge, params=params)


@functools.lru_cache(maxsize=None)
def _jitted_balls(**statics):
    return jax.jit(functools.partial(_balls, **statics))


def _balls(p, cell_edge, *, metric: str, widen: float, kernel_size: int, d_factor, ramp, spacing, local_k: int,
           max_count: int | None, dedupe: bool, slots: int, columns: int, spacing_k: int | None):
    """(idx (N, columns) int32, scale (N,), overflow, width): the cubes or balls and their voxel spacing, pure JAX.

    ``spacing_k``: the local spacing's k when known (eagerly, from the host's count of
    locations), or None to pick it from the traced count (a ``lax.switch``). ``overflow``: 0,
    the columns the fullest row needs when more than ``columns``, or -1 (a row not covered);
    ``width``: the fullest row's count.
    """
    n = p.shape[0]
    x64 = bool(jax.config.jax_enable_x64)
    searches = _Searches(p, slots, cell_edge)
    # the spacing and the d factor
    near = None
    if isinstance(spacing, str) and spacing == "local":
        near = searches.nearest(local_k + 1, dedupe)
        res, res_lo = _local_spacing(p, near, local_k, dedupe, spacing_k, x64)
    elif isinstance(spacing, str):
        other = searches.nearest(2, False)
        res, res_lo = _mean_other(p, other, x64)
    else:
        res, res_lo = spacing, None
    if d_factor is None:
        distinct = near if near is not None and dedupe else searches.nearest(2, True)
        factor, factor_lo = _ramped(p, distinct, ramp, x64)
        base = widen * kernel_size / 2  # the host's (widen * k / 2) * d_factor
        if x64:
            factor, factor_lo = _exact.mul(jnp.float64(base), factor), None
        else:
            factor, factor_lo = _exact.pair_mul(*_exact.pair_const(base), factor, factor_lo)
    else:
        factor, factor_lo = widen * kernel_size / 2 * d_factor, None  # a Python float, as the host's
    radius, radius_lo = _times(factor, factor_lo, res, res_lo, x64)
    radius = jnp.broadcast_to(jnp.asarray(radius, jnp.float64 if x64 else jnp.float32), (n,))
    radius_lo = None if radius_lo is None else jnp.broadcast_to(radius_lo, (n,))
    found = searches.within(radius, radius_lo, columns, metric, dedupe, max_count)
    # scale d = (2 / k) x the radius used / widen, as the host
    used = found.reach
    if x64:
        scale = _exact.div(_exact.mul(2 / kernel_size, used), widen)
    else:
        shrunk = used != radius
        h = (jnp.where(shrunk, used, radius), jnp.where(shrunk, 0, 0 if radius_lo is None else radius_lo))
        scaled = _exact.pair_mul(*_exact.pair_const(2 / kernel_size), *h)
        scale = _p_round(_exact.pair_div(*scaled, *_exact.pair_const(widen)))
    return found.idx.astype(jnp.int32), lax.stop_gradient(scale), searches.overflow, found.columns_needed


class _Searches:
    """The build's traced searches, with one ``slots`` and (where given) one first cell edge, their
    overflow summed up: 0, the columns a ball needs, or -1 (a row not covered)."""

    def __init__(self, p, slots: int, edge):
        self.p, self.slots, self.edge = p, slots, edge
        self.overflow = jnp.zeros((), jnp.int32)

    def _run(self, query, *args, default_edge=None, **kwargs):
        edge = default_edge if self.edge is None else self.edge
        found = query(self.p, *args, slots=self.slots, edge=edge, **kwargs)
        wide = jnp.where(found.columns_needed > found.idx.shape[-1], found.columns_needed, 0)
        this = jnp.where(found.uncovered, -1, wide).astype(jnp.int32)
        self.overflow = jnp.where((self.overflow < 0) | (this < 0), -1, jnp.maximum(self.overflow, this))
        return found

    def nearest(self, k: int, dedupe: bool):
        return self._run(cells.traced_knn, k, dedupe=dedupe)

    def within(self, radius, radius_lo, columns: int, metric: str, dedupe: bool, max_count):
        # A default edge from most rows' radius, not the largest (a sparse point's ball would make every
        # block hold most of the cloud): the few rows it misses are searched again at a wider edge.
        n = radius.shape[0]
        typical = jnp.sort(lax.stop_gradient(radius))[(n - 1) * EDGE_QUANTILE // 100]
        return self._run(cells.within, radius, columns=columns, metric=metric, dedupe=dedupe,
                         max_count=max_count, radius_lo=radius_lo, default_edge=cells.EDGE_MARGIN * typical)


# ----------------------------------------------------------------------------- the host's statistics

def local_spacing(found: cells.Found):
    """HKC/HKF's per-point sample spacing, :func:`hgjax.neighbours.spatial.local_spacing`, from a traced kNN.

    s_i = sqrt(pi / k x mean over the k + 1 points j of row i of r_j^2), r_j the distance of
    point j's (k + 1)-th point (itself first), 1 where s_i = 0; with the same float64
    operations in the same order as the host (NumPy's pairwise mean), so under x64 the
    spacing is the host's to the last bit.

    Args:
      found: :func:`hgjax.neighbours.cells.traced_knn` of the cloud with k + 1 columns and ``dedupe=True`` (the host's
        ``LOCAL_K + 1`` = 17); the cloud must hold at least k + 1 distinct locations (the
        host then lowers k; this does not).

    Returns:
      (spacing, reach): (N,) each; reach the distance within which every point the estimate
      used lies (the row's own (k + 1)-th distance plus the largest of its neighbours').
      Padding rows (``count``) get spacing 1 and reach 0.

    Examples:
      >>> import numpy as np
      >>> from hgjax.neighbours import balls, cells
      >>> p = np.c_[np.mgrid[0:8, 0:8].reshape(2, -1).T, np.zeros(64)].astype(np.float32)
      >>> s, _ = balls.local_spacing(cells.traced_knn(p, 17, dedupe=True))
      >>> round(float(s[27]), 3)  # inside an 8 x 8 grid of spacing 1
      0.991
    """
    idx, rk = found.idx, found.reach
    n, width = idx.shape[-2], idx.shape[-1]
    k = width - 1
    real = idx[:, 0] < n
    near = jnp.where(real[:, None], rk[jnp.minimum(idx, n - 1)], 0)
    mean = _exact.div(_exact.numpy_sum(_exact.mul(near, near)), width)
    spacing = jnp.sqrt((math.pi / k) * mean)
    spacing = jnp.where(real & (spacing > 0), spacing, 1.0)
    reach = jnp.where(real, rk + jnp.max(near, axis=1), 0)
    return spacing, reach


def _sq_pairs(p, j):
    """The squared distance from every point to point ``j`` (N,) as a float32 pair (exact differences)."""
    return _sq_pairs_of(p, np.arange(p.shape[0]), j)


def _local_spacing(p, near, local_k: int, dedupe: bool, spacing_k: int | None, x64: bool):
    """(spacing, lo) (N,): :func:`hgjax.neighbours.spatial.local_spacing` of every point, k lowered to the other locations
    (``spacing_k`` when known, else from the traced count of locations)."""
    n = p.shape[0]
    if spacing_k is not None or not dedupe:
        return _spacing_k(p, near, min(local_k, n - 1) if spacing_k is None else spacing_k, x64)
    locations = jnp.sum(near.idx[:, 0] == jnp.arange(n, dtype=near.idx.dtype))
    branches = [lambda kk=kk: _spacing_k(p, near, kk, x64) for kk in range(local_k + 1)]
    return lax.switch(jnp.clip(locations - 1, 0, local_k), branches)


def _spacing_k(p, near, kk: int, x64: bool):
    """The spacing from the kk nearest other locations (the host's k = min(local_k, locations - 1))."""
    n = p.shape[0]
    if kk == 0:  # one location: the host's spacing 1
        one = jnp.ones(n, jnp.float64 if x64 else jnp.float32)
        return one, (None if x64 else jnp.zeros(n, jnp.float32))
    idx = near.idx[:, :kk + 1]
    if x64:
        found = dataclasses.replace(near, idx=idx, dist=near.dist[:, :kk + 1], reach=near.dist[:, kk])
        return local_spacing(found)[0], None
    sh, sl = _sq_pairs(p, idx[:, kk])  # r_j^2 of every point j
    safe = jnp.minimum(idx, n - 1)
    total = _exact.pair_sum(sh[safe], sl[safe])
    mean = _exact.pair_div(*total, *_exact.pair_const(kk + 1))
    sh2, sl2 = _exact.pair_sqrt(*_exact.pair_mul(*_exact.pair_const(math.pi / kk), *mean))
    ok = sh2 > 0
    return jnp.where(ok, sh2, 1.0), jnp.where(ok, sl2, 0.0)


def _sample_column(p, found, x64: bool):
    """(S,) (hi, lo) of the distance in column 1 of ``found`` (nearest other point) for the sampled ids."""
    ids = spatial.sample_ids(p.shape[0])
    if x64:
        return found.dist[ids, 1], None
    return _exact.pair_sqrt(*_sq_pairs_of(p, ids, found.idx[ids, 1]))


def _sq_pairs_of(p, rows, j):
    """Squared distances (float32 pairs) from the points ``rows`` (S,) to points ``j`` (S,)."""
    q = lax.stop_gradient(p).astype(jnp.float32)
    n = q.shape[0]
    valid = j < n
    hi, lo = _pair_keys(q[rows][:, None, :], q[jnp.minimum(j, n - 1)][:, None, :], "l2")
    return jnp.where(valid, hi[:, 0], jnp.inf), jnp.where(valid, lo[:, 0], 0)


def _mean_other(p, other, x64: bool):
    """The sample's mean nearest-other distance, 1.0 where it is 0 (:meth:`hgjax.neighbours.spatial.SampleStats.resolution`)."""
    d, lo = _sample_column(p, other, x64)
    s = d.shape[0]
    if x64:
        mean = _exact.div(_exact.numpy_sum(d), s)
        return jnp.where(mean > 0, mean, 1.0), None
    mh, ml = _exact.pair_div(*_exact.pair_sum(d, lo), *_exact.pair_const(s))
    ok = mh > 0
    return jnp.where(ok, mh, 1.0), jnp.where(ok, ml, 0.0)


def _ramped(p, distinct, ramp, x64: bool):
    """The d factor from the sample's irregularity (std / mean of nearest distinct distances) through ``ramp``."""
    (x0, x1), (y0, y1) = ramp
    d, lo = _sample_column(p, distinct, x64)
    s = d.shape[0]
    finite = jnp.isfinite(d[0])  # every sampled distance is finite, or none (a single location)
    d = jnp.where(finite, d, 0)
    if x64:
        mean = _exact.div(_exact.numpy_sum(d), s)
        x = d - mean
        std = jnp.sqrt(_exact.div(_exact.numpy_sum(_exact.mul(x, x)), s))
        irr = jnp.where(mean > 0, _exact.div(std, jnp.where(mean > 0, mean, 1)), 0)
        return linear_ramp(irr, ramp), None
    lo = jnp.where(finite, lo, 0)
    mean = _exact.pair_div(*_exact.pair_sum(d, lo), *_exact.pair_const(s))
    x = _exact.pair_add(d, lo, -mean[0], -mean[1])
    var = _exact.pair_div(*_exact.pair_sum(*_exact.pair_mul(*x, *x)), *_exact.pair_const(s))
    std = _exact.pair_sqrt(*var)
    ok = mean[0] > 0
    irr = _exact.pair_div(*std, jnp.where(ok, mean[0], 1), jnp.where(ok, mean[1], 0))
    irr = (jnp.where(ok, irr[0], 0), jnp.where(ok, irr[1], 0))
    x0h, x0l = _exact.pair_const(x0)
    t = _exact.pair_div(*_exact.pair_add(*irr, -x0h, -x0l), *_exact.pair_const(x1 - x0))
    t = _p_clip01(t)
    return _exact.pair_add(*_exact.pair_const(y0), *_exact.pair_mul(*t, *_exact.pair_const(y1 - y0)))


def linear_ramp(x, ramp):
    """``ramp`` = ((x0, x1), (y0, y1)) at x: y0 up to x0, y1 from x1, linear in between, traced, in the
    float64 operations of :func:`hgjax.neighbours.balls.default_d_factor` (its bits under x64)."""
    (x0, x1), (y0, y1) = ramp
    x = jnp.asarray(x)
    t = jnp.clip(_exact.div(x - x0, jnp.asarray(x1 - x0, x.dtype)), 0.0, 1.0)
    return y0 + _exact.mul(t, jnp.asarray(y1 - y0, x.dtype))


def _times(a, a_lo, b, b_lo, x64: bool):
    """a x b (the radius factor x the spacing), as the host's float64 product or a float32 pair."""
    if x64:
        if isinstance(a, float) and isinstance(b, float):
            return np.float64(a) * np.float64(b), None
        return _exact.mul(jnp.asarray(a, jnp.float64), jnp.asarray(b, jnp.float64)), None
    if isinstance(a, float) and isinstance(b, float):
        return _exact.pair_const(np.float64(a) * np.float64(b))
    pa = _exact.pair_const(a) if isinstance(a, float) else (a, jnp.zeros_like(a) if a_lo is None else a_lo)
    pb = _exact.pair_const(b) if isinstance(b, float) else (b, jnp.zeros_like(b) if b_lo is None else b_lo)
    return _exact.pair_mul(*pa, *pb)


# ----------------------------------------------------------------------------- float32 pairs

def _p_clip01(a):
    below, above = a[0] < 0, a[0] > 1
    return (jnp.where(below, 0, jnp.where(above, 1, a[0])), jnp.where(below | above, 0, a[1]))


def _p_round(a):
    return a[0] + a[1]
