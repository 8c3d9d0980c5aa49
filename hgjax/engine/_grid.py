"""The tiled grid: a plan of every whole-cloud decision, tiles with verified halos, and where the tiles run.

Generic machinery of :mod:`hgjax.engine`; it knows no method by name: what a method needs is
its :class:`hgjax.Method`'s ``tiling`` (:class:`hgjax._method.Tiling`).

1. **Plan** (:class:`Plan`). Every decision a method takes from the whole cloud is made
   once and passed to every tile: the frame origin (the centre of the bounding box, an exact
   min / max reduction), the number kept, and the build parameters that depend on the
   cloud (HKC/HKF's ``d_factor`` from the sampling irregularity, the reference resolution),
   resolved from the nearest distances of a seeded sample of global ids
   (:func:`hgjax.neighbours.spatial.sample_ids`) gathered from the tiles that own them.
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
3. **Runners** (:class:`Here`, :class:`Dask`): the tiles one after another in this process,
   or each as one pure Dask task whose results stay on the workers until gathered.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import threading
import time

import jax
import numpy as np

from hgjax import _progress, _stream, select
from hgjax.neighbours import spatial

__all__ = ["Cloud", "Dask", "Here", "Plan", "Source", "tile_scores"]

HALO_SPACINGS = 2  # the first halo, in mean sample spacings times sqrt(K) per k-nearest radius reached
KEEP_POINTS = 4_000_000  # up to this N, a run in this process keeps each tile's index (or GFR graph) between passes
MAX_TILES = 1 << 31  # grid cells of a tiled cloud (its (tile, sub-cell) keys stay within 64 bits)
SUB = 16  # a tile's members are grouped in SUB^3 sub-cells, so that a halo reads slabs of its neighbours
PASS_ROWS = 1 << 20  # points per chunk of a pass over the whole cloud
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

    progress = False  # a survey reports each finished tile on stderr (:class:`Ticker`)

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


class Ticker:
    """The progress of one pass of tasks of known sizes (a survey's, ``progress``), called with a task's key
    as it ends, from any thread.

    Under the command line, a count of its run's progress (:func:`hgjax._progress.current`). Else, a
    tqdm bar of the points done where stderr is a terminal and tqdm is installed; else a first line as
    the pass starts (``hgjax tiles: tile scores: 12 tiles, 1.2M points``), then, at most one a
    :attr:`PERIOD` and at the last task, the tasks and points done, the rate and, once it can be told
    (:class:`hgjax._progress.Rate`), the time left (``hgjax tiles: tile scores 3/12 tiles, 210k/1.2M
    points, 53k points/s, ETA 19 s``).

    Args:
      what: the pass's name, or its task function (named by it: ``_tile_scores`` is "tile scores").
      sizes: {task key: its size in ``unit``}.
      task, unit, prefix: the words of the lines.
    """

    PERIOD = 1.0

    def __init__(self, what, sizes: dict, *, task: str = "tile", unit: str = "points", prefix: str = "hgjax tiles"):
        self.what = what if isinstance(what, str) else what.__name__.strip("_").replace("_", " ")
        self.sizes, self.total, self.task, self.unit, self.prefix = sizes, sum(sizes.values()), task, unit, prefix
        self.done, self.amount, self.lock = 0, 0, threading.Lock()
        self.start = self.said = time.perf_counter()
        self.rate = _progress.Rate(self.start)
        self.bar, self.run = None, _progress.current()
        if self.run is not None:
            self.counted = self.run.count(self.what, self.total, len(sizes), task, unit)
            return
        if sys.stderr.isatty():
            try:
                from tqdm import tqdm
            except ImportError:  # tqdm is optional (the progress extra): plain lines then
                pass
            else:
                self.bar = tqdm(total=self.total, unit=f" {unit}", unit_scale=True, file=sys.stderr,
                                desc=f"{prefix}: {self.what} ({len(sizes)} {task}s)", dynamic_ncols=True)
        if self.bar is None:
            self.say(f"{prefix}: {self.what}: {len(sizes)} {task}s, {self.si(self.total)} {unit}")

    def __call__(self, key) -> None:
        if self.run is not None:
            self.run.task_done(self.counted, self.sizes[key])
            return
        with self.lock:
            self.done += 1
            self.amount += self.sizes[key]
            last = self.done == len(self.sizes)
            if self.bar is not None:
                self.bar.update(self.sizes[key])
                if last:
                    self.bar.close()
                return
            now = time.perf_counter()
            rate = self.rate(self.amount, now)
            if now - self.said < self.PERIOD and not last:
                return
            self.said, left = now, self.rate.left(self.amount, self.total, now)
            self.say(f"{self.prefix}: {self.what} {self.done}/{len(self.sizes)} {self.task}s, {self.si(self.amount)}/"
                     f"{self.si(self.total)} {self.unit}, {self.si(rate)} {self.unit}/s"
                     + ("" if left is None else f", ETA {left}"))

    say = staticmethod(_progress.say)
    si = staticmethod(_progress.si)


def map_tasks(client, fn, items, *args) -> list:
    """``[fn(item, *args) for item in items]``, as Dask tasks on ``client`` when given."""
    if client is None:
        return [fn(item, *args) for item in items]
    return client.gather([client.submit(fn, item, *args, pure=False) for item in items])


class Here:
    """Runs the tile tasks one after another in this process.

    Up to KEEP_POINTS points, each tile's index is kept from the pass that gathers the sample
    statistics to the scoring pass, so each tile is indexed once; above, one index is held at
    a time (memory bounded by a tile).
    """

    def __init__(self, cloud: Cloud):
        self.cloud = cloud
        cloud.keep = cloud.n <= KEEP_POINTS

    def tiles(self, fn, *args, cells=None) -> list:
        cells = cells or self.cloud.occupied()
        tick = Ticker(fn, {cell: self.cloud.core_size(cell) for cell in cells}) if self.cloud.progress else None
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


class Dask(Here):
    """Runs each tile task as one pure Dask task; results stay on the workers until gathered.

    The tiled cloud is the result of one task whose recipe holds it (a ``np.memmap`` travels
    as its file name): the scheduler keeps that recipe, so a worker that dies with the only
    copy of the cloud loses nothing (scattered data has no recipe, and Dask's active memory
    manager drops the extra copies a broadcast made). Each worker that runs tiles holds a copy
    of it, the result of a task of its own on that task's result, made before its first tile
    starts (a copy fetched from a worker busy with tiles waits for that worker's interpreter).
    A task is a function of the cloud, its cell and the resolved plan only, so a task retried
    after a worker died computes the same bits. Smaller tiles run first (a higher Dask
    priority): a tile that kills the workers it runs on then takes no smaller tile queued
    behind it down with it.
    """

    def __init__(self, cloud: Cloud, client, k: int):
        import dask

        self.cloud, self.client, self.k = cloud, client, k
        # Dask warns of a large graph because data repeated in it is sent again and again; the cloud is
        # sent once. A fresh key per run: a key shared with an earlier run can be released under this one.
        with dask.config.set({"distributed.admin.large-graph-warning-threshold": "1 PiB"}):
            self.shared = client.submit(held, cloud, pure=False)
        self.copies = {}  # worker address -> the future of its copy of the cloud
        self.x64 = bool(jax.config.jax_enable_x64)  # the workers compute in the client's precision
        self.cells = {}  # task key -> the tile it computes or derives from

    def tiles(self, fn, *args, cells=None) -> list:
        cells = cells or self.cloud.occupied()
        where = self.placed(cells)
        self.copied(where.values())
        futures = [self.client.submit(task, self.x64, fn, self.copies.get(where[cell], self.shared), cell, *args,
                                      pure=True, workers=where[cell], allow_other_workers=True,
                                      priority=-self.cloud.core_size(cell)) for cell in cells]
        self.cells.update((f.key, cell) for f, cell in zip(futures, cells))
        if self.cloud.progress:
            tick = Ticker(fn, {cell: self.cloud.core_size(cell) for cell in cells})
            for f, cell in zip(futures, cells):
                f.add_done_callback(lambda _, cell=cell: tick(cell))
        return futures

    def placed(self, cells: list) -> dict:
        """{cell: the address of the worker it runs on}: largest tile first to the least loaded worker,
        in points (ties to the first worker by address), or None for each where the cluster has no
        worker yet.

        Left to itself, the scheduler runs every tile where the cloud is held (the transfer looks
        dearer than an unknown task) and the other workers idle; the placement is a preference
        (``allow_other_workers``): a tile whose worker died runs elsewhere, with the same bits.
        """
        workers = sorted(self.client.ncores())
        if not workers:
            return dict.fromkeys(cells)
        load, where = [0] * len(workers), {}
        for cell in sorted(cells, key=lambda c: (-self.cloud.core_size(c), c)):
            w = min(range(len(workers)), key=lambda i: (load[i], i))
            load[w] += self.cloud.core_size(cell)
            where[cell] = workers[w]
        return where

    def copied(self, workers) -> None:
        """Make each of ``workers`` (addresses) hold its copy of the cloud, and wait for the copies."""
        from distributed import wait

        new = sorted({w for w in workers if w is not None} - set(self.copies))
        for w in new:
            self.copies[w] = self.client.submit(held, self.shared, pure=False, workers=w, allow_other_workers=True)
        wait([self.copies[w] for w in new])

    def each(self, fn, parts, *args) -> list:
        futures = [self.client.submit(task, self.x64, fn, part, *args, pure=True) for part in parts]
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


def held(value):
    """``value`` itself: the task whose result is the tiled cloud on the workers."""
    return value


def task(x64: bool, fn, *args):
    """``fn(*args)`` on a worker, with JAX's 64-bit mode as on the client (only inside the task)."""
    with jax.enable_x64(x64):
        return fn(*args)


def runner(cloud: Cloud, client, k: int) -> Here:
    """Where the tiles of ``cloud`` run: here, or on the Dask ``client`` (``k`` neighbours per point in a task)."""
    return Here(cloud) if client is None else Dask(cloud, client, k)


def base(points, m: int, entry, tile: float | None, params: dict, client=None) -> tuple[Plan, Cloud]:
    """The plan before any decision that needs neighbours, and the tiled cloud (a lazy source's census on ``client``).

    Args:
      points: validated (N, 3) points (an ``np.memmap`` streams from disk), or a :class:`Source`.
      m: the number kept.
      entry: the scoring method (:class:`hgjax.Method`); its ``tiling`` validates ``params``.
      tile: validated tile edge, or None for one tile.
    """
    if isinstance(points, Source):
        n, (bmin, bmax), dtype = points.n, points.bounds(), spatial.working_dtype(np.float64)
    else:
        n, (bmin, bmax), dtype = points.shape[0], bounds(points), spatial.working_dtype(points.dtype)
    build, score = entry.tiling.params(n, params)
    origin = spatial.frame_origin(bmin, bmax, dtype)  # ValueError where dtype cannot represent the cloud
    lo, hi = bmin - origin, bmax - origin
    if isinstance(points, Source):
        cloud = points.cloud(origin, lo, hi, tile, client)
    else:
        cloud = Cloud(points, origin, lo, hi, tile, points if isinstance(points, np.memmap) else None)
    # The first halo: a few k-nearest radii per radius a neighbourhood reaches (Tiling.reach) at the
    # mean density of the occupied tiles (a surface crossing a cube of edge t with n points has a
    # spacing of about t / sqrt(n)).
    k, radii = entry.tiling.reach(build)
    spacing = 0.0 if tile is None else tile * np.sqrt(len(cloud.occupied()) / n)
    halo = HALO_SPACINGS * radii * spacing * np.sqrt(k)
    return Plan(entry.name, n, m, origin, lo, hi, tile, dtype, build, score, halo=float(halo), tiling=entry.tiling), cloud


def resolved(plan_: Plan, runner: Here) -> Plan:
    """The plan with the build parameters that depend on the seeded sample (SampleStats) resolved,
    and the first halo the resolved parameters need (:attr:`hgjax._method.Tiling.halo`).

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
        build = tiling.resolve(dict(plan_.build), stats)
        halo = plan_.halo if tiling.halo is None else tiling.halo(build, plan_.halo)
        resolved_ = dataclasses.replace(plan_, build=build, halo=halo)
    wide = getattr(getattr(runner.cloud, "points", None), "dtype", np.float64)  # a lazy Source reads float64
    extent = float(np.max(np.abs([plan_.lo, plan_.hi])))
    spatial.working_dtype(wide, extent=extent, spacing=lambda: spatial.finest_spacing(stats().distinct))
    return resolved_


def bounds(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis float64 min and max, one chunk at a time (an exact reduction, in the points' dtype)."""
    bounds = [spatial.axis_bounds(pts[s:s + PASS_ROWS]) for s in range(0, pts.shape[0], PASS_ROWS)]
    return np.min([lo for lo, _ in bounds], axis=0), np.max([hi for _, hi in bounds], axis=0)


def sample_stats(runner: Here, plan_: Plan) -> spatial.SampleStats:
    """:class:`hgjax.neighbours.spatial.SampleStats` of the seeded sample (:func:`hgjax.neighbours.spatial.sample_ids`), from the tiles that own it."""
    wanted = spatial.sample_ids(plan_.n)
    cells = runner.cloud.owners(wanted)
    found = {}
    for part in runner.gather(runner.tiles(tile_stats, plan_, wanted, cells=cells)):
        found.update(part)
    distinct, other, offsets, valid = (np.array([found[g][i] for g in wanted.tolist()]) for i in range(4))
    return spatial.SampleStats(distinct.astype(np.float64), other.astype(np.float64),
                               offsets.reshape(-1, spatial.SAMPLE_K, 3), valid.reshape(-1, spatial.SAMPLE_K))


def tile_stats(cloud: Cloud, cell, plan_: Plan, wanted: np.ndarray) -> dict:
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


def tile_scores(cloud: Cloud, cell, plan_: Plan, stream: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Scores of the core points of one tile, computed on the tile and a verified halo.

    Args:
      cloud: the tiled cloud :func:`plan` returned.
      cell: the tile's grid cell (i, j, k).
      plan_: the resolved :class:`Plan`.
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


def gathered(runner: Here, parts, plan_: Plan) -> np.ndarray:
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
