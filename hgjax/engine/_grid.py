"""The tiled grid: a cloud cut into tiles, and each tile scored on its core points with a verified halo.

Generic machinery of :mod:`hgjax.engine`; it knows no method by name: what a method needs is
its :class:`hgjax.Method`'s ``tiling`` (:class:`hgjax._method.Tiling`).

A point belongs to exactly one tile, the cell ``floor((x - lo) / tile)`` of the grid anchored at
the cloud's minimum corner (half-open ``[lo, hi)`` ownership) (:class:`Cloud`). A tile is scored
on its core points with the points of a halo around it (:func:`tile_scores`). The halo is
verified, not guessed: every core neighbourhood (its k-nearest radius, its cube, the
neighbourhoods its spacing estimate read) must lie inside the tile's box; otherwise the tile is
redone with twice the halo (:func:`covered`). Neighbour ties are broken by (distance, global id)
and each neighbourhood's offsets are rounded to the working dtype from float64 coordinates, so a
core point's score has the same bits in every tile that can hold its neighbourhood. A halo reads
only the sub-cells of the neighbouring tiles that meet its box, and a tile is indexed once for
the sample statistics and its scores (in this process, up to
:data:`hgjax.engine._runners.KEEP_POINTS` points).
"""

from __future__ import annotations

import numpy as np

from hgjax import _stream
from hgjax.neighbours import spatial

__all__ = ["Cloud", "Source", "covered", "per_point", "tile_scores"]

MAX_TILES = 1 << 31  # grid cells of a tiled cloud (its (tile, sub-cell) keys stay within 64 bits)
SUB = 16  # a tile's members are grouped in SUB^3 sub-cells, so that a halo reads slabs of its neighbours
PASS_ROWS = 1 << 20  # points per chunk of a pass over the whole cloud


def grid_shape(lo: np.ndarray, hi: np.ndarray, tile: float) -> tuple:
    """The number of tiles of edge ``tile`` along each axis of the box [lo, hi].

    Raises:
      ValueError: the grid would have more than MAX_TILES cells (``tile`` too small for the extent).
    """
    along = np.floor((hi - lo) / tile) + 1  # float: no integer overflow for any tile
    if float(np.prod(along)) > MAX_TILES:
        raise ValueError(f"tile={tile!r} cuts the cloud's extent {(hi - lo).tolist()} into {float(np.prod(along)):.3g}"
                         f" tiles ({' x '.join(f'{a:.3g}' for a in along)}); at most {MAX_TILES}: pass a larger tile")
    return tuple(int(c) for c in along)


def stable_order(key: np.ndarray, top: int) -> np.ndarray:
    """(n,) int64 permutation that sorts the unsigned integer ``key`` (n,), all < ``top``, equal keys in index order.

    A least-significant-digit radix sort in 16-bit digits: NumPy's stable argsort of 16-bit
    integers is a counting sort, linear in n, so a key of up to 32 bits costs two passes.
    """
    order = np.argsort(key.astype(np.uint16), kind="stable")
    for shift in range(16, max(1, int(top - 1).bit_length()), 16):
        order = order[np.argsort((key >> shift).astype(np.uint16)[order], kind="stable")]
    return order


class Cloud:
    """Points by global id, and the global ids of each tile (host; the points are never copied whole).

    ``members[cell]`` holds a tile's global ids grouped by its SUB^3 sub-cells (ascending
    within each), ``subs[cell]`` the (S, 3) coordinates of its S occupied sub-cells and their
    (S + 1,) starts in it, and ``grid`` the (T, 3) occupied cells in grid order: a halo reads
    only the sub-cells of its neighbours that meet its box. One radix sort of each point's
    (tile, sub-cell) key orders the whole cloud. ``keep`` (set by the runner) keeps
    every tile's host index once built, instead of only the last one, until :meth:`release`.
    """

    progress = False  # a survey reports each finished tile on stderr (:class:`hgjax.engine._runners.Ticker`)

    def __init__(self, points: np.ndarray, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 tile: float | None, source=None):
        self.points, self.origin, self.lo, self.hi, self.tile = points, origin, lo, hi, tile
        self.source = source  # the caller's array (an np.memmap is pickled as its file name)
        self.keep, self._indices = False, {}
        self.n = n = points.shape[0]
        if tile is None:
            self.shape, self.members, self.subs = (1, 1, 1), {(0, 0, 0): np.arange(n, dtype=np.int64)}, {}
            self.grid = np.zeros((1, 3), np.int64)
            return
        self.shape = grid_shape(lo, hi, tile)
        per_tile = SUB ** 3
        top = int(np.prod(self.shape)) * per_tile
        key = np.empty(n, dtype=np.uint32 if top <= 1 << 32 else np.uint64)  # (tile, sub-cell) of each point
        for s in range(0, n, PASS_ROWS):  # one chunk of the cloud at a time
            x = np.asarray(points[s:s + PASS_ROWS], dtype=np.float64) - origin
            c = self.cells(x)
            key[s:s + PASS_ROWS] = (np.ravel_multi_index(c.T, self.shape) * per_tile
                                    + np.ravel_multi_index(self.subcells(x, c).T, (SUB,) * 3))
        order = stable_order(key, top)  # by tile, then sub-cell, then ascending global id
        key = key[order]
        firsts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])  # the first point of each occupied sub-cell
        runs = key[firsts]
        tiles_of, sub_codes = runs // per_tile, (runs % per_tile).astype(np.int64)
        del key
        heads = np.flatnonzero(np.r_[True, tiles_of[1:] != tiles_of[:-1]])  # each tile's first sub-cell
        ends = np.r_[heads[1:], runs.size]
        self.members, self.subs = {}, {}
        for h, e in zip(heads.tolist(), ends.tolist()):
            s, t = int(firsts[h]), int(firsts[e]) if e < runs.size else n
            cell = tuple(int(i) for i in np.unravel_index(int(tiles_of[h]), self.shape))
            at = np.stack(np.unravel_index(sub_codes[h:e], (SUB,) * 3), axis=1)
            self.members[cell], self.subs[cell] = order[s:t], (at, np.r_[firsts[h:e], t] - s)  # views of one array
        self.grid = np.array(list(self.members), dtype=np.int64).reshape(-1, 3)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__, keep=False, _indices={})
        if self.source is not None and self.source.filename:  # travels as its file, not its bytes
            m = self.source
            state["points"] = state["source"] = (m.filename, m.dtype.str, m.offset, m.shape)
        return state

    def __setstate__(self, state: dict) -> None:
        if isinstance(state.get("points"), tuple):
            filename, dtype, offset, shape = state["points"]
            state["points"] = state["source"] = np.memmap(filename, dtype=dtype, mode="r", offset=offset, shape=shape)
        self.__dict__.update(state)

    def occupied(self) -> list:
        """The cells that own at least one point, in grid order."""
        return list(self.members)

    def core_size(self, cell) -> int:
        """The number of points ``cell`` owns."""
        return int(self.members[cell].size)

    def owners(self, wanted: np.ndarray) -> list:
        """The cells that own at least one of the global ids ``wanted``."""
        return [cell for cell, core in self.members.items() if np.isin(core, wanted).any()]

    def indexed(self, cell, halo: float, dedupe: bool):
        """(gids, x, core, index) of :meth:`gather` with a host index over it, reused until released.

        One index is held (the last built), or one per tile while ``keep`` is set.
        """
        key = (None if self.tile is None else halo, dedupe)
        held = self._indices.get(cell)
        if held is None or held[0] != key:
            if not self.keep:
                self._indices.clear()
            gids, x, core = self.gather(cell, halo)
            held = self._indices[cell] = (key, (gids, x, core, spatial.SpatialIndex(x, dedupe=dedupe, gid=gids)))
        return held[1]

    def release(self, cell) -> None:
        """Forget the index held for ``cell``."""
        self._indices.pop(cell, None)

    def frame(self, gids: np.ndarray) -> np.ndarray:
        """(R, 3) float64 coordinates of ``gids`` minus the plan's origin."""
        return np.asarray(np.take(self.points, gids, axis=0), dtype=np.float64) - self.origin

    def cells(self, x: np.ndarray) -> np.ndarray:
        """(R, 3) int64 grid cell owning each point of frame coordinates ``x``."""
        c = np.floor((x - self.lo) / self.tile).astype(np.int64)
        return np.clip(c, 0, np.array(self.shape) - 1, out=c)

    def box(self, cell, halo: float) -> tuple[np.ndarray, np.ndarray]:
        """The half-open box [lo, hi) of ``cell`` grown by ``halo``, in frame coordinates."""
        if self.tile is None:
            return self.lo - halo, self.hi + halo
        c = np.asarray(cell, dtype=np.float64)
        return self.lo + c * self.tile - halo, self.lo + (c + 1) * self.tile + halo

    def subcells(self, x: np.ndarray, cell) -> np.ndarray:
        """(R, 3) int64 sub-cell of ``cell`` (R, 3) or (3,) nearest each point of frame coordinates ``x``
        (R, 3) or (3,) (clipped to the tile).

        Non-decreasing in each coordinate, so the sub-cells of a box's corners bound those of its points.
        """
        at = np.floor((x - self.lo) * (SUB / self.tile)).astype(np.int64) - SUB * np.asarray(cell, dtype=np.int64)
        return np.clip(at, 0, SUB - 1, out=at)

    def slab(self, cell, first: np.ndarray, last: np.ndarray) -> np.ndarray:
        """Global ids of the sub-cells of ``cell`` from ``first`` to ``last`` (3,) (:meth:`subcells`), inclusive."""
        at, starts = self.subs[cell]
        ids = self.members[cell]
        hit = np.flatnonzero(((at >= first) & (at <= last)).all(axis=1))
        return np.concatenate([ids[starts[i]:starts[i + 1]] for i in hit.tolist()] or [ids[:0]])

    def gather(self, cell, halo: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(gids (n,) ascending, frame coordinates (n, 3), core mask (n,)) of a tile and its halo."""
        core = self.members[cell]
        if self.tile is None:  # the whole cloud, read in one pass
            return core, np.subtract(self.points, self.origin, dtype=np.float64), np.ones(core.size, bool)
        box_lo, box_hi = self.box(cell, halo)
        first, last = self.cells(np.stack([box_lo, box_hi]))
        meets = self.grid[((self.grid >= first) & (self.grid <= last)).all(axis=1)]
        meets = meets[(meets != cell).any(axis=1)]  # the other tiles the box meets, and the sub-cells it meets
        sub_lo, sub_hi = self.subcells(box_lo, meets), self.subcells(box_hi, meets)
        whole = ((sub_lo == 0) & (sub_hi == SUB - 1)).all(axis=1)
        near = [self.members[c] if w else self.slab(c, a, b)
                for c, w, a, b in zip(map(tuple, meets.tolist()), whole.tolist(), sub_lo, sub_hi)]
        gids = np.concatenate([core] + near)
        order = np.argsort(gids, kind="stable")
        gids, is_core = gids[order], order < core.size
        x = self.frame(gids)  # read in ascending id order
        keep = is_core | ((x >= box_lo) & (x < box_hi)).all(axis=1)
        return gids[keep], x[keep], is_core[keep]

    def covers(self, cell, halo: float, x: np.ndarray, reach: np.ndarray) -> bool:
        """Whether every box of half-width ``reach`` around ``x`` lies in the tile's box (or beyond the cloud)."""
        if self.tile is None:
            return True
        box_lo, box_hi = self.box(cell, halo)
        for a in range(3):  # only the faces inside the cloud bound a neighbourhood
            if box_lo[a] > self.lo[a] and not (x[:, a] - reach >= box_lo[a]).all():
                return False
            if box_hi[a] <= self.hi[a] and not (x[:, a] + reach < box_hi[a]).all():
                return False
        return True


class Source:
    """A cloud read lazily by its tiles (a survey of files): the engine plans it without its coordinates.

    Subclasses give ``n`` (the number of points), ``bounds()`` (per-axis float64 min and max)
    and ``cloud(origin, lo, hi, tile, client) -> Cloud`` (the tiled cloud whose ``gather``
    reads each tile's core and halo).
    """

    n: int

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def cloud(self, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile, client) -> "Cloud":
        raise NotImplementedError


def tile_scores(cloud: Cloud, cell, plan_, stream: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Scores of the core points of one tile, computed on the tile and a verified halo.

    Args:
      cloud: the tiled cloud :func:`hgjax.tiles.plan` returned.
      cell: the tile's grid cell (i, j, k).
      plan_: the resolved :class:`hgjax.engine.Plan`.
      stream: ``chunk_size`` and ``progress`` of the kernel stream; never change results.

    Returns:
      (gids (R,) ascending, scores (R,) or (R, 2) for LHF's two lengths) of the core points.
    """
    tiling = plan_.tiling
    kernel, narrow = tiling.kernel(plan_.score)
    stream = stream or {}

    def rows_of(index, rows):
        """(the kernel's values, to wait for, and the reach) of the core ``rows``."""
        # Each batch's neighbourhoods go to the device as soon as they are built.
        out = (_stream.NarrowStream if narrow else _stream.Stream)(
            kernel, _stream.device_points(index.points, plan_.dtype), total=rows.size, **stream)
        reach = np.empty(rows.size)
        for part, idx, row_args, part_reach in tiling.rows(index, rows, plan_.build, plan_.dtype):
            out.push(rows[part], idx, row_args)
            reach[part] = part_reach
        return out.collect, reach

    gids, core, index, rows, values = covered(cloud, cell, plan_.halo, plan_.build["dedupe"], rows_of)
    return gids[core], per_point(index, rows, core, values())


def covered(cloud: Cloud, cell, halo: float, dedupe: bool, build):
    """A tile indexed with the first halo (``halo``, doubled until it fits) that holds every core neighbourhood.

    ``build(index, rows) -> (built, reach)`` makes the neighbourhoods of the core ``rows`` and
    says how far each reaches; a tile whose neighbourhoods reach the halo's edge is redone
    with twice the halo.

    Returns:
      (gids, core, index, rows, built) of the tile at the halo that holds them.
    """
    while True:
        gids, _, core, index = cloud.indexed(cell, halo, dedupe)
        rows = core_rows(index, core)
        built, reach = build(index, rows)
        if cloud.covers(cell, halo, index.points[rows], reach):
            cloud.release(cell)
            return gids, core, index, rows, built
        halo *= 2


def per_point(index: spatial.SpatialIndex, rows: np.ndarray, core: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-location ``values`` (R, ...) of ``rows`` as the values of the core points (copies share theirs)."""
    loc = index.row if core.all() else index.row[core]
    if rows.size < index.n:  # else every location is a core one: ``rows`` is 0..n-1
        at = np.empty(index.n, dtype=np.int64)
        at[rows] = np.arange(rows.size)
        loc = at[loc]
    return np.take(values, loc, axis=0)


def core_rows(index: spatial.SpatialIndex, core: np.ndarray) -> np.ndarray:
    """(R,) ascending sorted-frame rows (locations) of the core points."""
    if core.all():  # one tile: every location
        return np.arange(index.n)
    mine = np.zeros(index.n, bool)
    mine[index.row[core]] = True
    return np.flatnonzero(mine)
