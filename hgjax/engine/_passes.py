"""Two passes over the tiles with a global reduction between them (:class:`hgjax._method.Passes`).

A method whose tiles are not independent rows (GFR: the weights of its graph come from moments
over the whole cloud) declares a first pass, a reduction and a second pass; :func:`scores` runs
them on any runner and decides where each tile's state waits between the passes:

* where it was made: on the Dask worker that ran the tile (only the summaries travel), or in
  this process up to :data:`hgjax.engine._runners.KEEP_POINTS` points (:meth:`Here.holds`);
* else on disk, in a private temporary directory (``tempfile``'s, e.g. ``TMPDIR``), so that
  memory stays bounded by a tile; a tile whose state the disk has no room for (the write fails,
  or leaves less free space than it took) is made again in the second pass. The scores are the
  same either way.
"""

from __future__ import annotations

import os
import pickle
import shutil
import tempfile

import numpy as np

from hgjax.engine import _grid

__all__ = ["scores"]


def scores(runner, plan, stream: dict) -> list:
    """Every tile's (gids, scores) of the method's two passes (``plan.tiling.passes``)."""
    passes = plan.tiling.passes
    if runner.holds():
        tiles = runner.tiles(first, plan)
        total = passes.reduce(runner.gather(runner.each(summary, tiles, plan)))
        return runner.each(second, tiles, plan, total, stream)
    with tempfile.TemporaryDirectory(prefix="hgjax-tiles-") as spill:
        total = passes.reduce(runner.tiles(spilled_first, plan, spill))
        return runner.tiles(spilled_second, plan, total, stream, spill)


def first(cloud: _grid.Cloud, cell, plan) -> tuple:
    """(gids, core, index, rows, state) of one tile: its first pass on a halo verified to hold the method's reach."""
    passes = plan.tiling.passes
    reach = passes.reach(plan.build)
    gids, core, index, rows, _ = _grid.covered(cloud, cell, plan.halo, plan.build["dedupe"],
                                               lambda index, rows: (None, np.full(rows.size, reach)))
    return gids, core, index, rows, passes.first(index, rows, plan)


def summary(tile: tuple, plan):
    """What the reduction takes of a tile's state."""
    return plan.tiling.passes.summary(tile[-1])


def second(tile: tuple, plan, total, stream: dict) -> tuple[np.ndarray, np.ndarray]:
    """(gids, scores) of a tile's core points: its second pass, given the reduction's ``total``."""
    gids, core, index, rows, state = tile
    values = plan.tiling.passes.second(index, rows, state, plan, total, stream)
    return gids[core], _grid.per_point(index, rows, core, values)


def _path(spill: str, cell) -> str:
    return os.path.join(spill, "_".join(map(str, cell)) + ".pickle")


def spilled_first(cloud: _grid.Cloud, cell, plan, spill: str):
    """A tile's summary; the tile goes to ``spill`` where the disk keeps at least as much room as it takes."""
    tile = first(cloud, cell, plan)
    path = _path(spill, cell)
    try:
        with open(path, "wb") as f:
            pickle.dump(tile, f, protocol=pickle.HIGHEST_PROTOCOL)
            size = f.tell()
        if shutil.disk_usage(spill).free < size:
            os.remove(path)
    except OSError:
        if os.path.exists(path):
            os.remove(path)
    return summary(tile, plan)


def spilled_second(cloud: _grid.Cloud, cell, plan, total, stream: dict, spill: str):
    """:func:`second` of a tile read back from ``spill`` (and removed there), or made again."""
    path = _path(spill, cell)
    if not os.path.exists(path):
        return second(first(cloud, cell, plan), plan, total, stream)
    with open(path, "rb") as f:
        tile = pickle.load(f)
    os.remove(path)
    return second(tile, plan, total, stream)
