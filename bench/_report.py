"""Writing a benchmark's Markdown result: the command that produced it, then the table."""

from __future__ import annotations

import sys
from pathlib import Path


def write(path: Path, script: str, argv, *, title: str, paragraphs: list[str], table: list[str]) -> None:
    """Write a result to ``path`` (creating its folder) and say where.

    The page: ``title``, the command that reruns ``bench/<script>`` with ``argv`` (default:
    this process's arguments), the ``paragraphs`` and the ``table`` lines.
    """
    argv = argv if argv is not None else sys.argv[1:]
    lines = [f"# {title}", "", f"Command: `python bench/{script}{''.join(f' {a}' for a in argv)}`", ""]
    for paragraph in paragraphs:
        lines += [paragraph, ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines + table + [""]))
    print(f"wrote {path}")


# Shared measuring helpers of speed.py and tiles.py (imports inside: a worker sets jax's x64 first).

CHUNK = 1 << 20  # rows per pass over a cloud that may be an np.memmap


def peak_mb() -> float:
    """Peak resident set of this process so far (MB).

    Linux's VmHWM, which starts afresh at exec; ``ru_maxrss`` (elsewhere) keeps the parent's
    resident set at the fork, so a worker started by a parent that holds a large cloud would
    report the parent's size.
    """
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # kB
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def machine() -> str:
    """One line: cores, processor, JAX device and version, UTC date and time."""
    import os
    import platform
    import time

    import jax

    d = jax.devices()[0]
    return (f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}, "
            f"{os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.0f} GiB RAM, device "
            f"{d.platform}:{getattr(d, 'device_kind', '?')} x{len(jax.devices())}, jax {jax.__version__}, "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")


def spawn(script: Path, args, timeout: float | None = None) -> dict:
    """Run ``python script *args`` in a fresh process; its last stdout line is a JSON dict.

    A failure (exit status, timeout) comes back as ``{"error": last line of stderr}``.
    """
    import json
    import subprocess

    try:
        out = subprocess.run([sys.executable, str(script), *map(str, args)], capture_output=True, text=True,
                             cwd=Path(script).resolve().parent.parent, check=False, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    if out.returncode != 0:
        lines = out.stderr.strip().splitlines()
        return {"error": lines[-1] if lines else f"exit status {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def morton_copy(points):
    """The floor's cloud: ``points[hgjax.spatial_order(points)]``."""
    import numpy as np

    import hgjax

    pts = np.asarray(points)
    return pts[hgjax.spatial_order(pts)]


def knn16_seconds(p) -> float:
    """Seconds of ``cKDTree(p).query(p, k=16, workers=-1)``, the tree build included."""
    import time

    from scipy.spatial import cKDTree

    t = time.perf_counter()
    cKDTree(p).query(p, k=16, workers=-1)
    return time.perf_counter() - t


def knn_times(points, repeats: int) -> dict:
    """Medians of the kNN16 yardsticks of ``points``, timed in turn (one call of each per round).

    ``bare``: ``cKDTree(p).query(p, k=16, workers=-1)`` in random order (as users' files come);
    ``floor``: the same on the Morton-sorted copy ``points[hgjax.spatial_order(points)]``. Both
    include the tree build; neither includes the permutation or the sort.
    """
    import statistics

    import numpy as np

    pts = np.asarray(points)
    bare = pts[np.random.default_rng(0).permutation(pts.shape[0])]
    floor = morton_copy(pts)
    times = {"bare": [], "floor": []}
    for _ in range(repeats):
        for name, p in (("bare", bare), ("floor", floor)):
            times[name].append(knn16_seconds(p))
    return {name: statistics.median(v) for name, v in times.items()}


def bounds(points) -> tuple:
    """Per-axis float64 (min, max) of an (N, 3) array, a chunk at a time (an ``np.memmap`` streams)."""
    import numpy as np

    parts = [np.asarray(points[s:s + CHUNK], dtype=np.float64) for s in range(0, points.shape[0], CHUNK)]
    return (np.min([p.min(axis=0) for p in parts], axis=0), np.max([p.max(axis=0) for p in parts], axis=0))


def tile_edge(points, per_tile: float, *, sample: int = 200_000, seed: int = 0) -> float:
    """A tile edge for ``hgjax.tiles.resample`` whose occupied tiles hold about ``per_tile`` points each.

    The edge is the box extent (largest side) over an integer k, nudged up so that k tiles span
    that side exactly (``tiles`` anchors its grid at the cloud's minimum corner; a cloud's far face
    would otherwise fill a tile of its own). k is the one whose mean points per occupied tile,
    counted on a seeded sample of ``sample`` rows, is nearest ``per_tile`` in ratio. Reads the
    cloud a chunk at a time (an ``np.memmap`` works); returns None (one tile) when k = 1 is nearest.
    """
    import numpy as np

    n = points.shape[0]
    lo, hi = bounds(points)
    extent = float((hi - lo).max())
    rows = np.sort(np.random.default_rng(seed).choice(n, min(n, sample), replace=False))
    x = np.asarray(points[rows], dtype=np.float64) - lo
    best, k = None, 1
    while True:
        edge = extent / k * (1 + 1e-6)
        occupied = np.unique(np.floor(x / edge).astype(np.int64), axis=0).shape[0]
        mean = n / occupied
        miss = abs(np.log(mean / per_tile))
        if best is None or miss < best[0]:
            best = (miss, edge if k > 1 else None)
        if mean < per_tile / 2 or occupied >= rows.size:
            return best[1]
        k += 1


def box_cloud(n: int, dtype, directory=None):
    """``hgjax.eval.box_surface(n, seed=0)`` as ``dtype``, from ``directory`` when a parent saved it there.

    A worker that only loads the saved cloud does not count the sampler's temporaries (about
    100 MB per 1e6 points) in its peak RSS; :func:`save_box_cloud` writes the file.
    """
    import numpy as np

    from hgjax.eval import box_surface

    if directory is not None:
        path = Path(directory) / f"box_surface_{n}_{np.dtype(dtype).name}.npy"
        if path.exists():
            return np.load(path)
    return box_surface(n, seed=0).astype(dtype, copy=False)


def save_box_cloud(n: int, dtype, directory) -> Path:
    """Write :func:`box_cloud` ``(n, dtype)`` under ``directory`` (once) and return the path."""
    import numpy as np

    path = Path(directory) / f"box_surface_{n}_{np.dtype(dtype).name}.npy"
    if not path.exists():
        np.save(path, box_cloud(n, dtype))
    return path


class SearchLog:
    """The host k-d tree work of calls made inside ``with log:``, kept to be replayed alone.

    Every :class:`hgjax.neighbours.kdtree.Tree` built (or first queried) inside is recorded with its
    points, and every query on it with its arguments, in the order made (queries from
    background threads included). :meth:`seconds` replays them: each tree built anew, its
    queries run one after another with nothing beside them: a method's own neighbour search
    alone, with the engines hgjax chose for each query.
    """

    def __init__(self):
        self.trees = []  # [(points, [(x, k, bound, p), ...]), ...]

    def __enter__(self):
        import threading

        from hgjax.neighbours import kdtree

        self._init, self._query, lock = kdtree.Tree.__init__, kdtree.Tree.query, threading.Lock()
        log, init, query = self, self._init, self._query

        def entry(tree) -> list:
            """The recorded queries of ``tree``."""
            if "_log" not in vars(tree):  # built before the log started: recorded from its first query
                tree._log = []
                log.trees.append((tree.points, tree._log))
            return tree._log

        def recorded_init(tree, points):
            init(tree, points)
            with lock:
                entry(tree)

        def recorded_query(tree, x, k, bound=float("inf"), p=2):
            with lock:
                entry(tree).append((x, k, bound, p))
            return query(tree, x, k, bound, p)

        kdtree.Tree.__init__, kdtree.Tree.query = recorded_init, recorded_query
        return self

    def __exit__(self, *exc):
        from hgjax.neighbours import kdtree

        kdtree.Tree.__init__, kdtree.Tree.query = self._init, self._query

    @property
    def queries(self) -> int:
        return sum(len(q) for _, q in self.trees)

    def seconds(self) -> float:
        """Wall seconds of building every recorded tree and running its recorded queries, in order."""
        import time

        from hgjax.neighbours import kdtree

        t = time.perf_counter()
        for points, queries in self.trees:
            tree = kdtree.Tree(points)
            for x, k, bound, p in queries:
                tree.query(x, k, bound, p)
        return time.perf_counter() - t
