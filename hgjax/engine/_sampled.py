"""A sampler in tiles, on Dask workers or from a survey's point count (:class:`hgjax.Sampler`).

A sampler that reads only the point count (``uniform``: each point's draw from the key and its
global id) is sampled from it (``ids``). One that declares its tiles (:class:`hgjax._method.SampleTiles`,
``voxel``) gives each tile's candidates; the engine ranks them all at once by (value, global id)
from per-tile histograms (:func:`hgjax.engine.select.top_pairs`), exactly as in one process.
"""

from __future__ import annotations

import numpy as np

from hgjax import _validate
from hgjax._method import Sampler
from hgjax.engine import _grid, _plan, _runners, select
from hgjax.neighbours import spatial

__all__ = ["sample"]


def sample(entry: Sampler, points, ratio, tile, client, key, params: dict) -> np.ndarray:
    """A sampler's indices: from the point count, its tiles given a tile, a client or a lazy source, else its
    own function on the whole cloud."""
    keyed = {"key": key} if entry.needs_key else {}
    spread = tile is not None or client is not None or isinstance(points, _grid.Source)
    if entry.ids is not None and spread:
        n = points.n if isinstance(points, _grid.Source) else _validate.check_points(points).shape[0]
        return entry.ids(n, ratio, **keyed, **params)
    if entry.tiles is not None and spread:
        return _tiled(entry, points, ratio, tile, client, params)
    return entry.draw(_validate.check_points(points), ratio, key, **params)


def _tiled(entry: Sampler, points, ratio, tile, client, params: dict) -> np.ndarray:
    """The m highest ranked candidates of every tile (every candidate for ``ratio=None``), and where there
    are fewer than m, the other points after them in index order."""
    pts = _validate.check_points(points)
    n = pts.shape[0]
    m = None if ratio is None else _validate.n_keep(n, _validate.check_ratio(ratio))
    context = entry.tiles.plan(pts, m, **params)
    bmin, bmax = _plan.bounds(pts)
    origin = spatial.frame_origin(bmin, bmax, np.float64)
    source = points if isinstance(points, np.memmap) else None  # travels to Dask workers as its file
    cloud = _grid.Cloud(pts, origin, bmin - origin, bmax - origin, tile, source)
    runner = _runners.runner(cloud, client, 1)  # a task holds its tile's points, no neighbours
    parts = runner.tiles(_part, entry.tiles, context)
    v = sum(runner.gather(runner.each(_count, parts)))
    ranked = select.top_pairs(parts, v if m is None else min(m, v), run=runner.run(parts))
    if m is None or m <= v:
        return ranked
    candidates = np.concatenate([g for _, g in runner.gather(parts)])
    return np.concatenate([ranked, np.setdiff1d(np.arange(n), candidates)])[:m].astype(np.int64)


def _part(cloud: _grid.Cloud, cell, tiles, context) -> tuple[np.ndarray, np.ndarray]:
    """(order keys, global ids) of one tile's candidates."""
    gids, _, core = cloud.gather(cell, tiles.halo(context))
    values, rows = tiles.part(np.asarray(cloud.points[gids], dtype=np.float64), core, context)
    return select.order_keys(values, largest=True), gids[rows]


def _count(part) -> int:
    return int(part[1].size)
