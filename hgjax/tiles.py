"""Tiled resampling: a plan of every whole-cloud decision, tiles with verified halos, an exact global selection.

:func:`resample` cuts the cloud with a fixed global grid of cubes of edge ``tile`` and gives
the same indices, in the same order, whatever the grid (``tile=None`` is one tile, and is
what :func:`hgjax.resample` runs):

1. **Plan** (:class:`Plan`). Every decision a method takes from the whole cloud is made
   once and passed to every tile: the frame origin (the centre of the bounding box, an exact
   min / max reduction), the number kept, and the build parameters that depend on the
   cloud (HKC/HKF's ``d_factor`` from the sampling irregularity, the reference resolution),
   resolved from the nearest distances of a seeded sample of global ids
   (:func:`hgjax.spatial.sample_ids`) gathered from the tiles that own them.
2. **Tiles** (:func:`tile_scores`). A point belongs to exactly one tile, the cell
   ``floor((x - lo) / tile)`` of the grid anchored at the cloud's minimum corner (half-open
   ``[lo, hi)`` ownership). A tile is scored on its core points with the points of a halo
   around it. The halo is verified, not guessed: every core neighbourhood (its k-nearest
   radius, its cube, the neighbourhoods its spacing estimate read) must lie inside the
   tile's box; otherwise the tile is redone with twice the halo. Neighbour ties are broken
   by (distance, global id) and each neighbourhood's offsets are rounded to the working
   dtype from float64 coordinates, so a core point's score has the same bits in every tile
   that can hold its neighbourhood. A halo reads only the sub-cells of the neighbouring
   tiles that meet its box, and a tile is indexed once for the sample statistics and its
   scores (in this process, up to KEEP_POINTS points).
3. **Selection** (:func:`hgjax.select.top_pairs`). The kept set is the top ceil(ratio N)
   by (score, global id) over the whole cloud, exactly, from per-tile histograms of
   order-preserving integer keys; LHF's two order statistics (Eqs. (15)-(16)) are taken
   the same way. Random methods draw each point's number from the key and its global id.

Each tile is a pure function of its points and the plan, and only per-tile summaries and
scores leave it. ``pca_ac`` (Ward clustering of all scores) and ``fps`` (every pick needs
the global farthest point) are inherently global: they run with ``tile=None`` and are
refused with a tile size.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import pickle
import shutil
import sys
import tempfile
import threading

import jax
import numpy as np

from hgjax import _stream, _validate, pipeline, samplers, select, spatial
from hgjax.scores import ea, gfr, voxel

__all__ = ["Plan", "SurveyResult", "plan", "resample", "resample_files", "tile_scores"]

def _refused(entry, params: dict) -> tuple[str, str] | None:
    """Why ``entry`` with ``params`` needs the whole cloud at once (its ``untiled`` hook), or None."""
    return None if entry.untiled is None else entry.untiled(params)


def _untiled(entry, params: dict, tile, client) -> tuple[str, str] | None:
    """:func:`_refused`, raising ValueError when a ``tile`` or a ``client`` asks for tiles anyway."""
    refused = _refused(entry, params)
    if refused is not None and (tile is not None or client is not None):
        raise ValueError(f"method {entry.name!r}{refused[0]} cannot run in tiles (tile={tile!r}): {refused[1]};"
                         " pass tile=None")
    return refused


TILED = tuple(sorted(name for name, entry in pipeline.METHODS.items()  # with their default parameters
                    if _refused(entry, {}) is None))
HALO_SPACINGS = 2  # the first halo, in mean sample spacings times sqrt(K) per k-nearest radius reached
KEEP_POINTS = 4_000_000  # up to this N, a run in this process keeps each tile's index (or GFR graph) between passes
SUB = 16  # a tile's members are grouped in SUB^3 sub-cells, so that a halo reads slabs of its neighbours
PASS_ROWS = 1 << 20  # points per chunk of a pass over the whole cloud
MANIFEST = "hgjax-manifest.json"
GATHER_BATCH = 64  # per-tile summaries (65,536-bin histograms) a Dask client holds at once in a selection
TASK_BYTES = 32  # per neighbour of a core point in a tile task: an int64 index and three float64 offsets


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

    def record(self) -> dict:
        """The plan as JSON values (arrays as lists, the dtype by name), as a survey's manifest holds it."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        fields["dtype"] = np.dtype(self.dtype).name
        return json.loads(json.dumps(fields, default=_jsonable))


def _grid_shape(lo: np.ndarray, hi: np.ndarray, tile: float) -> tuple:
    """The number of tiles of edge ``tile`` along each axis of the box [lo, hi]."""
    return tuple(int(c) for c in np.floor((hi - lo) / tile).astype(np.int64) + 1)


def _stable_order(key: np.ndarray, top: int) -> np.ndarray:
    """(n,) int64 permutation that sorts the unsigned integer ``key`` (n,), all < ``top``, equal keys in index order.

    A least-significant-digit radix sort in 16-bit digits: NumPy's stable argsort of 16-bit
    integers is a counting sort, linear in n, so a key of up to 32 bits costs two passes.
    """
    order = np.argsort(key.astype(np.uint16), kind="stable")
    for shift in range(16, max(1, int(top - 1).bit_length()), 16):
        order = order[np.argsort((key >> shift).astype(np.uint16)[order], kind="stable")]
    return order


class _Cloud:
    """Points by global id, and the global ids of each tile (host; the points are never copied whole).

    ``members[cell]`` holds a tile's global ids grouped by its SUB^3 sub-cells (ascending
    within each), ``subs[cell]`` the (S, 3) coordinates of its S occupied sub-cells and their
    (S + 1,) starts in it, and ``grid`` the (T, 3) occupied cells in grid order: a halo reads
    only the sub-cells of its neighbours that meet its box. One radix sort of each point's
    (tile, sub-cell) key orders the whole cloud. ``keep`` (set by the runner) keeps
    every tile's host index once built, instead of only the last one, until :meth:`release`.
    """

    progress = False  # a survey reports each finished tile on stderr (:class:`_Ticker`)

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
        self.shape = _grid_shape(lo, hi, tile)
        per_tile = SUB ** 3
        top = int(np.prod(self.shape)) * per_tile
        key = np.empty(n, dtype=np.uint32 if top <= 1 << 32 else np.uint64)  # (tile, sub-cell) of each point
        for s in range(0, n, PASS_ROWS):  # one chunk of the cloud at a time
            x = np.asarray(points[s:s + PASS_ROWS], dtype=np.float64) - origin
            c = self.cells(x)
            key[s:s + PASS_ROWS] = (np.ravel_multi_index(c.T, self.shape) * per_tile
                                    + np.ravel_multi_index(self.subcells(x, c).T, (SUB,) * 3))
        order = _stable_order(key, top)  # by tile, then sub-cell, then ascending global id
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


@dataclasses.dataclass(frozen=True)
class _Source:
    """One file of a survey: its path, the global id of its first point, its point count, its exact bounds."""

    path: str
    start: int
    count: int
    lo: np.ndarray  # (3,) float64 per-axis minimum of its coordinates
    hi: np.ndarray  # (3,) float64 per-axis maximum


@dataclasses.dataclass(frozen=True)
class _Sources:
    """A survey's files as one cloud, described by their :class:`_Source` records (no coordinates).

    ``progress``: report each finished tile task on stderr.
    """

    files: tuple
    progress: bool = False

    @property
    def n(self) -> int:
        return sum(f.count for f in self.files)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis float64 min and max of the whole survey (the exact reduction of the files' bounds)."""
        return np.min([f.lo for f in self.files], axis=0), np.max([f.hi for f in self.files], axis=0)


class _Survey(_Cloud):
    """A survey of files tiled as one cloud, read lazily: a tile reads its core and halo from the files its box meets.

    The grid and ownership are :class:`_Cloud`'s. The client holds the files' records, each
    occupied tile's point count and the owners of the sampled ids (:func:`hgjax.spatial.sample_ids`),
    taken by one census task per file; never the coordinates. :meth:`gather` reads, one chunk
    at a time, only the files whose exact bounds meet the tile's box, and of a COPC file only
    the octree nodes whose bounds meet it.
    """

    def __init__(self, sources: _Sources, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile: float | None,
                 client=None):
        self.origin, self.lo, self.hi, self.tile, self.files = origin, lo, hi, tile, sources.files
        self.source, self.keep, self._indices, self.n = None, False, {}, sources.n
        self.progress = sources.progress
        self.shape = (1, 1, 1) if tile is None else _grid_shape(lo, hi, tile)
        wanted = spatial.sample_ids(self.n)
        counts, self._owners = {}, {}
        for codes, sizes, gids, owner in _map(client, _census, range(len(self.files)), self, wanted):
            for c, r in zip(codes.tolist(), sizes.tolist()):
                counts[c] = counts.get(c, 0) + r
            self._owners.update(zip(gids.tolist(), owner.tolist()))
        self.counts = {tuple(int(i) for i in np.unravel_index(c, self.shape)): counts[c] for c in sorted(counts)}

    def occupied(self) -> list:
        return list(self.counts)

    def core_size(self, cell) -> int:
        return self.counts[cell]

    def owners(self, wanted: np.ndarray) -> list:
        mine = {tuple(int(i) for i in np.unravel_index(self._owners[g], self.shape)) for g in wanted.tolist()}
        return [cell for cell in self.counts if cell in mine]

    def codes(self, x: np.ndarray) -> np.ndarray:
        """(R,) int64 raveled grid cell owning each point of frame coordinates ``x``."""
        if self.tile is None:
            return np.zeros(x.shape[0], np.int64)
        return np.ravel_multi_index(self.cells(x).T, self.shape)

    def gather(self, cell, halo: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        box_lo, box_hi = self.box(cell, halo)
        slack = 1e-9 * (self.hi - self.lo + 1.0)  # a core point may sit an ulp outside its cell's box
        code = np.ravel_multi_index(cell, self.shape)
        gids, xs, cores = [], [], []
        for f in self.files:
            if ((f.hi - self.origin < box_lo - slack) | (f.lo - self.origin > box_hi + slack)).any():
                continue
            for first, xyz in _chunks(f.path, (box_lo + self.origin - slack, box_hi + self.origin + slack)):
                x = xyz - self.origin
                core = self.codes(x) == code
                keep = np.flatnonzero(core | ((x >= box_lo) & (x < box_hi)).all(axis=1))
                gids.append(f.start + first + keep)
                xs.append(x[keep])
                cores.append(core[keep])
        return np.concatenate(gids), np.concatenate(xs), np.concatenate(cores)


class _Ticker:
    """Writes one line on stderr per finished tile task of a pass: ``hgjax tiles: <pass> 3/12 tile (i, j, k)``."""

    def __init__(self, fn, total: int):
        self.what, self.total = fn.__name__.strip("_").replace("_", " "), total
        self.done, self.lock = 0, threading.Lock()

    def __call__(self, cell) -> None:
        with self.lock:
            self.done += 1
            print(f"hgjax tiles: {self.what} {self.done}/{self.total} tile {tuple(cell)}", file=sys.stderr, flush=True)


def _map(client, fn, items, *args) -> list:
    """``[fn(item, *args) for item in items]``, as Dask tasks on ``client`` when given."""
    if client is None:
        return [fn(item, *args) for item in items]
    return client.gather([client.submit(fn, item, *args, pure=False) for item in items])


def _census(i: int, survey: _Survey, wanted: np.ndarray) -> tuple:
    """(occupied cell codes, their point counts, the sampled global ids in file ``i``, their cell codes)."""
    f = survey.files[i]
    cells, sizes, mine, owner = [], [], wanted[(wanted >= f.start) & (wanted < f.start + f.count)], []
    for first, xyz in _chunks(f.path):
        c = survey.codes(xyz - survey.origin)
        u, r = np.unique(c, return_counts=True)
        cells.append(u)
        sizes.append(r)
        owner.append(c[mine[(mine >= f.start + first) & (mine < f.start + first + c.size)] - f.start - first])
    cells, at = np.unique(np.concatenate(cells), return_inverse=True)
    return cells, np.bincount(at, weights=np.concatenate(sizes)).astype(np.int64), mine, np.concatenate(owner)


def _reach_k(build: dict) -> int:
    return voxel.LOCAL_K + 1 if "kernel_size" in build else build.get("k", ea.DEFAULT_K)


def _reach_radii(build: dict) -> int:
    """k-nearest radii a core neighbourhood reaches: two for the spacing-adaptive cube, else one.

    The invariant cube's spacing estimate reads the k-nearest radius of each of the point's
    k nearest neighbours (:func:`hgjax.spatial.local_spacing`).
    """
    return 2 if "kernel_size" in build and build["variant"] == "invariant" and build["resolution"] is None else 1


class _Here:
    """Runs the tile tasks one after another in this process.

    Up to KEEP_POINTS points, each tile's index is kept from the pass that gathers the sample
    statistics to the scoring pass, so each tile is indexed once; above, one index is held at
    a time (memory bounded by a tile).
    """

    def __init__(self, cloud: _Cloud):
        self.cloud = cloud
        cloud.keep = cloud.n <= KEEP_POINTS

    def tiles(self, fn, *args, cells=None) -> list:
        cells = cells or self.cloud.occupied()
        tick = _Ticker(fn, len(cells)) if self.cloud.progress else None
        out = []
        for cell in cells:
            out.append(fn(self.cloud, cell, *args))
            if tick:
                tick(cell)
        return out

    def each(self, fn, parts, *args) -> list:
        return [fn(part, *args) for part in parts]

    def gather(self, values) -> list:
        return values

    def run(self, parts):
        """``run`` of :func:`hgjax.select.kth_pair`: each part's result as it is computed."""
        return select.run_here(parts)


class _Dask(_Here):
    """Runs each tile task as one pure Dask task; results stay on the workers until gathered.

    The tiled cloud is the result of one task whose recipe holds it (a ``np.memmap`` travels
    as its file name): the scheduler keeps that recipe, so a worker that dies with the only
    copy of the cloud loses nothing (scattered data has no recipe, and Dask's active memory
    manager drops the extra copies a broadcast made). A task is a function of the cloud, its
    cell and the resolved plan only, so a task retried after a worker died computes the same
    bits. Smaller tiles run first (a higher Dask priority): a tile that kills the workers it runs
    on then takes no smaller tile queued behind it down with it.
    """

    def __init__(self, cloud: _Cloud, client, k: int = ea.DEFAULT_K):
        import dask

        self.cloud, self.client, self.k = cloud, client, k
        # Dask warns of a large graph because data repeated in it is sent again and again; the cloud is
        # sent once. A fresh key per run: a key shared with an earlier run can be released under this one.
        with dask.config.set({"distributed.admin.large-graph-warning-threshold": "1 PiB"}):
            self.shared = client.submit(_held, cloud, pure=False)
        self.x64 = bool(jax.config.jax_enable_x64)  # the workers compute in the client's precision
        self.cells = {}  # task key -> the tile it computes or derives from

    def tiles(self, fn, *args, cells=None) -> list:
        cells = cells or self.cloud.occupied()
        futures = [self.client.submit(_task, self.x64, fn, self.shared, cell, *args, pure=True,
                                      priority=-self.cloud.core_size(cell)) for cell in cells]
        self.cells.update((f.key, cell) for f, cell in zip(futures, cells))
        if self.cloud.progress:
            tick = _Ticker(fn, len(cells))
            for f, cell in zip(futures, cells):
                f.add_done_callback(lambda _, cell=cell: tick(cell))
        return futures

    def each(self, fn, parts, *args) -> list:
        futures = [self.client.submit(_task, self.x64, fn, part, *args, pure=True) for part in parts]
        self.cells.update((f.key, self.cells[p.key]) for f, p in zip(futures, parts) if p.key in self.cells)
        return futures

    def run(self, parts):
        """``run`` of :func:`hgjax.select.kth_pair`: every part's task submitted at once, the results
        gathered GATHER_BATCH at a time, so the client holds one batch of summaries, not every tile's."""
        def results(fn, *args):
            futures = self.each(fn, parts, *args)
            for start in range(0, len(futures), GATHER_BATCH):
                yield from self.gather(futures[start:start + GATHER_BATCH])

        return results

    def gather(self, values) -> list:
        from distributed import KilledWorker

        try:
            return self.client.gather(values)
        except KilledWorker as err:
            raise RuntimeError(self.killed(err.task, err.last_worker.memory_limit)) from err

    def killed(self, task, memory_limit: int | None) -> str:
        """The message of a task whose workers died: its tile, an estimate of the memory it needs, and the
        memory limit of the last worker that died running it (as the scheduler recorded it: the workers
        being restarted at that moment are not asked).

        A worker can die during a small task when a large tile it ran before left it near its limit (the
        nanny samples memory, so a short peak can pass unseen and the memory held after it cannot); when
        the task's tile is not the run's largest, the message names the largest one too.
        """
        limit = f"; the workers' memory limit: {memory_limit / 2**20:.0f} MiB" if memory_limit else ""
        cell = self.cells.get(task)
        if cell is None:
            return f"Dask workers died running task {task!r} (out of memory?){limit}"
        largest = max(self.cells.values(), key=self.cloud.core_size)
        also = (f"; the largest tile {largest} needs about {self.need(largest)}"
                if self.cloud.core_size(largest) > self.cloud.core_size(cell) else "")
        return (f"Dask workers died running tile {cell} (task {task!r}): it needs about {self.need(cell)}{also}{limit};"
                f" give each worker more memory or pass a smaller tile")

    def need(self, cell) -> str:
        """An estimate of the memory a tile task needs beyond a worker's own footprint, with its terms."""
        r = self.cloud.core_size(cell)
        return (f"{r * self.k * TASK_BYTES / 2**20:.1f} MiB beyond a worker's own footprint (an estimate: {r} core"
                f" points x K={self.k} neighbours x {TASK_BYTES} bytes; its halo's points add to it)")


def _held(value):
    """``value`` itself: the task whose result is the tiled cloud on the workers."""
    return value


def _task(x64: bool, fn, *args):
    """``fn(*args)`` on a worker, with JAX's 64-bit mode as on the client (only inside the task)."""
    with jax.enable_x64(x64):
        return fn(*args)


def _runner(cloud: _Cloud, client, k: int = ea.DEFAULT_K) -> _Here:
    return _Here(cloud) if client is None else _Dask(cloud, client, k)


def plan(points, ratio: float, *, method: str, tile: float | None = None, client=None,
         **params) -> tuple[Plan, _Cloud]:
    """Resolve every whole-cloud decision of a tiled run (host, or a Dask client's workers).

    Args:
      points: (N, 3) float32 or float64 array (an ``np.memmap`` streams from disk).
      ratio: fraction kept, in (0, 1].
      method: a scoring method with a tiled plan (not the samplers); one outside
        :data:`TILED` (PCA-AC) only as one tile.
      tile: tile edge (> 0) in the points' units, or None for one tile.
      client: a ``dask.distributed.Client`` that computes the sample's nearest distances, or None.
      **params: the method's build and score parameters.

    Returns:
      (plan, cloud): the :class:`Plan` and the tiled cloud it was made for.

    Raises:
      ValueError: a method without a tiled plan, or a ``tile`` or ``client`` for a method
        refused in tiles; TypeError, ValueError: invalid arguments.
    """
    plan_, cloud = _base(points, ratio, method, tile, params, client)
    return _resolved(plan_, _runner(cloud, client, _reach_k(plan_.build))), cloud


def _base(points, ratio, method: str, tile, params: dict, client=None) -> tuple[Plan, _Cloud]:
    """The plan before any decision that needs neighbours, and the tiled cloud (a survey's census on ``client``)."""
    entry = pipeline._entry(method)
    if not _planned(entry):
        raise ValueError(f"method {method!r} has no tiled plan; expected one of"
                         f" {sorted(m for m, e in pipeline.METHODS.items() if _planned(e))}")
    _untiled(entry, params, tile, client)
    if isinstance(points, _Sources):
        n, (bmin, bmax), dtype = points.n, points.bounds(), spatial.working_dtype(np.float64)
    else:
        pts = _validate.check_points(points)
        n, (bmin, bmax), dtype = pts.shape[0], _bounds(pts), spatial.working_dtype(pts.dtype)
    m = _validate.n_keep(n, _validate.check_ratio(ratio))
    if tile is not None:
        tile = _validate.check_positive(tile, "tile")
    build, score = entry.tile_params(n, params)
    origin = (bmin + bmax) / 2
    lo, hi = bmin - origin, bmax - origin
    if isinstance(points, _Sources):
        cloud = _Survey(points, origin, lo, hi, tile, client)
    else:
        cloud = _Cloud(pts, origin, lo, hi, tile, points if isinstance(points, np.memmap) else None)
    # The first halo: a few k-nearest radii per radius a neighbourhood reaches (_reach_radii) at the
    # mean density of the occupied tiles (a surface crossing a cube of edge t with n points has a
    # spacing of about t / sqrt(n)).
    spacing = 0.0 if tile is None else tile * np.sqrt(len(cloud.occupied()) / n)
    halo = HALO_SPACINGS * _reach_radii(build) * spacing * np.sqrt(_reach_k(build))
    return Plan(entry.name, n, m, origin, lo, hi, tile, dtype, build, score, halo=float(halo)), cloud


def _planned(entry) -> bool:
    """Whether a registry entry is a scoring method with a tiled plan."""
    return isinstance(entry, pipeline.Method) and entry.tile_params is not None


def _resolved(plan_: Plan, runner: _Here) -> Plan:
    """The plan with the build parameters that depend on the seeded sample (SampleStats) resolved.

    A graph's first halo is just wider than the reach its tiles verify (:func:`_graph_reach`).
    """
    entry = pipeline.METHODS[plan_.method]
    if entry.resolve is None:
        return plan_
    build = entry.resolve(dict(plan_.build), lambda: _sample_stats(runner, plan_))
    halo = max(plan_.halo, _graph_reach(build["r"]) * (1 + 1e-3)) if entry.kind == "graph" else plan_.halo
    return dataclasses.replace(plan_, build=build, halo=halo)


def _bounds(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis float64 min and max, one chunk at a time (an exact reduction, in the points' dtype)."""
    bounds = [spatial.axis_bounds(pts[s:s + PASS_ROWS]) for s in range(0, pts.shape[0], PASS_ROWS)]
    return np.min([lo for lo, _ in bounds], axis=0), np.max([hi for _, hi in bounds], axis=0)


def _sample_stats(runner: _Here, plan_: Plan) -> spatial.SampleStats:
    """:class:`hgjax.spatial.SampleStats` of the seeded sample (:func:`hgjax.spatial.sample_ids`), from the tiles that own it."""
    wanted = spatial.sample_ids(plan_.n)
    cells = runner.cloud.owners(wanted)
    found = {}
    for part in runner.gather(runner.tiles(_tile_stats, plan_, wanted, cells=cells)):
        found.update(part)
    distinct, other, offsets, valid = (np.array([found[g][i] for g in wanted.tolist()]) for i in range(4))
    return spatial.SampleStats(distinct.astype(np.float64), other.astype(np.float64),
                               offsets.reshape(-1, spatial.SAMPLE_K, 3), valid.reshape(-1, spatial.SAMPLE_K))


def _tile_stats(cloud: _Cloud, cell, plan_: Plan, wanted: np.ndarray) -> dict:
    """{gid: (distinct, other, offsets, valid)} of the sampled core points of one tile (:class:`hgjax.spatial.SampleStats`)."""
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


def tile_scores(cloud: _Cloud, cell, plan_: Plan, stream: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Scores of the core points of one tile, computed on the tile and a verified halo.

    Args:
      cloud: the tiled cloud :func:`plan` returned.
      cell: the tile's grid cell (i, j, k).
      plan_: the resolved :class:`Plan`.
      stream: ``chunk_size`` and ``progress`` of the kernel stream; never change results.

    Returns:
      (gids (R,) ascending, scores (R,) or (R, 2) for LHF's two lengths) of the core points.
    """
    entry = pipeline.METHODS[plan_.method]
    kernel, narrow = entry.kernel(plan_.score)
    stream = stream or {}

    def rows_of(index, rows):
        """(the kernel's values, to wait for, and the reach) of the core ``rows``."""
        # Each batch's neighbourhoods go to the device as soon as they are built.
        out = (_stream.NarrowStream if narrow else _stream.Stream)(
            kernel, _stream.device_points(index.points, plan_.dtype), total=rows.size, **stream)
        reach = np.empty(rows.size)
        for part, idx, row_args, part_reach in entry.rows(index, rows, plan_.build, plan_.dtype):
            out.push(rows[part], idx, row_args)
            reach[part] = part_reach
        return out.collect, reach

    gids, core, index, rows, values = _covered(cloud, cell, plan_.halo, plan_.build["dedupe"], rows_of)
    return gids[core], _per_point(index, rows, core, values())


def _covered(cloud: _Cloud, cell, halo: float, dedupe: bool, build):
    """A tile indexed with the first halo (``halo``, doubled until it fits) that holds every core neighbourhood.

    ``build(index, rows) -> (built, reach)`` makes the neighbourhoods of the core ``rows`` and
    says how far each reaches; a tile whose neighbourhoods reach the halo's edge is redone
    with twice the halo.

    Returns:
      (gids, core, index, rows, built) of the tile at the halo that holds them.
    """
    while True:
        gids, _, core, index = cloud.indexed(cell, halo, dedupe)
        rows = _core_rows(index, core)
        built, reach = build(index, rows)
        if cloud.covers(cell, halo, index.points[rows], reach):
            cloud.release(cell)
            return gids, core, index, rows, built
        halo *= 2


def _per_point(index: spatial.SpatialIndex, rows: np.ndarray, core: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-location ``values`` (R, ...) of ``rows`` as the values of the core points (copies share theirs)."""
    loc = index.row if core.all() else index.row[core]
    if rows.size < index.n:  # else every location is a core one: ``rows`` is 0..n-1
        at = np.empty(index.n, dtype=np.int64)
        at[rows] = np.arange(rows.size)
        loc = at[loc]
    return np.take(values, loc, axis=0)


def _core_rows(index: spatial.SpatialIndex, core: np.ndarray) -> np.ndarray:
    """(R,) ascending sorted-frame rows (locations) of the core points."""
    if core.all():  # one tile: every location
        return np.arange(index.n)
    mine = np.zeros(index.n, bool)
    mine[index.row[core]] = True
    return np.flatnonzero(mine)


def resample(points, ratio: float, *, method: str = "hkc", tile: float | None = None, client=None, key=None,
             return_scores: bool = False, **params):
    """Indices of the ceil(ratio N) points a method keeps, computed tile by tile.

    The same indices, in the same order, as :func:`hgjax.resample` on the whole cloud,
    whatever ``tile`` is and wherever the tiles run (module docstring); with ``tile=None``
    and no client it is :func:`hgjax.resample`. Memory is bounded by a tile and its halo,
    not by N (scores aside: 12-16 bytes per point; and up to KEEP_POINTS points, the
    tiles' host indices, kept between the sample-statistics and scoring passes), so an
    ``np.memmap`` of 1e8 points streams from disk. Above KEEP_POINTS, GFR writes each
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
      **params: the method's parameters (as :func:`hgjax.resample`), and ``chunk_size``,
        ``progress``.

    Returns:
      (M,) int64 unique indices, M = ceil(ratio N), highest keep priority first, ties by index;
      with ``return_scores``, (indices, scores) with scores (N,) in the working dtype: the
      values ranked (LHF: its two lengths combined at the kept count, Eqs. (15)-(16)), or None
      for the samplers.

    Raises:
      TypeError, ValueError: invalid arguments, or a method that cannot be tiled given a tile.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = hgjax.eval.box_union_cloud(seed=0, n_points=4000).points
      >>> a = hgjax.tiles.resample(pts, 0.2, method="ea", tile=0.5)
      >>> bool((a == hgjax.resample(pts, 0.2, method="ea")).all())
      True
    """
    run = _resample(points, ratio, method, tile, client, key, return_scores, params)
    return (run.idx, run.scores) if return_scores else run.idx


@dataclasses.dataclass(frozen=True)
class _Run:
    """One run of :func:`resample`: the kept ids, and what decided them (for a survey's manifest).

    Attributes:
      idx: (M,) kept global ids, highest priority first.
      scores: (N,) scores, or None unless asked for (and for the samplers).
      plan: the :class:`Plan`, or None for the samplers and GFR's reference (whole cloud at once).
      selection: the global statistics of the selection: LHF's order statistics Gamma_a,
        Gamma_b (Eqs. (15)-(16)), GFR's exact score sum; empty for the others.
      threshold: the last kept (value, global id) pair, the value being the score (GFR's
        random mode: the Gumbel-perturbed log weight), or None without a plan and for a
        whole selection (PCA-AC's clusters).
    """

    idx: np.ndarray
    scores: np.ndarray | None = None
    plan: Plan | None = None
    selection: dict = dataclasses.field(default_factory=dict)
    threshold: dict | None = None


def _resample(points, ratio, method: str, tile, client, key, return_scores: bool, params: dict,
              on_stage=None) -> _Run:
    """:func:`resample`'s work, returning the :class:`_Run` that a survey's manifest records.

    The one composition of every resampling entry point (:func:`hgjax.resample`,
    :func:`resample`, the command line). ``on_stage(name, seconds)``, when given, is called as
    each stage ends: ``"sample"`` for a sampler; ``"neighbourhoods"``, ``"score"``, ``"keep"``
    on the whole cloud (GFR's reference: :func:`hgjax.pipeline._whole`); ``"plan"`` (bounds,
    grid, resolved parameters), ``"tiles"`` (every tile's neighbourhoods and scores) and
    ``"keep"`` (the global selection; PCA-AC's Ward clustering of every score, in one tile)
    in tiles.
    """
    clock = pipeline._Clock(on_stage)
    entry = pipeline._entry(method)
    return_scores = _validate.check_bool(return_scores, "return_scores")
    distributed = tile is not None or client is not None
    refused = _untiled(entry, params, tile, client)
    pipeline._check_known(entry, params)
    if isinstance(entry, pipeline.Sampler):
        if (distributed or isinstance(points, _Sources)) and method in _TILED_SAMPLERS:
            keyed = {"key": key} if entry.needs_key else {}
            return _Run(clock("sample", _TILED_SAMPLERS[method](points, ratio, tile, client, **keyed, **params)))
        return _Run(clock("sample", entry.draw(_validate.check_points(points), ratio, key, **params)))
    if "tau" in params:  # a soft-score parameter resample does not use: still checked
        _validate.check_traced_positive(params["tau"], "tau")
    if refused is not None and not entry.whole_selection:
        idx, scores = pipeline._whole(points, ratio, entry, key, params, on_stage)
        return _Run(idx, scores if return_scores else None)
    stream = {k: params.pop(k) for k in ("chunk_size", "progress") if k in params}
    if entry.check_key is not None:
        key = entry.check_key(key, params)
    plan_, cloud = _base(points, ratio, method, tile, params, client)
    runner = _runner(cloud, client, _reach_k(plan_.build))
    plan_ = clock("plan", _resolved(plan_, runner))
    parts = _gfr_scores(runner, plan_, stream) if entry.kind == "graph" else runner.tiles(tile_scores, plan_, stream)
    clock("tiles")
    if entry.whole_selection:
        scores = _gathered(runner, parts, plan_)
        return _Run(clock("keep", pipeline.keep(scores, ratio, method=method, key=key, **params)),
                    scores if return_scores else None, plan_)
    if entry.tiled_select is None:
        keyed, selection, largest = runner.each(select.part_keys, parts, entry.largest), {}, entry.largest
    else:
        parts, keyed, selection, largest = entry.tiled_select(runner, parts, plan_, key)
    idx, (last_key, last_gid) = select.top_pairs(keyed, plan_.m, run=runner.run(keyed), boundary=True)
    clock("keep")
    threshold = {"value": select.key_value(last_key, largest=largest), "gid": last_gid}
    return _Run(idx, _gathered(runner, parts, plan_) if return_scores else None, plan_, selection, threshold)


def _gathered(runner: _Here, parts, plan_: Plan) -> np.ndarray:
    """(N,) scores of every point, in the working dtype, gathered from the tiles' (gids, scores) parts."""
    scores = np.empty(plan_.n, dtype=plan_.dtype)
    for gids, values in runner.gather(parts):
        scores[gids] = values
    return scores


def _gfr_graph(cloud: _Cloud, cell, plan_: Plan, with_sums: bool = True) -> dict:
    """GFR's graph around the core locations of one tile, and its exact pair sums if ``with_sums``
    (else None) (Chen et al. 2018).

    A core location's stored pairs are those it ranks or that rank it, so every location
    within the radius R of it must see its whole R-ball: the halo is verified to hold 2R
    around every core location.
    """
    b = plan_.build
    reach = _graph_reach(b["r"])
    gids, core, index, rows, _ = _covered(cloud, cell, plan_.halo, True,
                                          lambda index, rows: (None, np.full(rows.size, reach)))
    if with_sums:
        chunks, sums = gfr.graph_sums(index, rows, b["r"], b["max_nn"], plan_.dtype)
    else:
        chunks, sums = list(gfr.graph_rows(index, rows, b["r"], b["max_nn"])), None
    return {"gids": gids, "core": core, "index": index, "rows": rows, "chunks": chunks, "sums": sums}


def _graph_reach(r: float) -> float:
    """How far around a core location GFR's tile must hold every point: twice the pair query's bound
    (its partners' partners), for the squared radius ``r``."""
    return 2 * np.sqrt(r) * (1 + 1e-5)


def _gfr_sums(graph: dict) -> tuple:
    return graph["sums"]


def _gfr_norms(graph: dict, plan_: Plan, mean_q: float, two_var: float, stream: dict):
    """(gids, scores) of a tile's core points from its graph and the global weight statistics."""
    index, rows, core = graph["index"], graph["rows"], graph["core"]
    lp = gfr.graph_norms(index, graph["chunks"], mean_q, two_var, plan_.dtype, **stream)
    return graph["gids"][core], _per_point(index, rows, core, lp.astype(plan_.dtype))


def _gfr_scores(runner: _Here, plan_: Plan, stream: dict):
    """GFR scores of every tile's core points: pair sums over all tiles, then the flows (two passes).

    Dask workers and small clouds keep each tile's graph between the passes. A large cloud in
    this process keeps only each tile's pair sums in memory and writes its graph to a private
    temporary directory (``tempfile``'s, e.g. ``TMPDIR``) for the second pass, so memory stays
    bounded by a tile; a tile whose graph the disk has no room for is built again in the second
    pass (without its pair sums). The scores are the same either way.
    """
    if isinstance(runner, _Dask) or plan_.n <= KEEP_POINTS:
        graphs = runner.tiles(_gfr_graph, plan_)
        mean_q, two_var = gfr.moments(gfr.summed(runner.gather(runner.each(_gfr_sums, graphs))))
        return runner.each(_gfr_norms, graphs, plan_, mean_q, two_var, stream)
    with tempfile.TemporaryDirectory(prefix="hgjax-gfr-") as spill:
        mean_q, two_var = gfr.moments(gfr.summed(runner.tiles(_gfr_spilled_sums, plan_, spill)))
        return runner.tiles(_gfr_spilled_tile, plan_, mean_q, two_var, stream, spill)


def _spill_path(spill: str, cell) -> str:
    return os.path.join(spill, "_".join(map(str, cell)) + ".pickle")


def _gfr_spilled_sums(cloud: _Cloud, cell, plan_: Plan, spill: str) -> tuple:
    """A tile's pair sums; its graph goes to ``spill`` when the disk has room for twice its arrays."""
    graph = _gfr_graph(cloud, cell, plan_)
    index = graph["index"]
    size = sum(own.nbytes + sym.nbytes for own, sym in graph["chunks"]) + 4 * index.points.nbytes
    path = _spill_path(spill, cell)
    if shutil.disk_usage(spill).free > 2 * size:
        try:
            with open(path, "wb") as f:
                pickle.dump(graph, f, protocol=pickle.HIGHEST_PROTOCOL)
        except OSError:
            os.remove(path)
    return graph["sums"]


def _gfr_spilled_tile(cloud: _Cloud, cell, plan_: Plan, mean_q: float, two_var: float, stream: dict, spill: str):
    path = _spill_path(spill, cell)
    if not os.path.exists(path):
        return _gfr_norms(_gfr_graph(cloud, cell, plan_, with_sums=False), plan_, mean_q, two_var, stream)
    with open(path, "rb") as f:
        graph = pickle.load(f)
    os.remove(path)
    return _gfr_norms(graph, plan_, mean_q, two_var, stream)


def _voxel(points, ratio, tile, client, *, voxel_size=None) -> np.ndarray:
    """``voxel`` in tiles: :func:`hgjax.voxel_sample`'s grid, voxels owned by the tile of their lowest id.

    The edge is searched once on the whole cloud (or given); each tile assigns its core
    points and a halo of one voxel edge, so every voxel with a core point is whole. A voxel
    belongs to the tile that owns its lowest-id point, which gives its representative (the
    point nearest the centroid, summed in id order) and population; the global ranking is
    by (population, id), exactly as in one process.
    """
    pts = _validate.check_points(points)
    n = pts.shape[0]
    if tile is not None:
        tile = _validate.check_positive(tile, "tile")
    m = None if ratio is None else _validate.n_keep(n, _validate.check_ratio(ratio))
    if m is None and voxel_size is None:
        raise ValueError("voxel_sample needs ratio or voxel_size; got neither")
    grid = dataclasses.replace(samplers.voxel_grid(pts, m, voxel_size), voxel=None)
    bmin, bmax = _bounds(pts)
    origin = (bmin + bmax) / 2
    source = points if isinstance(points, np.memmap) else None
    runner = _runner(_Cloud(pts, origin, bmin - origin, bmax - origin, tile, source), client)
    parts = runner.tiles(_voxel_part, grid)
    v = sum(runner.gather(runner.each(_count, parts)))
    ranked = select.top_pairs(parts, v if m is None else min(m, v), run=runner.run(parts))
    if m is None or m <= v:
        return ranked
    reps = np.concatenate([g for _, g in runner.gather(parts)])
    return np.concatenate([ranked, np.setdiff1d(np.arange(n), reps)])[:m].astype(np.int64)


def _voxel_part(cloud: _Cloud, cell, grid) -> tuple[np.ndarray, np.ndarray]:
    """(keys, gids) of the voxels a tile owns: representatives ranked by population."""
    gids, _, core = cloud.gather(cell, 1.01 * grid.size)
    rep, counts, first = samplers.voxel_tile(np.asarray(cloud.points[gids], dtype=np.float64).T, grid)
    owned = core[first]
    return select.order_keys(counts[owned].astype(np.float64), largest=True), gids[rep[owned]]


def _count(part) -> int:
    return int(part[1].size)


def _uniform(points, ratio, tile, client, *, key=None) -> np.ndarray:
    """``uniform`` on a cloud or a survey: each point's draw comes from the key and its global id
    (:func:`hgjax.select.point_bits`), so the draw reads the point count N and no coordinate."""
    n = points.n if isinstance(points, _Sources) else _validate.check_points(points).shape[0]
    if tile is not None:
        _validate.check_positive(tile, "tile")
    return samplers.uniform_ids(n, ratio, key=key)


_TILED_SAMPLERS = {"uniform": _uniform, "voxel": _voxel}  # samplers with an engine of their own here
_SURVEY_SAMPLERS = ("uniform",)  # those of them that read a survey lazily (no coordinate at all)


@dataclasses.dataclass(frozen=True)
class SurveyResult:
    """What :func:`resample_files` did.

    Attributes:
      written: output paths written, in input order.
      skipped: output paths left as they were (``skip_existing``).
      failures: {input path: error message} of the inputs that could not be read or written.
      manifest: path of the manifest JSON, or None when nothing was resampled.
    """

    written: list
    skipped: list
    failures: dict
    manifest: str | None


def _survey_paths(paths) -> list[str]:
    """Files of ``paths`` (files or glob patterns), in the order given, each once."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    found = []
    for p in paths:
        p = os.fspath(p)
        matches = sorted(glob.glob(p)) if glob.has_magic(p) else [p]
        if not matches:
            raise ValueError(f"paths: the pattern {p!r} matches no file")
        found += [m for m in matches if m not in found]
    if not found:
        raise ValueError("paths must name at least one file; got none")
    return found


def _is_las(path: str) -> bool:
    return os.path.splitext(path)[1].lower() in (".las", ".laz")


def _header_count(path: str) -> int | None:
    """The number of points a LAS/LAZ file's header announces (read alone); None for other formats."""
    from hgjax import io

    if not _is_las(path):
        return None
    if not os.path.isfile(path):
        raise io.PointCloudNotFoundError(f"cannot read {path}: no such file")
    laspy, _ = io._require("las", f"reading {path}")
    try:
        with laspy.open(path) as f:
            return int(f.header.point_count)
    except Exception as err:
        raise io.PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err


def _chunks(path: str, box: tuple | None = None):
    """(position of the first point in the file, (R, 3) float64 coordinates of consecutive points), in file order.

    LAS/LAZ PASS_ROWS points at a time (laspy's chunked reading); a COPC file (one with a COPC
    info VLR, whatever its name) one octree node at a time (:func:`_copc_nodes`), only the nodes
    whose bounds meet ``box`` (lo (3,), hi (3,) in file coordinates) when given; any other
    format whole (:func:`hgjax.io.read_points`). Chunks may hold points outside ``box``.
    """
    from hgjax import io

    if not _is_las(path):
        yield 0, io.read_points(path).points
        return
    laspy, _ = io._require("las", f"reading {path}")
    at = 0
    try:
        with laspy.open(path) as f:
            if any(isinstance(v, laspy.copc.CopcInfoVlr) for v in f.header.vlrs):
                yield from _copc_nodes(path, box)
                return
            for chunk in f.chunk_iterator(PASS_ROWS):
                yield at, np.stack([np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)], axis=1)
                at += len(chunk)
    except io.PointCloudReadError:
        raise
    except Exception as err:
        raise io.PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err


def _copc_nodes(path: str, box: tuple | None):
    """(position of a node's first point in the file, (R, 3) float64 coordinates) per COPC octree node.

    The nodes' point chunks are stored in the file in the order of their offsets, so a node's
    first point sits at the sum of the point counts of the nodes stored before it (its
    hierarchy entry: offset, point count). The whole hierarchy is read (laspy's
    ``load_octree_for_query``, every page), then only the nodes whose bounds, grown by one
    scale step, meet ``box`` are decompressed (laspy's ``CopcReader`` chunk reader, nodes
    batched by PASS_ROWS points: a batch starts at the node holding the next multiple), in
    file order. A point outside its node's bounds (one scale step of slack) makes the file
    unreadable: a spatial query could miss it.

    Raises:
      hgjax.io.PointCloudReadError: a point lies outside its node's bounds.
    """
    from laspy.copc import CopcReader, load_octree_for_query

    from hgjax import io

    with CopcReader.open(path) as reader:
        nodes = load_octree_for_query(reader.source, reader.copc_info, reader.root_page)
        nodes = sorted((node for node in nodes if node.point_count > 0), key=lambda node: node.offset)
        starts = np.cumsum([0] + [node.point_count for node in nodes])[:-1].tolist()
        step = np.asarray(reader.header.scales, dtype=np.float64)
        picked = [(s, node) for s, node in zip(starts, nodes)
                  if box is None or ((node.bounds.mins - step <= box[1]) & (node.bounds.maxs + step >= box[0])).all()]
        counts = np.array([node.point_count for _, node in picked], dtype=np.int64)
        firsts = np.flatnonzero(np.diff((np.cumsum(counts) - counts) // PASS_ROWS)) + 1
        batches = np.split(np.arange(len(picked)), firsts)
        for batch in ([picked[i] for i in rows] for rows in batches if rows.size):
            record = reader._fetch_and_decompress_points_of_nodes([node for _, node in batch])
            xyz = np.stack([np.asarray(record.x), np.asarray(record.y), np.asarray(record.z)], axis=1)
            at = 0
            for s, node in batch:
                x, at = xyz[at:at + node.point_count], at + node.point_count
                if ((x < node.bounds.mins - step) | (x > node.bounds.maxs + step)).any():
                    raise io.PointCloudReadError(f"cannot read {path}: a point of COPC node {node.key} lies outside"
                                                 f" the node's bounds (corrupt octree)")
                yield s, x


def _scan(entry: tuple):
    """(count, lo (3,), hi (3,)) of a file from a read of all its coordinates, or the message of why it cannot be read.

    ``entry`` is (path, the point count its header announces or None); a LAS/LAZ file must hold
    the points its header announces, all finite.
    """
    from hgjax import io

    path, announced = entry
    n, lo, hi = 0, np.full(3, np.inf), np.full(3, -np.inf)
    try:
        for _, xyz in _chunks(path):
            if not np.isfinite(xyz).all():
                raise io.PointCloudReadError(f"cannot read {path}: non-finite coordinates (corrupt scale or offset)")
            n += xyz.shape[0]
            lo, hi = np.minimum(lo, xyz.min(axis=0, initial=np.inf)), np.maximum(hi, xyz.max(axis=0, initial=-np.inf))
        if announced is not None and n != announced:
            raise io.PointCloudReadError(f"cannot read {path}: the file holds {n} points; its header announces"
                                         f" {announced} (truncated or corrupt)")
        if n == 0:
            raise io.PointCloudReadError(f"cannot read {path}: the file holds no points")
    except io.PointCloudReadError as err:
        return str(err)
    return n, lo, hi


def _stage(disk: np.memmap, start: int, path: str) -> None:
    """Copy the float64 coordinates of ``path`` into ``disk[start:]``, one chunk at a time."""
    for first, xyz in _chunks(path):
        disk[start + first:start + first + xyz.shape[0]] = xyz


def _jsonable(value):
    if isinstance(value, jax.Array) and jax.dtypes.issubdtype(value.dtype, jax.dtypes.prng_key):
        return np.asarray(jax.random.key_data(value)).tolist()
    if isinstance(value, (np.ndarray, jax.Array, np.generic)):
        return np.asarray(value).tolist()
    return repr(value)


def _run_record(paths, method, ratio, tile, key, params) -> dict:
    """The part of the manifest that decides whether an earlier run's outputs can be kept."""
    inputs = [{"path": os.path.abspath(p), "bytes": os.path.getsize(p) if os.path.exists(p) else None,
               "mtime_ns": os.stat(p).st_mtime_ns if os.path.exists(p) else None} for p in paths]
    return json.loads(json.dumps({"method": method, "ratio": ratio, "tile": tile, "key": key, "params": params,
                                  "inputs": inputs}, default=_jsonable))


def resample_files(paths, out_dir, ratio: float, *, method: str = "hkc", tile: float | None = None, client=None,
                   key=None, keep_going: bool = False, skip_existing: bool = False, progress: bool = False,
                   **params) -> SurveyResult:
    """Resample a survey of files as one cloud, writing the kept points of each file beside the others.

    Global ids run in file order, then point order within each file, and the kept ids are
    exactly those of :func:`resample` on the concatenated cloud. The survey is read lazily:
    the LAS/LAZ headers first (point counts), then one task per file reads its coordinates
    (LAS/LAZ in chunks of PASS_ROWS points, through laspy) for its exact bounds and checks
    them, so every input is checked before any output is written; one census task per file
    counts the points of each tile; each tile's task reads its core and halo from only the
    files whose bounds meet its box, and of a COPC file (known by its COPC info VLR) only the
    octree nodes whose bounds meet it (a node's points are numbered from the point counts of
    the nodes stored before it in the file, so ids are those of the whole file read in order).
    The client holds per file its path, count and bounds,
    per tile its count, and, while writing, one input file with its attributes; never the
    survey's coordinates. Tasks read the inputs by absolute path, so Dask workers must see
    them. ``uniform`` reads no coordinate after that check (a point's draw comes from the key
    and its global id). The methods that need the whole cloud at once read it from a float64
    memmap (24 bytes a point, on disk) in a hidden temporary directory of ``out_dir`` instead,
    and hold what they need per point in memory: ``voxel`` (its count-targeted edge search
    assigns every point of the cloud to a voxel, pass after pass, until the kept count is
    reached), GFR's ``variant="reference"`` (its squared radius comes from the min and max nearest
    distance of the whole cloud) and those :func:`resample` runs untiled (``fps``, ``pca_ac``).

    Args:
      paths: files or glob patterns (each pattern's matches sorted), any format
        :func:`hgjax.io.read_points` reads; never modified.
      out_dir: directory of the outputs (created if missing): one file per input, same name.
      ratio: fraction of the whole survey kept, in (0, 1].
      method, tile, client, key, **params: as :func:`resample`.
      keep_going: an unreadable input is reported in the result and left out of the survey
        instead of raising; an output that cannot be written is reported likewise.
      skip_existing: keep outputs that exist when the manifest in ``out_dir`` records the
        same method, ratio, tile, key, parameters and inputs (paths, sizes, modification
        times); only missing outputs are written.
      progress: write one line on stderr as each tile task of each pass finishes
        (``hgjax tiles: tile scores 3/12 tile (0, 1, 0)``).

    Returns:
      :class:`SurveyResult`. Each output holds its input's kept points in input order, with
      every attribute, and a LAS/LAZ output keeps its input's header (point format, scale,
      offset, extra dimensions); the output of a COPC input is a plain LAZ file of the same
      name (its octree VLRs are dropped: nothing here writes COPC). ``out_dir/hgjax-manifest.json`` records the run, the
      number of points N and kept M, each output's count, and under ``resolved`` what
      decided the kept set: the :class:`Plan` (origin, bounds, resolved build and score
      parameters, halo), the selection's global statistics (LHF's Gamma_a and Gamma_b,
      GFR's score sum) and the threshold (the last kept score and its global id), so a
      rerun can be checked against it; outputs and manifest are written atomically.

    Raises:
      ValueError: ``paths`` matches no file, or an output would be one of the inputs.
      hgjax.io.PointCloudReadError: an input cannot be read (without ``keep_going``), before
        any output is written.
      TypeError, ValueError: as :func:`resample`.
    """
    from hgjax import __version__, io

    keep_going = _validate.check_bool(keep_going, "keep_going")
    skip_existing = _validate.check_bool(skip_existing, "skip_existing")
    progress = _validate.check_bool(progress, "progress")
    files = _survey_paths(paths)
    out_dir = os.fspath(out_dir)
    targets = {p: os.path.join(out_dir, os.path.basename(p)) for p in files}
    if len(set(targets.values())) < len(files):
        raise ValueError("paths: two inputs have the same file name, so their outputs in out_dir would collide")
    clash = [p for p in files if os.path.abspath(targets[p]) == os.path.abspath(p)]
    if clash:
        raise ValueError(f"out_dir: the output of {clash[0]} would overwrite it; choose another directory")
    record = _run_record(files, method, ratio, tile, key, params)
    manifest = os.path.join(out_dir, MANIFEST)
    done = set()
    if skip_existing and os.path.isfile(manifest):
        with open(manifest) as fh:
            old = json.load(fh)
        if old.get("run") == record:
            done = {p for p in files if os.path.exists(targets[p])}
    if done and len(done) == len(files):
        return SurveyResult([], [targets[p] for p in files], {}, manifest)
    failures, announced = {}, {}
    for p in files:  # headers first: a LAS/LAZ file whose header cannot be read fails before any coordinate is
        try:
            announced[p] = _header_count(p)
        except io.PointCloudReadError as err:
            if not keep_going:
                raise
            failures[p] = str(err)
    sources, counts = [], {}
    for p, got in zip(announced, _map(client, _scan, [(os.path.abspath(p), c) for p, c in announced.items()])):
        if isinstance(got, str):
            if not keep_going:
                raise io.PointCloudReadError(got)
            failures[p] = got
            continue
        counts[p] = got[0]
        sources.append(_Source(os.path.abspath(p), sum(counts.values()) - got[0], *got))
    if not sources:
        raise io.PointCloudReadError(f"no input could be read: {failures}")
    survey, n = _Sources(tuple(sources), progress), sum(counts.values())
    starts = {p: f.start for p, f in zip(counts, sources)}
    os.makedirs(out_dir, exist_ok=True)
    entry = pipeline._entry(method)
    if (_planned(entry) and _refused(entry, params) is None) or entry.name in _SURVEY_SAMPLERS:
        run = _resample(survey, ratio, method, tile, client, key, False, dict(params))
    else:  # the methods that need the whole cloud at once read it from a float64 memmap
        with tempfile.TemporaryDirectory(dir=out_dir, prefix=".hgjax-survey-") as work:
            disk = np.memmap(os.path.join(work, "xyz.f8"), dtype=np.float64, mode="w+", shape=(n, 3))
            for f in sources:
                _stage(disk, f.start, f.path)
            disk.flush()
            run = _resample(disk, ratio, method, tile, client, key, False, dict(params))
            del disk
    kept = np.sort(run.idx)
    written, skipped, outputs = [], [], {}
    for p, start in starts.items():
        local = kept[np.searchsorted(kept, start):np.searchsorted(kept, start + counts[p])] - start
        outputs[p] = {"output": os.path.abspath(targets[p]), "points": counts[p], "kept": int(local.size)}
        if p in done:
            skipped.append(targets[p])
            continue
        try:
            data = io.read_points(p)
            if len(data) != counts[p]:
                raise io.PointCloudReadError(f"cannot read {p}: it changed while being resampled")
            kept_data = data.subset(local)
            io.write_points(targets[p], kept_data.points, attributes=kept_data.attributes, header=kept_data.header)
        except (io.PointCloudReadError, io.PointCloudWriteError, OSError, ValueError) as err:
            if not keep_going:
                raise
            failures[p] = str(err)
            continue
        written.append(targets[p])
    resolved = {"plan": None if run.plan is None else run.plan.record(), "selection": run.selection,
                "threshold": run.threshold}
    body = {"hgjax": __version__, "run": record, "resolved": resolved, "n": n, "m": int(kept.size),
            "outputs": list(outputs.values()), "failures": failures}
    text = json.dumps(body, indent=2, default=_jsonable).encode()
    io._atomic_write(os.path.abspath(manifest), lambda fh: fh.write(text))
    return SurveyResult(written, skipped, failures, manifest)
