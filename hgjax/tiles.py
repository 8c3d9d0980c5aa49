"""Tiled resampling: the same indices as one process, whatever the tiles and wherever they run.

:func:`resample` cuts the cloud with a fixed global grid of cubes of edge ``tile`` and gives
the same indices, in the same order, as :func:`hgjax.resample` on the whole cloud
(``tile=None`` is one tile, and is what :func:`hgjax.resample` runs). Both are the engine
(:mod:`hgjax.engine`): every whole-cloud decision made once in a :class:`Plan`; each tile
scored on its core points with a verified halo (:func:`tile_scores`); the kept set is the
top ceil(ratio N) by (score, global id) over the whole cloud, exactly, from per-tile
histograms of order-preserving integer keys (:mod:`hgjax.engine` says how).

Each tile is a pure function of its points and the plan, and only per-tile summaries and
scores leave it, so tiles run in this process or as Dask tasks (``client``). A method says
whether and how it tiles (its ``tiling``); those that need the whole cloud at once (PCA-AC's
Ward clustering of all scores, ``fps``, GFR's reference radius) run with ``tile=None`` and are
refused with a tile size. Files as one cloud: :func:`hgjax.survey.resample_files`.
"""

from __future__ import annotations

from hgjax import engine
from hgjax._method import Method
from hgjax.engine import Plan, tile_scores

__all__ = ["TILED", "Plan", "plan", "resample", "tile_scores"]

TILED = tuple(sorted(name for name, entry in engine.METHODS.items() if entry.refused({}) is None))
"""The methods that run in tiles with their default parameters."""


def plan(points, ratio: float, *, method: str, tile: float | None = None, client=None,
         **params) -> tuple[Plan, engine.Cloud]:
    """Resolve every whole-cloud decision of a tiled run (host, or a Dask client's workers).

    Args:
      points: (N, 3) float32 or float64 array (an ``np.memmap`` streams from disk), or a lazy
        source (:class:`hgjax.engine._grid.Source`).
      ratio: fraction kept, in (0, 1].
      method: a scoring method (not the samplers); one outside :data:`TILED` (PCA-AC) only
        as one tile.
      tile: tile edge (> 0) in the points' units, or None for one tile.
      client: a ``dask.distributed.Client`` that computes the sample's nearest distances, or None.
      **params: the method's build and score parameters.

    Returns:
      (plan, cloud): the :class:`Plan` and the tiled cloud it was made for.

    Raises:
      ValueError: a sampler, or a ``tile`` or ``client`` for a method refused in tiles;
        TypeError, ValueError: invalid arguments.
    """
    entry = engine.entry(method)
    if not isinstance(entry, Method):
        raise ValueError(f"method {method!r} has no tiled plan; expected one of"
                         f" {sorted(m for m, e in engine.METHODS.items() if isinstance(e, Method))}")
    tile = engine.checked_tile(entry, params, tile, client)
    plan_, runner = engine.planned(points, ratio, entry, tile, params, client)
    return plan_, runner.cloud


def resample(points, ratio: float, *, method: str = engine.DEFAULT, tile: float | None = None, client=None, key=None,
             return_scores: bool = False, on_stage=None, **params):
    """Indices of the ceil(ratio N) points a method keeps, computed tile by tile.

    The same indices, in the same order, as :func:`hgjax.resample` on the whole cloud,
    whatever ``tile`` is and wherever the tiles run (module docstring); with ``tile=None``
    and no client it is :func:`hgjax.resample`. Memory is bounded by a tile and its halo,
    not by N (scores aside: 12-16 bytes per point; and up to ``KEEP_POINTS`` points, the
    tiles' host indices, kept between the sample-statistics and scoring passes), so an
    ``np.memmap`` of 1e8 points streams from disk. Above ``KEEP_POINTS``, GFR writes each
    tile's graph to a temporary directory between its two passes (``tempfile``'s; about
    430 bytes per point on a surface) where the disk has room, and builds it again where not.

    Args:
      points: (N, 3) float32 or float64 (NumPy, JAX or ``np.memmap``); never modified.
      ratio: fraction kept, in (0, 1].
      method: a key of :data:`hgjax.METHODS`.
      tile: tile edge (> 0) in the points' units, or None (one tile).
      client: a ``dask.distributed.Client``: each tile is one pure task on its workers,
        scores stay there and only per-tile summaries and kept ids travel (extra
        ``distributed``); None runs the tiles one after another in this process.
      key: ``jax.random`` key of the random methods.
      return_scores: also return every point's score (gathered to this process).
      on_stage: ``on_stage(name, seconds)`` as each stage ends (:func:`hgjax.resample`).
      **params: the method's parameters (as :func:`hgjax.resample`), and ``chunk_size``,
        ``progress``.

    Returns:
      (M,) int64 unique indices, M = ceil(ratio N), highest keep priority first, ties by index;
      with ``return_scores``, (indices, scores) as :func:`hgjax.resample`.

    Raises:
      TypeError, ValueError: invalid arguments, or a method that cannot be tiled given a tile.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = hgjax.eval.box_union_cloud(seed=0, n_points=4000).points
      >>> a = hgjax.tiles.resample(pts, 0.2, method="ea", tile=0.5)
      >>> bool((a == hgjax.resample(pts, 0.2, method="ea")).all())
      True
    """
    done = engine.run(points, ratio, method=method, tile=tile, client=client, key=key, return_scores=return_scores,
                      on_stage=on_stage, params=params)
    return (done.idx, done.scores) if return_scores else done.idx
