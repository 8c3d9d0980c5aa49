"""The plan: every whole-cloud decision of a run, made once and passed to every tile.

The frame origin (the centre of the bounding box, an exact min / max reduction), the number
kept, and the build parameters that depend on the cloud (HKC/HKF's ``d_factor`` from the
sampling irregularity, the reference resolution), resolved from the nearest distances of a
seeded sample of global ids (:func:`hgjax.neighbours.spatial.sample_ids`) gathered from the tiles
that own them (:func:`base`, :func:`resolved`).
"""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np

from hgjax.engine import _grid, _runners
from hgjax.neighbours import spatial

__all__ = ["Plan", "base", "gathered", "resolved"]

HALO_SPACINGS = 2  # the first halo, in mean sample spacings times sqrt(K) per k-nearest radius reached


@dataclasses.dataclass(frozen=True)
class Plan:
    """Every whole-cloud decision of one run, made once and passed to every tile.

    Attributes:
      method: the scoring method.
      n: number of points N; m: number kept, ceil(ratio N).
      origin: (3,) float64 frame origin (the bounding box's centre); coordinates reach the
        host index as ``points - origin`` in float64.
      lo, hi: (3,) float64 bounds of the cloud in that frame.
      tile: tile edge in the points' units, or None for one tile.
      dtype: the kernels' float dtype.
      build: resolved build parameters (nothing left to decide per tile).
      score: score parameters.
      halo: the first halo width tried around each tile.
      tiling: the method's :class:`hgjax._method.Tiling` (not recorded).
    """

    method: str
    n: int
    m: int
    origin: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    tile: float | None
    dtype: np.dtype
    build: dict
    score: dict
    halo: float
    tiling: object = dataclasses.field(default=None, repr=False, compare=False)

    def record(self) -> dict:
        """The plan as JSON values (arrays as lists, the dtype by name), as a survey's manifest holds it."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "tiling"}
        fields["dtype"] = np.dtype(self.dtype).name
        return json.loads(json.dumps(fields, default=jsonable))


def base(points, m: int, entry, tile: float | None, params: dict, client=None) -> tuple[Plan, _grid.Cloud]:
    """The plan before any decision that needs neighbours, and the tiled cloud (a lazy source's census on ``client``).

    Args:
      points: validated (N, 3) points (an ``np.memmap`` streams from disk), or a :class:`_grid.Source`.
      m: the number kept.
      entry: the scoring method (:class:`hgjax.Method`); its ``tiling`` validates ``params``.
      tile: validated tile edge, or None for one tile.
    """
    if isinstance(points, _grid.Source):
        n, (bmin, bmax), dtype = points.n, points.bounds(), spatial.working_dtype(np.float64)
    else:
        n, (bmin, bmax), dtype = points.shape[0], bounds(points), spatial.working_dtype(points.dtype)
    build, score = entry.tiling.params(n, params)
    origin = spatial.frame_origin(bmin, bmax, dtype)  # ValueError where dtype cannot represent the cloud
    lo, hi = bmin - origin, bmax - origin
    if isinstance(points, _grid.Source):
        cloud = points.cloud(origin, lo, hi, tile, client)
    else:
        cloud = _grid.Cloud(points, origin, lo, hi, tile, points if isinstance(points, np.memmap) else None)
    # The first halo: a few k-nearest radii per radius a neighbourhood reaches (Tiling.reach) at the
    # mean density of the occupied tiles (a surface crossing a cube of edge t with n points has a
    # spacing of about t / sqrt(n)).
    k, radii = entry.tiling.reach(build)
    spacing = 0.0 if tile is None else tile * np.sqrt(len(cloud.occupied()) / n)
    halo = HALO_SPACINGS * radii * spacing * np.sqrt(k)
    return Plan(entry.name, n, m, origin, lo, hi, tile, dtype, build, score, halo=float(halo), tiling=entry.tiling), cloud


def resolved(plan_: Plan, runner: _runners.Here) -> Plan:
    """The plan with the build parameters that depend on the seeded sample (SampleStats) resolved,
    and the first halo the resolved parameters need (:attr:`hgjax._method.Passes.reach`).

    Where float64 points are cast to float32 (:func:`hgjax.neighbours.spatial.working_dtype`), the same
    sample's finest spacing judges the cast (a :class:`hgjax.PrecisionWarning` where it loses
    it): the statistics the resolution gathered, else gathered for it from the tiles' indices,
    which a run in this process keeps for its scoring pass.
    """
    held = []

    def stats() -> spatial.SampleStats:
        if not held:
            held.append(sample_stats(runner, plan_))
        return held[0]

    tiling, resolved_ = plan_.tiling, plan_
    if tiling.resolve is not None:
        resolved_ = dataclasses.replace(plan_, build=tiling.resolve(dict(plan_.build), stats))
    if tiling.passes is not None:  # the first halo: just wider than the reach its tiles verify
        reach = tiling.passes.reach(resolved_.build)
        resolved_ = dataclasses.replace(resolved_, halo=max(resolved_.halo, reach * (1 + 1e-3)))
    wide = getattr(getattr(runner.cloud, "points", None), "dtype", np.float64)  # a lazy Source reads float64
    extent = float(np.max(np.abs([plan_.lo, plan_.hi])))
    spatial.working_dtype(wide, extent=extent, spacing=lambda: spatial.finest_spacing(stats().distinct))
    return resolved_


def bounds(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis float64 min and max, one chunk at a time (an exact reduction, in the points' dtype)."""
    bounds = [spatial.axis_bounds(pts[s:s + _grid.PASS_ROWS]) for s in range(0, pts.shape[0], _grid.PASS_ROWS)]
    return np.min([lo for lo, _ in bounds], axis=0), np.max([hi for _, hi in bounds], axis=0)


def sample_stats(runner: _runners.Here, plan_: Plan) -> spatial.SampleStats:
    """:class:`hgjax.neighbours.spatial.SampleStats` of the seeded sample (:func:`hgjax.neighbours.spatial.sample_ids`), from the tiles that own it."""
    wanted = spatial.sample_ids(plan_.n)
    cells = runner.cloud.owners(wanted)
    found = {}
    for part in runner.gather(runner.tiles(tile_stats, plan_, wanted, cells=cells)):
        found.update(part)
    distinct, other, offsets, valid = (np.array([found[g][i] for g in wanted.tolist()]) for i in range(4))
    return spatial.SampleStats(distinct.astype(np.float64), other.astype(np.float64),
                               offsets.reshape(-1, spatial.SAMPLE_K, 3), valid.reshape(-1, spatial.SAMPLE_K))


def tile_stats(cloud: _grid.Cloud, cell, plan_: Plan, wanted: np.ndarray) -> dict:
    """{gid: (distinct, other, offsets, valid)} of the sampled core points of one tile (:class:`hgjax.neighbours.spatial.SampleStats`)."""
    halo = plan_.halo
    while True:
        gids, x, core, index = cloud.indexed(cell, halo, plan_.build["dedupe"])
        mine = gids[core & np.isin(gids, wanted)]
        pos = np.searchsorted(gids, mine)
        distinct, other = spatial.nearest_distances(index, index.row[pos])
        offsets, valid, near = spatial.sample_offsets(index, index.row[pos])
        reach = np.maximum(np.where(np.isfinite(distinct), distinct, np.inf), near)
        if cloud.covers(cell, halo, x[pos], reach):
            return {int(g): (d, o, f, v) for g, d, o, f, v in zip(mine, distinct, other, offsets, valid)}
        halo *= 2


def gathered(runner: _runners.Here, parts, plan_: Plan) -> np.ndarray:
    """(N,) scores of every point, in the working dtype, gathered from the tiles' (gids, scores) parts."""
    scores = np.empty(plan_.n, dtype=plan_.dtype)
    for gids, values in runner.gather(parts):
        scores[gids] = values
    return scores


def jsonable(value):
    """``value`` as JSON data: a key by its data, arrays as lists, anything else by its repr."""
    if isinstance(value, jax.Array) and jax.dtypes.issubdtype(value.dtype, jax.dtypes.prng_key):
        return np.asarray(jax.random.key_data(value)).tolist()
    if isinstance(value, (np.ndarray, jax.Array, np.generic)):
        return np.asarray(value).tolist()
    return repr(value)
