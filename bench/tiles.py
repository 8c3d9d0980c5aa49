"""The tiled engine against one process: halo overhead, memory, identical indices, a streamed 1e8 cloud.

Usage:
  python bench/tiles.py                  # full table -> bench/results/tiles.md (hours: see below)
  python bench/tiles.py --quick          # smoke run at small N (a few minutes) -> /tmp/tiles_quick.md
  python bench/tiles.py --sizes 1e6 --methods hkc,ea --repeats 5 --stream 0 --out /tmp/tiles.md
  python bench/tiles.py --sizes 1e6,1e7 --no-scan --stream 1e8 --stream-method ea
  python bench/tiles.py --sizes "" --no-scan --stream 0 --survey 4e5 --methods ea,lhf --dask 1,2

(a) For each cloud -- ``hgjax.eval.box_surface(n, seed=0)`` as float32 at each ``--sizes`` N,
and the real scan ``shared/data/scans/scan_table_mug.ply`` read with ``hgjax.io`` at its own N
(float32) -- and each method of ``--methods`` that is in ``hgjax.tiles.TILED`` at run time (the
others are listed as skipped): one process, ``hgjax.resample(p, 0.2, method=m)``, against the
tiled engine, ``hgjax.tiles.resample(p, 0.2, method=m, tile=edge)``, on the same cloud. The
edge is taken from the box extent (``_report.tile_edge``) so that the occupied tiles hold about
min(``--per-tile``, N / ``--min-tiles``) points each: 1e6-point tiles at 1e7, and at least
``--min-tiles`` tiles at smaller N, so that every tiled row is really cut. One fresh process per
(cloud, method) times both in turn (a warm-up of each, then ``--repeats`` rounds of one call of
each; medians), checks that the indices are identical, and counts the tiles and the halo
(``tiles.plan`` + ``cloud.gather(cell, plan.halo)``: the first halo tried; a tile whose
neighbourhoods reach further is redone with a wider one). Peak RSS comes from two more fresh
processes, one call each (compile included). The kNN16 yardsticks of each cloud (bare, random
order, and the floor, Morton order, tree build included) come from one more process.

(b) ``--stream N`` (default 1e8; 0 skips it): the box surface written to a float32 ``.npy`` a
chunk at a time (``np.lib.format.open_memmap``; chunk i is ``box_surface(chunk, seed=i)``, so
N points are never in memory at once), then ``hgjax.tiles.resample(np.load(path,
mmap_mode="r"), 0.2, method=--stream-method, tile=edge)`` in a fresh process: one call, wall
time (compile included) and peak RSS (the mapped file's resident pages included), against the
8 GB target. The file is deleted afterwards.

(c) "Scale on paper": 1e10 points on 100 machines like this one, computed by
:func:`scale_on_paper` from the measured numbers of (a) and (b).

(d) ``--survey N`` (default 0: none): the box surface of N points scaled to a 100 m box, cut
into 4 LAZ files by its x and y medians (:func:`write_survey`), resampled as one survey,
``hgjax.survey.resample_files(paths, out, 0.2, method=m, tile=edge)`` (tiles of about N / 8
points), in one process and on a LocalCluster of each ``--dask`` worker count (``--threads`` each),
timed in turn in one fresh process per method (a warm-up of each, then ``--repeats`` rounds;
medians); the outputs of every run are checked equal to one process's.

Every cloud a worker reads is saved by this process first (``--tmpdir``), so a worker's peak
RSS holds no sampler temporaries. Expected run time of the defaults on a quiet 2-core machine
(hkc, lhf, ea): roughly 3 min at 1e6, 20 min at 1e7, 7 min for the 1e8 stream; gfr, once tiled,
adds about 40 min (its one-process 1e7 row may run out of memory; that row then says error).
``--timeout`` bounds each worker process.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))  # run from a checkout without installing
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

SCAN = ROOT.parent / "shared" / "data" / "scans" / "scan_table_mug.ply"
METHODS = ("hkc", "lhf", "ea", "gfr")
RATIO = 0.2
HALO_TARGET = 1.15  # tiled / one process at 1e6
STREAM_TARGET_MB = 8000
STREAM_CHUNK = 10**6
# The "scale on paper" scenario: its parameters, not results.
PAPER = {"n": 1e10, "machines": 100, "cores": 2, "ram_gb": 24, "per_tile": 1e6, "bins": 65_536, "rounds": 4,
         "hist_bytes": 8, "id_bytes": 8, "link_gbit": 10}


# ---------------------------------------------------------------- workers (fresh processes)

def _points(cloud: str, n: int, clouds: str):
    """The float32 cloud a worker runs on: the saved box surface of N points, or the scan."""
    import numpy as np

    import hgjax

    if cloud == "scan":
        return np.asarray(hgjax.io.read_points(SCAN).points, dtype=np.float32)
    return _report.box_cloud(n, np.float32, clouds)


def _one(points, method: str):
    import jax

    import hgjax

    return hgjax.resample(points, RATIO, method=method, key=jax.random.key(0))


def _tiled(points, method: str, edge: float):
    import jax

    import hgjax

    return hgjax.tiles.resample(points, RATIO, method=method, tile=edge, key=jax.random.key(0))


def halo_stats(points, method: str, edge: float) -> dict:
    """Tiles of ``edge`` and their first halo: count, largest core, halo points / core points."""
    import numpy as np

    import hgjax

    plan, cloud = hgjax.tiles.plan(points, RATIO, method=method, tile=edge)
    cores, halos = [], []
    for cell in cloud.members:
        _, _, core = cloud.gather(cell, plan.halo)
        cores.append(int(core.sum()))
        halos.append(int(core.size - core.sum()))
    cores, halos = np.array(cores), np.array(halos)
    return {"tiles": len(cores), "largest": int(cores.max()), "halo": plan.halo,
            "halo_mean": float((halos / cores).mean()), "halo_all": float(halos.sum() / cores.sum())}


def pair_worker(cloud: str, n: int, method: str, repeats: int, edge: float, clouds: str) -> dict:
    """One process and tiled on the same cloud, in turn; identical indices; tiles and halo."""
    import numpy as np

    pts = _points(cloud, n, clouds)
    runs = {"one": lambda: _one(pts, method), "tiled": lambda: _tiled(pts, method, edge)}
    times, out = {k: [] for k in runs}, {}
    for k, fn in runs.items():  # warm-up (compile)
        out[k] = np.asarray(fn())
    for _ in range(repeats):
        for k, fn in runs.items():
            t = time.perf_counter()
            out[k] = np.asarray(fn())
            times[k].append(time.perf_counter() - t)
    same = out["one"].shape == out["tiled"].shape and bool((out["one"] == out["tiled"]).all())
    differ = int((out["one"] != out["tiled"]).sum()) if out["one"].shape == out["tiled"].shape else -1
    return {"n": int(pts.shape[0]), "one": statistics.median(times["one"]), "tiled": statistics.median(times["tiled"]),
            "ratios": [t / o for o, t in zip(times["one"], times["tiled"])], "identical": same, "differ": differ,
            "kept": int(out["one"].size), **halo_stats(pts, method, edge)}


def mem_worker(cloud: str, n: int, method: str, edge: str, clouds: str) -> dict:
    """Peak RSS of one call (compile included), one process (``edge`` "none") or tiled."""
    pts = _points(cloud, n, clouds)
    t = time.perf_counter()
    _one(pts, method) if edge == "none" else _tiled(pts, method, float(edge))
    return {"wall": time.perf_counter() - t, "peak_mb": _report.peak_mb()}


def dask_worker(cloud: str, n: int, method: str, workers: int, threads: int, repeats: int, edge: float,
                clouds: str) -> dict:
    """Tiles as Dask tasks on a LocalCluster of ``workers`` processes of ``threads`` threads, beside one process.

    One process (the same tiles, no client) and the cluster in turn, ``repeats`` rounds after a
    warm-up of each (each worker compiles its kernels once); medians and the median of the
    per-round ratios; the indices are checked against one process; per-worker peak RSS from the
    workers; scheduler overhead per task = (workers x threads x wall - summed task compute time)
    / tasks of the last call; bytes per tile and call: gathered by the client (``dask.sizeof``) and
    sent between workers (the workers' ``transfer_outgoing_bytes_total``, the copies of the cloud
    each worker makes once included).
    """
    import numpy as np
    from dask.sizeof import sizeof
    from distributed import Client, LocalCluster, get_task_stream

    import hgjax

    pts = _points(cloud, n, clouds)
    want = np.asarray(_one(pts, method))
    with LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True, dashboard_address=None,
                      host="127.0.0.1") as cluster, Client(cluster) as client:
        run = lambda: hgjax.tiles.resample(pts, RATIO, method=method, tile=edge, client=client,  # noqa: E731
                                           key=__import__("jax").random.key(0))
        same = bool((np.asarray(run()) == want).all())
        _tiled(pts, method, edge)
        gathered, gather = [0], client.gather

        def counted(futures, *a, **kw):
            out = gather(futures, *a, **kw)
            gathered[0] += sizeof(out)
            return out

        client.gather = counted
        here, times = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            _tiled(pts, method, edge)
            here.append(time.perf_counter() - t)
            with get_task_stream(client) as stream:
                t = time.perf_counter()
                got = np.asarray(run())
                times.append(time.perf_counter() - t)
            same &= bool((got == want).all())
        busy = sum(stop - start for task in stream.data for action, start, stop in
                   ((s["action"], s["start"], s["stop"]) for s in task["startstops"]) if action == "compute")
        peaks = client.run(lambda: __import__("resource").getrusage(__import__("resource").RUSAGE_SELF).ru_maxrss)
        between = sum(client.run(lambda dask_worker: dask_worker.transfer_outgoing_bytes_total).values())
        tiles = len(hgjax.tiles.plan(pts, RATIO, method=method, tile=edge)[1].occupied())
    return {"wall": statistics.median(times), "one": statistics.median(here), "identical": same, "tiles": tiles,
            "client_kb_per_tile": gathered[0] / repeats / tiles / 1024,
            "worker_kb_per_tile": between / (repeats + 1) / tiles / 1024,
            "ratio": statistics.median(d / h for d, h in zip(times, here)), "tasks": len(stream.data),
            "overhead_ms": (workers * threads * times[-1] - busy) / max(len(stream.data), 1) * 1e3,
            "worker_peak_mb": max(peaks.values()) / 1024}


def write_survey(directory: str, n: int) -> list[str]:
    """The box surface of ``n`` points, x 100 (a 100 m box), as 4 LAZ files cut at its x and y medians."""
    import numpy as np

    import hgjax

    p = _report.box_cloud(n, np.float64) * 100.0
    mx, my = np.median(p[:, 0]), np.median(p[:, 1])
    paths = []
    for i, part in enumerate([(p[:, 0] < mx) & (p[:, 1] < my), (p[:, 0] < mx) & (p[:, 1] >= my),
                              (p[:, 0] >= mx) & (p[:, 1] < my), (p[:, 0] >= mx) & (p[:, 1] >= my)]):
        paths.append(str(Path(directory) / f"survey_{i}.laz"))
        hgjax.io.write_points(paths[-1], p[part])
    return paths


def survey_worker(method: str, workers: str, threads: int, repeats: int, *paths: str) -> dict:
    """A survey of ``paths`` in one process and on LocalClusters of ``workers`` (comma list) of ``threads``
    threads each, in turn round by round beside each cluster."""
    import hashlib

    import numpy as np
    from distributed import Client, LocalCluster

    import hgjax

    pts = np.concatenate([hgjax.io.read_points(q).points for q in paths])
    edge = _report.tile_edge(pts, pts.shape[0] / 8)
    del pts

    def run(client) -> tuple[float, str]:
        with tempfile.TemporaryDirectory(prefix="hgjax_survey_out_") as out:
            t = time.perf_counter()
            hgjax.survey.resample_files(list(paths), out, RATIO, method=method, tile=edge, client=client)
            wall = time.perf_counter() - t
            digest = hashlib.sha256()
            for q in paths:
                digest.update(np.ascontiguousarray(hgjax.io.read_points(Path(out) / Path(q).name).points).tobytes())
        return wall, digest.hexdigest()

    want = run(None)[1]
    res = {"n": sum(hgjax.io.header_count(q) for q in paths), "edge": edge, "dask": {}}
    for w in [int(x) for x in workers.split(",") if x]:
        with LocalCluster(n_workers=w, threads_per_worker=threads, processes=True, dashboard_address=None,
                          host="127.0.0.1") as cluster, Client(cluster) as client:
            run(client)
            one, got = [], []
            for _ in range(repeats):
                one.append(run(None))
                got.append(run(client))
        res["dask"][w] = {"one": statistics.median(t for t, _ in one), "wall": statistics.median(t for t, _ in got),
                          "ratio": statistics.median(d / h for (d, _), (h, _) in zip(got, one)),
                          "identical": all(d == want for _, d in got + one)}
    return res


def knn_worker(cloud: str, n: int, repeats: int, clouds: str) -> dict:
    return {**_report.knn_times(_points(cloud, n, clouds), repeats), "peak_mb": _report.peak_mb()}


def stream_worker(path: str, method: str, edge: str) -> dict:
    """One tiled call on the memory-mapped cloud: wall time (compile included) and peak RSS."""
    import jax  # noqa: F401  (imported before the baseline)
    import numpy as np

    import hgjax  # noqa: F401

    base = _report.peak_mb()
    pts = np.load(path, mmap_mode="r")
    t = time.perf_counter()
    kept = _tiled(pts, method, None if edge == "none" else float(edge))
    return {"n": int(pts.shape[0]), "wall": time.perf_counter() - t, "peak_mb": _report.peak_mb(),
            "base_mb": base, "kept": int(np.asarray(kept).size)}


# ---------------------------------------------------------------- this process

def write_stream_cloud(path: Path, n: int, chunk: int = STREAM_CHUNK) -> None:
    """Box-surface points into a float32 ``.npy`` at ``path``, ``chunk`` rows at a time (seed = chunk number)."""
    import numpy as np

    from hgjax.eval import box_surface

    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(n, 3))
    for i, s in enumerate(range(0, n, chunk)):
        out[s:s + chunk] = box_surface(min(chunk, n - s), seed=i)
        out.flush()
    del out


def per_tile_points(n: int, per_tile: float, min_tiles: int) -> float:
    return min(per_tile, n / min_tiles)


def _spawn(*args, timeout=None) -> dict:
    return _report.spawn(Path(__file__), ["--worker", *args], timeout=timeout)


def measure(args) -> dict:
    """Every measurement of (a) and (b): {"rows": [...], "knn": {...}, "stream": {...} or None, "skipped": [...]}."""
    import numpy as np

    import hgjax

    methods = [m for m in args.methods.split(",") if m in hgjax.tiles.TILED]
    skipped = [m for m in args.methods.split(",") if m not in hgjax.tiles.TILED]
    clouds = [("box", int(float(s))) for s in args.sizes.split(",") if s] + ([("scan", 0)] if args.scan else [])
    res = {"rows": [], "knn": {}, "stream": None, "skipped": skipped, "methods": methods}
    with tempfile.TemporaryDirectory(prefix="hgjax_tiles_", dir=args.tmpdir) as tmp:
        for cloud, n in clouds:
            if cloud == "box":
                _report.save_box_cloud(n, np.float32, tmp)
            pts = _points(cloud, n, tmp)
            n = int(pts.shape[0])
            edge = _report.tile_edge(pts, per_tile_points(n, args.per_tile, args.min_tiles))
            del pts
            name = f"{cloud} {n:.0e}" if cloud == "box" else f"{SCAN.stem} ({n:,})"
            knn = _spawn("knn", cloud, n, args.repeats, tmp, timeout=args.timeout)
            res["knn"][name] = knn
            _log(name, "knn", knn)
            for m in methods:
                row = {"cloud": name, "method": m, "edge": edge}
                if edge is None:
                    row["error"] = "one tile at this N (raise --min-tiles)"
                else:
                    row["pair"] = _spawn("pair", cloud, n, m, args.repeats, edge, tmp, timeout=args.timeout)
                    row["mem_one"] = _spawn("mem", cloud, n, m, "none", tmp, timeout=args.timeout)
                    row["mem_tiled"] = _spawn("mem", cloud, n, m, edge, tmp, timeout=args.timeout)
                    for w in [int(x) for x in args.dask.split(",") if x]:
                        row[f"dask{w}"] = _spawn("dask", cloud, n, m, w, args.threads, args.repeats, edge, tmp,
                                                timeout=args.timeout)
                res["rows"].append(row)
                _log(name, m, row)
        if args.survey:
            paths = write_survey(tmp, args.survey)
            res["survey"] = {m: _spawn("survey", m, args.dask, args.threads, args.repeats, *paths, timeout=args.timeout)
                             for m in methods}
            _log("survey", res["survey"])
        if args.stream:
            path = Path(tmp) / f"stream_{args.stream}.npy"
            try:
                t = time.perf_counter()
                write_stream_cloud(path, args.stream)
                written = time.perf_counter() - t
                mm = np.load(path, mmap_mode="r")
                edge = _report.tile_edge(mm, per_tile_points(args.stream, args.per_tile, args.min_tiles))
                del mm
                r = _spawn("stream", path, args.stream_method, "none" if edge is None else edge, timeout=args.timeout)
                res["stream"] = {**r, "edge": edge, "write_s": written, "file_mb": path.stat().st_size / 2**20,
                                 "method": args.stream_method, "n": args.stream}
                _log("stream", args.stream_method, res["stream"])
            finally:
                path.unlink(missing_ok=True)
    return res


def _log(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def scale_on_paper(res: dict, p: dict = PAPER) -> dict:
    """The 1e10-point scenario of ``p`` from the measured rows of :func:`measure` (nothing hard-coded).

    Per-point tiled time, halo fraction and tile working set: the box row with the largest N
    (and the largest tiles) of each method; plan bytes per point: the streamed run's peak RSS / N.
    """
    rows = [r for r in res["rows"] if "pair" in r and "error" not in r["pair"] and r["cloud"].startswith("box")]
    if not rows:
        return {}
    best = {}
    for r in rows:  # the largest tiles measured, per method
        if r["method"] not in best or r["pair"]["largest"] > best[r["method"]]["pair"]["largest"]:
            best[r["method"]] = r
    tasks = math.ceil(p["n"] / p["per_tile"])
    kept = math.ceil(RATIO * p["n"])
    hist = tasks * p["rounds"] * p["bins"] * p["hist_bytes"]
    ids = kept * p["id_bytes"]
    link = p["link_gbit"] * 1e9 / 8  # bytes per second into the client
    out = {"tasks": tasks, "hist_bytes": hist, "id_bytes": ids, "transfer_s": (hist + ids) / link, "methods": {}}
    for m, r in best.items():
        pr, mem = r["pair"], r.get("mem_tiled", {})
        s_per_point = pr["tiled"] / pr["n"]
        compute = s_per_point * p["n"] / p["machines"]  # each machine runs as fast as the one measured
        out["methods"][m] = {"from": r["cloud"], "tiles": pr["tiles"], "largest": pr["largest"],
                             "us_per_point": s_per_point * 1e6, "halo_time": pr["tiled"] / pr["one"],
                             "halo_points": pr["halo_all"], "compute_s": compute,
                             "wall_s": compute + out["transfer_s"], "tile_peak_mb": mem.get("peak_mb", math.nan)}
    st = res.get("stream") or {}
    if "peak_mb" in st:
        out["plan_bytes_per_point"] = (st["peak_mb"] - st["base_mb"]) * 2**20 / st["n"]  # above the imports
        out["stream_us_per_point"] = st["wall"] / st["n"] * 1e6
    # What fills first: each candidate's use over its limit on one 24 GB machine.
    ram = p["ram_gb"] * 2**30
    per_machine = p["n"] / p["machines"]
    tile_peak = max((v["tile_peak_mb"] for v in out["methods"].values()), default=math.nan) * 2**20
    loads = {"client memory for the kept ids": ids / ram,
             "worker memory for scores and ids kept between selection rounds (12 B per point)":
                 per_machine * 12 / ram,
             "worker memory for one tile in flight (measured tiled peak)": tile_peak / ram}
    if "plan_bytes_per_point" in out:
        loads["one host planning the whole cloud as tiles.plan does today (measured bytes per point)"] = (
            out["plan_bytes_per_point"] * p["n"] / ram)
    out["loads"] = dict(sorted(loads.items(), key=lambda kv: -kv[1] if not math.isnan(kv[1]) else 0))
    return out


def report(res: dict, args) -> tuple[list[str], list[str], list[str]]:
    """(paragraphs, table lines, rows whose indices differ) of the results page."""
    paragraphs = [
        f"Machine: {_report.machine()}.",
        f"(a) One process `hgjax.resample(p, {RATIO}, method=m)` against the tiled engine "
        f"`hgjax.tiles.resample(p, {RATIO}, method=m, tile=edge)` on the same float32 cloud. Times: medians of "
        f"{args.repeats} rounds, one call of each per round after a warm-up of each, one fresh process per "
        "(cloud, method); halo overhead = tiled / one process (median), target <= "
        f"{HALO_TARGET} at 1e6. Edge from the box extent so that occupied tiles hold about min({args.per_tile:.3g}, "
        f"N / {args.min_tiles}) points (largest tile and halo columns: what that gave). Halo: the first halo width "
        "tried (`plan.halo`), halo points / core points "
        "from `cloud.gather(cell, plan.halo)`, mean over tiles and over all points. Peak MB: a fresh process "
        "per mode, one call (compile included), the cloud loaded from a saved `.npy`. floor = "
        "`cKDTree(q).query(q, k=16, workers=-1)` on the Morton-sorted copy `q = p[hgjax.spatial_order(p)]`, "
        "bare kNN = the same in random order (tree builds included, medians, in turn in one process).",
    ]
    if res["skipped"]:
        paragraphs.append("Skipped (not in `hgjax.tiles.TILED` at run time): " + ", ".join(res["skipped"]) + ".")
    table = ["| cloud | method | one process s | tiled s | tiled / one | within 1.15x | tiled / floor | tiles | "
             "largest tile | halo width | halo / core (mean of tiles) | halo / core (all) | peak MB one | "
             "peak MB tiled | indices |", "|" + "---|" * 15]
    bad = []
    for r in res["rows"]:
        pr = r.get("pair", {})
        if "error" in r or "error" in pr:
            table.append(f"| {r['cloud']} | {r['method']} | error: {r.get('error') or pr['error']} |" + " |" * 12)
            continue
        knn = res["knn"].get(r["cloud"], {})
        ratio = pr["tiled"] / pr["one"]
        ok = "yes" if ratio <= HALO_TARGET else "**no**"
        same = "identical" if pr["identical"] else f"**differ** ({pr['differ']:,} of {pr['kept']:,})"
        if not pr["identical"]:
            bad.append(f"{r['cloud']} {r['method']}")
        peak = lambda w: f"{r[w]['peak_mb']:.0f}" if "peak_mb" in r.get(w, {}) else r.get(w, {}).get("error", "")  # noqa: E731
        table.append(f"| {r['cloud']} | {r['method']} | {pr['one']:.3f} | {pr['tiled']:.3f} | {ratio:.2f} | {ok} | "
                     f"{pr['tiled'] / knn.get('floor', math.nan):.2f} | {pr['tiles']} | {pr['largest']:,} | "
                     f"{pr['halo']:.4g} | {pr['halo_mean']:.3f} | {pr['halo_all']:.3f} | {peak('mem_one')} | "
                     f"{peak('mem_tiled')} | {same} |")
    dask = [r for r in res["rows"] if any(k.startswith("dask") for k in r)]
    if dask:
        table += ["", f"Tiles as Dask tasks (`client=` a LocalCluster of {args.dask} worker processes, {args.threads}"
                  " thread(s) each, on this machine), same clouds and edges, timed in turn with the same tiles in one "
                  "process (no client) in the same fresh process; medians after a warm-up; / one process = median of "
                  "the per-round ratios, target <= 1.15; overhead per task = (workers x threads x wall - summed task "
                  "compute) / tasks; KB per tile: gathered by the client, and sent between workers (the cloud's copies "
                  "included), per call:", "",
                  "| cloud | method | one process s | workers | threads | wall s | / one process | tasks | tiles | "
                  "overhead ms/task | client KB/tile | worker KB/tile | peak MB per worker | indices |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in dask:
            for k in sorted(k for k in r if k.startswith("dask")):
                d = r[k]
                if "error" in d:
                    table.append(f"| {r['cloud']} | {r['method']} | | {k[4:]} | | error: {d['error']} |" + " |" * 8)
                    continue
                same = "identical" if d["identical"] else "**differ**"
                if not d["identical"]:
                    bad.append(f"{r['cloud']} {r['method']} dask {k[4:]}")
                table.append(f"| {r['cloud']} | {r['method']} | {d['one']:.3f} | {k[4:]} | {args.threads} | "
                             f"{d['wall']:.3f} | {d['ratio']:.2f} | {d['tasks']} | {d['tiles']} | {d['overhead_ms']:.1f} | "
                             f"{d['client_kb_per_tile']:.0f} | {d['worker_kb_per_tile']:.0f} | "
                             f"{d['worker_peak_mb']:.0f} | {same} |")
    if res.get("survey"):
        table += ["", f"(d) A survey of 4 LAZ files (`--survey`: the box surface x 100 cut at its x and y medians), "
                  "`hgjax.survey.resample_files(paths, out, 0.2, method=m, tile=edge)` with tiles of about N / 8 "
                  f"points, in one process and on a LocalCluster of {args.threads} thread(s) per worker, in turn round by "
                  "round; medians after a warm-up, / one process = median of the per-round ratios:", "",
                  "| survey points | method | one process s | workers | threads | wall s | / one process | outputs |",
                  "|---|---|---|---|---|---|---|---|"]
        for m, r in res["survey"].items():
            if "error" in r:
                table.append(f"| | {m} | error: {r['error']} | | | | | |")
                continue
            for w, d in r["dask"].items():
                if not d["identical"]:
                    bad.append(f"survey {m} dask {w}")
                table.append(f"| {r['n']:,} | {m} | {d['one']:.3f} | {w} | {args.threads} | {d['wall']:.3f} | "
                             f"{d['ratio']:.2f} | {'identical' if d['identical'] else '**differ**'} |")
    if res["knn"]:
        table += ["", "kNN16 yardsticks of the same clouds (s, medians; peak of their process):", "",
                  "| cloud | bare kNN (random order) | floor (Morton order) | bare / floor | peak MB |",
                  "|---|---|---|---|---|"]
    for name, k in res["knn"].items():
        if "error" in k:
            table.append(f"| {name} | error: {k['error']} | | | |")
        else:
            table.append(f"| {name} | {k['bare']:.3f} | {k['floor']:.3f} | {k['bare'] / k['floor']:.2f} | "
                         f"{k['peak_mb']:.0f} |")
    st = res["stream"]
    if st is not None:
        table += ["", f"(b) Streamed from disk: {st['n']:.0e} float32 points ({st['file_mb']:.0f} MB `.npy`, written "
                  f"in {STREAM_CHUNK:.0e}-point chunks in {st.get('write_s', math.nan):.0f} s, then deleted), "
                  f"`hgjax.tiles.resample(np.load(path, mmap_mode=\"r\"), {RATIO}, method=\"{st['method']}\", "
                  f"tile={st['edge'] if st['edge'] is None else format(st['edge'], '.4g')})` in a fresh process, one "
                  f"call (compile included); peak RSS includes the mapped file's resident pages; target <= "
                  f"{STREAM_TARGET_MB} MB.", "",
                  "| N | method | wall s | us / point | peak MB | within 8 GB | kept |", "|---|---|---|---|---|---|---|"]
        if "error" in st:
            table.append(f"| {st['n']:.0e} | {st['method']} | error: {st['error']} | | | | |")
        else:
            table.append(f"| {st['n']:.0e} | {st['method']} | {st['wall']:.1f} | {st['wall'] / st['n'] * 1e6:.3f} | "
                         f"{st['peak_mb']:.0f} | {'yes' if st['peak_mb'] <= STREAM_TARGET_MB else '**no**'} | "
                         f"{st['kept']:,} |")
    table += paper_lines(scale_on_paper(res))
    return paragraphs, table, bad


def paper_lines(s: dict, p: dict = PAPER) -> list[str]:
    """The "Scale on paper" section of :func:`scale_on_paper`'s result."""
    if not s:
        return []
    gb = lambda b: f"{b / 1e9:,.1f} GB"  # noqa: E731
    lines = ["", "## Scale on paper", "",
             f"{p['n']:.0e} points on {p['machines']} machines like this one ({p['cores']} cores, {p['ram_gb']} GB), "
             f"computed by `scale_on_paper` in bench/tiles.py from the rows above. Tasks: tiles of ~{p['per_tile']:.0e} "
             f"points -> {s['tasks']:,} tasks. Traffic if only per-tile summaries and kept ids travel: histograms of "
             f"{p['bins']:,} int64 bins x {p['rounds']} rounds per tile = {gb(s['hist_bytes'])}, kept ids "
             f"{RATIO} x N x {p['id_bytes']} B = {gb(s['id_bytes'])}; at an assumed {p['link_gbit']} Gbit/s into the "
             f"client, {s['transfer_s']:.0f} s. Wall time = measured tiled s/point x N / machines (each machine as "
             "fast as this one, halo included as measured) + that transfer; no scheduling or read cost added.", "",
             "| method | measured on | tiles | largest tile | tiled us/point | halo time (tiled / one) | "
             "halo points / core | compute s | wall s (h) | tile peak MB |", "|---|---|---|---|---|---|---|---|---|---|"]
    for m, v in s["methods"].items():
        lines.append(f"| {m} | {v['from']} | {v['tiles']} | {v['largest']:,} | {v['us_per_point']:.3f} | "
                     f"{v['halo_time']:.2f} | {v['halo_points']:.3f} | {v['compute_s']:,.0f} | "
                     f"{v['wall_s']:,.0f} ({v['wall_s'] / 3600:.1f}) | {v['tile_peak_mb']:.0f} |")
    if "stream_us_per_point" in s:
        lines += ["", f"The streamed run measured {s['stream_us_per_point']:.3f} us/point (compile included) and "
                  f"{s['plan_bytes_per_point']:.0f} bytes of peak RSS per point above its imports (everything "
                  "`tiles.resample` holds for the whole cloud: the grid cell of every point, the tile members, "
                  "scores, selection keys, the mapped file's resident pages; at small N compile memory "
                  "dominates it)."]
    lines += ["", "What fills first (use / one machine's memory; the first line breaks first):", ""]
    lines += [f"- {name}: {load:.2f}x" + (" **(breaks)**" if load > 1 else "") for name, load in s["loads"].items()]
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    parser.add_argument("--sizes", default="1e6,1e7", help="box-surface N, comma list (default 1e6,1e7)")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help="comma list; those not in hgjax.tiles.TILED are skipped (default hkc,lhf,ea,gfr)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scan", action=argparse.BooleanOptionalAction, default=True,
                        help="include the real scan at its own N (default yes)")
    parser.add_argument("--stream", type=float, default=1e8, help="N of the streamed row (0: none; default 1e8)")
    parser.add_argument("--stream-method", default="ea")
    parser.add_argument("--per-tile", type=float, default=1e6, help="points per occupied tile (default 1e6)")
    parser.add_argument("--min-tiles", type=int, default=8, help="tiles at least, at smaller N (default 8)")
    parser.add_argument("--tmpdir", default=None, help="where the clouds are saved (default: the system's)")
    parser.add_argument("--timeout", type=float, default=None, help="seconds per worker process (default none)")
    parser.add_argument("--dask", default="1,2", help="Dask worker counts to time beside one process ('' for none)")
    parser.add_argument("--threads", type=int, default=1, help="threads per Dask worker (default 1)")
    parser.add_argument("--survey", type=float, default=0, help="N of the 4-file LAZ survey rows (default 0: none)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: --sizes 2e4,1e5 --repeats 1 --stream 2e5 --per-tile 2.5e4 (scan included)")
    parser.add_argument("--out", default=None, help="default results/tiles.md (--quick: /tmp/tiles_quick.md)")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    if args.worker:
        kind, *a = args.worker
        fn = {"pair": lambda c, n, m, r, e, d: pair_worker(c, int(n), m, int(r), float(e), d),
              "mem": lambda c, n, m, e, d: mem_worker(c, int(n), m, e, d),
              "knn": lambda c, n, r, d: knn_worker(c, int(n), int(r), d),
              "dask": lambda c, n, m, w, t, r, e, d: dask_worker(c, int(n), m, int(w), int(t), int(r), float(e), d),
              "survey": lambda m, w, t, r, *paths: survey_worker(m, w, int(t), int(r), *paths),
              "stream": stream_worker}[kind]
        print(json.dumps(fn(*a)))
        return
    if args.quick:
        defaults = {"sizes": "1e6,1e7", "repeats": 3, "stream": 1e8, "per_tile": 1e6}
        for k, v in {"sizes": "2e4,1e5", "repeats": 1, "stream": 2e5, "per_tile": 2.5e4}.items():
            if getattr(args, k) == defaults[k]:
                setattr(args, k, v)
        args.out = args.out or "/tmp/tiles_quick.md"
    args.stream, args.survey = int(args.stream), int(args.survey)
    out = Path(args.out or HERE / "results" / "tiles.md")
    res = measure(args)
    paragraphs, table, bad = report(res, args)
    _report.write(out, "tiles.py", argv, title="Tiled engine against one process", paragraphs=paragraphs,
                  table=table)
    print(out.read_text())
    assert not bad, f"indices differ from one process: {bad}"
    print("indices: identical" if res["rows"] else "indices: no row ran")


if __name__ == "__main__":
    main()
