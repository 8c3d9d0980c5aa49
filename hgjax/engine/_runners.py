"""Where the tiles run: one after another in this process (:class:`Here`), or each as one pure
Dask task whose results stay on the workers until gathered (:class:`Dask`); and the progress of
a pass of tile tasks (:class:`Ticker`).
"""

from __future__ import annotations

import sys
import threading
import time

import jax

from hgjax import _progress
from hgjax.engine import _grid, select

__all__ = ["Dask", "Here", "Ticker", "runner"]

KEEP_POINTS = 4_000_000  # up to this N, a run in this process keeps each tile's index (or its two-pass state)
GATHER_BATCH = 64  # per-tile summaries (65,536-bin histograms) a Dask client holds at once in a selection
TASK_BYTES = 32  # per neighbour of a core point in a tile task: an int64 index and three float64 offsets


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

    def __init__(self, cloud: _grid.Cloud):
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

    def holds(self) -> bool:
        """Whether a tile's state may wait where it was made between two passes (:mod:`hgjax.engine._passes`):
        in this process up to KEEP_POINTS points, else on disk."""
        return self.cloud.keep

    def each(self, fn, parts, *args) -> list:
        return [fn(part, *args) for part in parts]

    def gather(self, values) -> list:
        return values

    def run(self, parts):
        """``run`` of :func:`hgjax.engine.select.kth_pair`: each part's result as it is computed."""
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

    def __init__(self, cloud: _grid.Cloud, client, k: int):
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

    def holds(self) -> bool:
        """Always: a tile's state waits on the worker that made it."""
        return True

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
        """``run`` of :func:`hgjax.engine.select.kth_pair`: every part's task submitted at once, the results
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


def runner(cloud: _grid.Cloud, client, k: int) -> Here:
    """Where the tiles of ``cloud`` run: here, or on the Dask ``client`` (``k`` neighbours per point in a task)."""
    return Here(cloud) if client is None else Dask(cloud, client, k)
