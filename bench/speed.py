"""Speed and memory of every method against a bare cKDTree kNN query, in one run.

Usage:
  python bench/speed.py                 # N = 1e4, 1e5, 1e6  -> bench/results/speed.md
  python bench/speed.py --scale         # adds N = 1e7 (tiled engine, float32) and a log-log PNG
  python bench/speed.py --sizes 10000 --methods hkc,ea --repeats 1 --scale --scale-n 2e5 --scale-ref 2e4 \
      --scale-tile 5e4 --out /tmp/speed_smoke.md     # smoke test of the scale path at small N
  python bench/speed.py --sizes 10000 --methods hkc,lhf --repeats 3 --out /tmp/speed.md
  python bench/speed.py --sizes 1000000 --methods lhf,lhf:reference --out bench/results/speed_lhf_reference.md
  python bench/speed.py --real          # real scans against synthetic clouds -> bench/results/speed_real.md

Each (method, N) runs in a fresh subprocess so its peak RSS is its own. Times are medians of
``--repeats`` calls after one warm-up call; the warm-up's extra time is reported as compile
time. Two yardsticks are timed in the same run, in one process, in turn: the bare kNN
``cKDTree(p).query(p, k=16, workers=-1)`` in random input order, and the floor, the same query
on the Morton-sorted copy ``p[hgjax.spatial_order(p)]`` (tree build included, sort not).
Clouds are sampled uniformly on the surface of a box (``hgjax.eval.box_surface``), float32
(``--dtype float64`` turns x64 on below 1e7; the scale rows are always float32).

At N = 1e7 (``--scale``) hkc, hkf, lhf, ea and gfr run through the tiled engine,
``hgjax.tiles.resample(points, 0.2, method=m, tile=edge)``, with the tile edge taken from the
box extent so that each occupied tile holds about 1e6 points (``_report.tile_edge``); memory is
then bounded by a tile and its halo. A method not in ``hgjax.tiles.TILED`` at run time runs in
one process (``tile=None``) and its row says so.

``--real`` times real data against synthetic clouds of the same N, all in ONE process (side
by side, so a shared machine's load hits every cloud alike): the table-and-mug scan
(``shared/data/scans/scan_table_mug.ply``), the same scan with 30 % of its points duplicated,
and a densely sampled mesh, each beside ``hgjax.eval.box_union_cloud`` of the same N, with the
bare kNN and the floor of each cloud. Every method runs once per cloud as a warm-up, then the
clouds take turns for each timed call (round robin), each call right after a floor query on the same
cloud. The method's ratio to those floors on the real cloud, over its ratio on the synthetic cloud of the
same N, is checked against the 1.2x target.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))  # run from a checkout without installing
sys.path.insert(0, str(HERE))

import _report  # noqa: E402
# Methods whose cost must scale to 1e7 (issue 6); the others are timed up to 1e6.
SCALE_METHODS = ("hkc", "hkf", "lhf", "ea", "gfr")
SCALE_TILE_POINTS = 10**6  # points per occupied tile at 1e7
# Points of the naive loop timed at 1e4, extrapolated per point (naive HKC takes ~2 s a point).
NAIVE_POINTS = {"hkc": 20, "lhf": 200}
SMALL_REPEATS = 11  # at least this many timed calls at N <= 1e4, where one call takes ~0.05 s
DATA = ROOT.parent / "shared" / "data"
REAL_SCAN = DATA / "scans" / "scan_table_mug.ply"
REAL_MESH = DATA / "meshes" / "fandisk.obj"
REAL_METHODS = ("hkc", "hkf", "lhf", "gfr", "ea", "pca_ac", "fps", "voxel")
REAL_TARGET = 1.2  # (real / its floor) / (synthetic / its floor), the same N
DUPLICATE_SHARE = 0.3


CLOUDS_ENV = "HGJAX_BENCH_CLOUDS"  # folder where the parent saved the scale cloud for its workers
DTYPE_ENV = "HGJAX_BENCH_DTYPE"  # the --dtype of the rows below the scale rows, as the parent set it
SCALE_ENV = "HGJAX_BENCH_SCALE"  # "N,reference N,points per tile" of the scale rows (--scale-n etc.)


def _scale_conf() -> tuple[int, int, int]:
    """(N of the scale rows, N of their one-process reference, points per tile), as the parent set them."""
    n, ref, per_tile = os.environ.get(SCALE_ENV, f"{10**7},{10**6},{SCALE_TILE_POINTS}").split(",")
    return int(n), int(ref), int(per_tile)


def _cloud(n: int):
    import numpy as np

    return _report.box_cloud(n, np.dtype(_dtype(n)), os.environ.get(CLOUDS_ENV))


def _dtype(n: int) -> str:
    """The dtype of the cloud of N points: float32 at the scale rows, else the --dtype."""
    return "float32" if n >= _scale_conf()[0] else os.environ.get(DTYPE_ENV, "float32")


def _method_params(method: str) -> tuple[str, dict]:
    """(name, keyword arguments) of a timed method: "lhf:reference" times LHF's non-default variant "reference"."""
    name, _, variant = method.partition(":")
    return name, {"variant": variant} if variant else {}


def _run_method(method: str, pts, tile=None):
    """``hgjax.resample`` (``tile=None``) or the tiled engine with tiles of edge ``tile``."""
    import jax

    import hgjax

    method, params = _method_params(method)
    if tile is None:
        return hgjax.resample(pts, 0.2, method=method, key=jax.random.key(0), **params)
    return hgjax.tiles.resample(pts, 0.2, method=method, tile=tile, key=jax.random.key(0), **params)


def _build(method: str, pts):
    """The host neighbourhood build that ``method`` performs: ``hgjax.neighbourhoods``."""
    import hgjax

    method, params = _method_params(method)
    if isinstance(hgjax.METHODS[method], hgjax.Sampler):
        return None  # samplers work on the points directly: no build
    return hgjax.neighbourhoods(pts, method, **params)


def worker(kind: str, n: int, repeats: int) -> dict:
    import jax

    if _dtype(n) == "float64":
        jax.config.update("jax_enable_x64", True)
    pts = _cloud(n)
    times = []
    if kind == "knn":  # bare (random order) and floor (Morton order), in turn
        knn = _report.knn_times(pts, repeats)
        return {"median": knn["bare"], "floor": knn["floor"], "peak_mb": _peak_mb()}
    if kind.startswith("naive:"):
        sys.path.insert(0, str(ROOT / "tests"))
        import naive

        method = kind.split(":", 1)[1]
        t = time.perf_counter()
        if method == "hkc":
            d = 1.3 * naive.resolution(pts[:2000]) * math.sqrt(2000 / n)
            c, lam, v = naive._kernel_spectrum(d)
            for i in range(NAIVE_POINTS[method]):
                naive.hkc_point(pts, i, c, lam, v, d)
        else:  # lhf, default lengths: one reference gamma per length
            from hgjax.scores.lhf import DEFAULT_LENGTHS

            for i in range(NAIVE_POINTS[method]):
                for length in DEFAULT_LENGTHS:
                    naive.lhf_point(pts, i, length)
        per_point = (time.perf_counter() - t) / NAIVE_POINTS[method]
        return {"median": per_point * n, "peak_mb": _peak_mb()}
    method = kind
    if n >= _scale_conf()[0]:
        return _scale_worker(method, pts, repeats)
    log = _report.SearchLog()  # the warm-up's trees and queries: the method's own search
    t = time.perf_counter()
    with log:
        _run_method(method, pts)
    first = time.perf_counter() - t
    for _ in range(repeats):
        t = time.perf_counter()
        _run_method(method, pts)
        times.append(time.perf_counter() - t)
    peak = _peak_mb()  # before the separate build timing and the floor below, which hold their own arrays
    build = []
    for _ in range(max(1, repeats // 2)):
        t = time.perf_counter()
        _build(method, pts)
        build.append(time.perf_counter() - t)
    med = statistics.median(times)
    return {"median": med, "compile": max(first - med, 0.0), "build": statistics.median(build), "peak_mb": peak,
            **_beside_floor(method, pts, repeats, log)}


def _beside_floor(method: str, pts, repeats: int, log) -> dict:
    """Rounds of (the floor, one call of ``method``, the method's own search alone) in this process: their medians.

    The floor here is the same query as the kNN process's (Morton-sorted copy, tree build
    included), timed in turn with the method, so both see the same load and the same process.
    The own search is every k-d tree the method's call builds and every query it makes on
    them (``log``, the :class:`_report.SearchLog` of its warm-up call), replayed alone: what
    the method must find, by the engines hgjax chose, with nothing beside it.
    """
    q = _report.morton_copy(pts)
    floor, paired, search, search_cpu = [], [], [], []
    for _ in range(repeats):
        floor.append(_report.knn16_seconds(q))
        t = time.perf_counter()
        _run_method(method, pts)
        paired.append(time.perf_counter() - t)
        if log.trees:
            c = time.process_time()
            search.append(log.seconds())
            search_cpu.append(time.process_time() - c)
    med = lambda v: statistics.median(v) if v else math.nan  # noqa: E731
    return {"floor_here": med(floor), "paired": med(paired), "search": med(search), "search_cpu": med(search_cpu),
            "kernel_cpu": _kernel_cpu(method, q)}


def _kernel_cpu(method: str, q) -> float:
    """CPU seconds (all threads) of ``hgjax.score`` alone on the method's neighbourhoods of ``q`` (compiled first).

    ``q`` is the Morton-sorted copy, so the kernel gathers its rows in the order the resample
    streams them; NaN for a sampler (no neighbourhoods).
    """
    import jax

    import hgjax

    nb = _build(method, q)
    if nb is None:
        return math.nan
    name, params = _method_params(method)
    jax.block_until_ready(hgjax.score(nb, name, **params))
    t = time.process_time()
    jax.block_until_ready(hgjax.score(nb, name, **params))
    return time.process_time() - t


def _scale_worker(method: str, pts, repeats: int) -> dict:
    """1e7 float32 through the tiled engine: a warm-up and a timed call, then 1e6 float32 in one process.

    The tile edge gives occupied tiles of about ``SCALE_TILE_POINTS`` points; a method not in
    ``hgjax.tiles.TILED`` runs with ``tile=None``. The 1e7 time is the second call (compile =
    first - second) and the peak RSS is read right after it. The per-point time at 1e6 comes
    from a float32 cloud run with ``hgjax.resample`` (one process, the same process), so the
    ratio is the whole cost of going to 1e7 the tiled way.
    """
    import numpy as np

    import hgjax

    _, ref_n, per_tile = _scale_conf()
    name = method.partition(":")[0]
    tiled = name in hgjax.tiles.TILED
    tile = _report.tile_edge(pts, per_tile) if tiled else None
    engine = {"engine": "one process (not in tiles.TILED)", "tiles": 1, "tile": None}
    if tile is not None:
        plan, cloud = hgjax.tiles.plan(pts, 0.2, method=name, tile=tile)
        sizes = [g.size for g in cloud.members.values()]
        engine = {"engine": "tiled", "tiles": len(sizes), "tile": tile, "largest_tile": max(sizes)}
        del plan, cloud
    calls = []
    for _ in range(2):
        t = time.perf_counter()
        _run_method(method, pts, tile)
        calls.append(time.perf_counter() - t)
    peak = _peak_mb()  # before the 1e6 reference, which is not part of the 1e7 run
    small = _report.box_cloud(ref_n, np.float32)
    _run_method(method, small)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        _run_method(method, small)
        times.append(time.perf_counter() - t)
    return {"median": calls[1], "compile": max(calls[0] - calls[1], 0.0), "build": math.nan,
            "us_per_point": calls[1] / len(pts) * 1e6,
            "us_per_point_1e6": statistics.median(times) / ref_n * 1e6, "peak_mb": peak, **engine}


def _real_clouds() -> list[tuple[str, str, object]]:
    """(name, synthetic twin name, points) of the real-data comparison, in timing order."""
    import numpy as np
    import trimesh

    import hgjax

    scan = hgjax.io.read_points(REAL_SCAN).points
    n = scan.shape[0]
    rng = np.random.default_rng(0)
    copies = scan[np.sort(rng.choice(n, round(DUPLICATE_SHARE * n), replace=False))]
    dup = np.concatenate([scan, copies])[rng.permutation(n + copies.shape[0])]
    mesh = trimesh.load(REAL_MESH, force="mesh")
    dense = np.asarray(trimesh.sample.sample_surface(mesh, n, seed=0)[0], dtype=np.float64)
    syn = lambda m: np.asarray(hgjax.eval.box_union_cloud(seed=0, n_points=m).points, dtype=np.float64)
    return [("mug scan", "synthetic", scan), (f"mug + {DUPLICATE_SHARE:.0%} duplicates", "synthetic dup N", dup),
            (f"{REAL_MESH.stem} dense", "synthetic", dense), ("synthetic", None, syn(n)),
            ("synthetic dup N", None, syn(dup.shape[0]))]


def real_worker(methods, repeats: int) -> dict:
    """Warm end-to-end times of ``methods``, the bare kNN and the floor on every real-data cloud, one process."""
    import jax

    import hgjax

    jax.config.update("jax_enable_x64", True)
    clouds = _real_clouds()
    out = {"clouds": [(name, twin, int(p.shape[0])) for name, twin, p in clouds], "times": {}, "beside": {},
           "search": {}}

    def timed(fn) -> float:
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    morton = {name: _report.morton_copy(p) for name, _, p in clouds}
    for m in ["knn", "floor"] + list(methods):
        yardstick = m in ("knn", "floor")
        if m == "knn":
            call = lambda name, p: _report.knn16_seconds(p)
        elif m == "floor":
            call = lambda name, p: _report.knn16_seconds(morton[name])
        else:
            params = {"mode": "top"} if m == "gfr" else {}
            call = lambda name, p, m=m, params=params: hgjax.resample(p, 0.2, method=m, **params)
        times, beside, search = ({name: [] for name, _, _ in clouds} for _ in range(3))
        logs = {name: _report.SearchLog() for name, _, _ in clouds}
        for name, _, p in clouds:
            with logs[name]:  # warm-up; a method's trees and queries recorded (the yardsticks build none of hgjax's)
                call(name, p)
        for _ in range(repeats):
            for name, _, p in clouds:
                if not yardstick:  # the floor of this cloud just before each call of a method
                    beside[name].append(_report.knn16_seconds(morton[name]))
                times[name].append(timed(lambda name=name, p=p, call=call: call(name, p)))
                if logs[name].trees:  # then the method's own search alone
                    search[name].append(logs[name].seconds())
        out["times"][m] = times
        if not yardstick:
            out["beside"][m] = beside
        if all(search.values()):
            out["search"][m] = search
        print(f"{m}: " + ", ".join(f"{k} {statistics.median(v):.3f}" for k, v in times.items()),
              file=sys.stderr, flush=True)
    out["peak_mb"] = _peak_mb()
    return out


def real_report(r: dict, repeats: int, command: str) -> list[str]:
    """Markdown of :func:`real_worker`'s result."""
    medians = lambda runs: {m: {c: statistics.median(v) for c, v in t.items()} for m, t in runs.items()}
    med, floor, search = medians(r["times"]), medians(r["beside"]), medians(r.get("search", {}))
    sizes = {name: n for name, _, n in r["clouds"]}
    real = [(name, twin) for name, twin, _ in r["clouds"] if twin is not None]
    lines = [
        "# Speed on real scans against synthetic clouds of the same N",
        "",
        f"Command: `{command}`  ",
        f"Machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, device {_device()}, "
        f"jax {__import__('jax').__version__}, {time.strftime('%Y-%m-%d')}; float64 (x64), one process "
        f"(peak RSS {r['peak_mb']:.0f} MB).  ",
        f"Clouds: the mug scan ({REAL_SCAN.relative_to(ROOT.parent)}); the same scan with "
        f"{DUPLICATE_SHARE:.0%} of its points duplicated (seed 0, shuffled); {REAL_MESH.name} sampled "
        "uniformly (trimesh, seed 0) to the scan's N; `box_union_cloud(seed=0, n_points=N)` of the same N "
        "(synthetic).  ",
        f"Warm end-to-end `hgjax.resample(points, 0.2, method=m)` (gfr: mode=\"top\"), median of {repeats} calls "
        "after one warm-up per cloud, the clouds timed in turn; kNN = bare "
        "`cKDTree(p).query(p, k=16, workers=-1)` of the same cloud (build included), floor = the same on its "
        "Morton-sorted copy `p[hgjax.spatial_order(p)]` (sort not timed); "
        "/ its floor = the method's time / the floor of the same cloud timed just before each of the method's calls "
        "(rounds of the floor, then the method: the median of those floors; the floor row is timed on its own); "
        f"ratio = (real / its floor) / (synthetic / its floor), the method's ratio on the real cloud against "
        f"its ratio on the synthetic cloud of the same N, target <= {REAL_TARGET}; own search = every k-d tree "
        "the method's call builds and every query it makes on that cloud (recorded in the warm-up, "
        "`_report.SearchLog`), replayed alone right after each of its calls: search ratio = the same ratio "
        "with each cloud's own search in place of its floor (the method's work beyond its search, real against "
        "synthetic).",
        "",
        "| cloud | N | method | real s | synthetic s | real / synthetic | real / its floor | synthetic / its floor "
        "| ratio | within 1.2x | real / own search | synthetic / own search | search ratio |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    names = {"knn": "bare kNN k=16", "floor": "floor: Morton kNN k=16"}
    for name, twin in real:
        for m in med:
            a, b = med[m][name], med[m][twin]
            base = floor.get(m, med["floor"])
            fa, fb = a / base[name], b / base[twin]
            ok = "" if m in names else "yes" if fa / fb <= REAL_TARGET else "**no**"
            own = ""
            if m in search:
                sa, sb = a / search[m][name], b / search[m][twin]
                own = f" {sa:.2f} | {sb:.2f} | {sa / sb:.2f}"
            lines.append(f"| {name} | {sizes[name]:,} | {names.get(m, m)} | {a:.3f} | {b:.3f} | {a / b:.2f} | "
                         f"{fa:.2f} | {fb:.2f} | {fa / fb:.2f} | {ok} |{own or ' | |'} |")
    return lines


_peak_mb = _report.peak_mb


def _spawn(kind: str, n: int, repeats: int) -> dict:
    return _report.spawn(Path(__file__), ["--worker", kind, n, repeats])


def _device() -> str:
    import jax

    d = jax.devices()[0]
    return f"{d.platform}:{getattr(d, 'device_kind', '?')} x{len(jax.devices())}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--scale", action="store_true", help="add N = 1e7 (tiled engine) and the log-log plot")
    parser.add_argument("--scale-n", type=float, default=1e7, help="N of the --scale rows (default 1e7)")
    parser.add_argument("--scale-ref", type=float, default=1e6,
                        help="N of their one-process per-point reference (default 1e6)")
    parser.add_argument("--scale-tile", type=float, default=SCALE_TILE_POINTS,
                        help="points per occupied tile of the --scale rows (default 1e6)")
    parser.add_argument("--sizes", default="10000,100000,1000000")
    parser.add_argument("--methods", default=None, help="comma list (default: all registered)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                        help="dtype of the clouds below the scale rows (float64 turns x64 on; default float32)")
    parser.add_argument("--real", action="store_true",
                        help="real scans against synthetic clouds of the same N -> results/speed_real.md")
    parser.add_argument("--out", default=None, help="default results/speed.md (--real: results/speed_real.md)")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    if args.worker:
        kind, n, repeats = args.worker
        if kind == "real":
            print(json.dumps(real_worker(n.split(","), int(repeats))))
        else:
            print(json.dumps(worker(kind, int(n), int(repeats))))
        return

    import hgjax

    if args.real:
        methods = args.methods.split(",") if args.methods else list(REAL_METHODS)
        out = subprocess.run([sys.executable, __file__, "--worker", "real", ",".join(methods), str(args.repeats)],
                             stdout=subprocess.PIPE, text=True, cwd=ROOT, check=True)
        command = "python bench/speed.py " + " ".join(argv)
        lines = real_report(json.loads(out.stdout.strip().splitlines()[-1]), args.repeats, command.strip())
        path = Path(args.out or HERE / "results" / "speed_real.md")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return
    args.out = args.out or str(HERE / "results" / "speed.md")

    methods = args.methods.split(",") if args.methods else sorted(hgjax.METHODS)
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    scale_n = int(args.scale_n)
    os.environ[DTYPE_ENV] = args.dtype
    os.environ[SCALE_ENV] = f"{scale_n},{int(args.scale_ref)},{int(args.scale_tile)}"  # read by the workers
    sizes = [n for n in sizes if n < scale_n] + ([scale_n] if args.scale else [])
    with tempfile.TemporaryDirectory(prefix="hgjax_speed_") as clouds:
        os.environ[CLOUDS_ENV] = clouds
        if args.scale:  # saved once: the workers load it instead of sampling it (peak RSS)
            _report.save_box_cloud(scale_n, "float32", clouds)
        results = _measure(methods, sizes, args.repeats)
    lines = _table(results, methods, sizes, args, argv)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    if args.scale:
        _plot(results, methods, sizes, Path(args.out).with_suffix(".png"))
    print("\n".join(lines))


def _measure(methods, sizes, repeats: int) -> dict:
    """{(kind, N): worker result} of the yardsticks, every method and the naive loops, one process each."""
    results = {}
    for n in sizes:
        reps = max(repeats, SMALL_REPEATS) if n <= 10**4 else repeats
        scale = n >= _scale_conf()[0]
        knn = _spawn("knn", n, 1 if scale else reps)
        results[("knn", n)] = knn
        print(f"N={n:.0e} knn {knn}", file=sys.stderr, flush=True)
        for m in methods:
            if scale and m.partition(":")[0] not in SCALE_METHODS:
                continue
            if m in ("fps",) and n > 10**5:
                continue  # O(N M) by design; reported up to 1e5
            r = _spawn(m, n, reps)
            results[(m, n)] = r
            print(f"N={n:.0e} {m} {r}", file=sys.stderr, flush=True)
        if n == 10**4:
            for m in ("hkc", "lhf"):
                if m in methods:
                    results[(f"naive:{m}", n)] = _spawn(f"naive:{m}", n, 1)
    return results


def _table(results: dict, methods, sizes, args, argv) -> list[str]:
    """Markdown of :func:`_measure`'s results."""
    import hgjax

    lines = [
        "# Speed and memory",
        "",
        f"Command: `python bench/speed.py{''.join(' ' + a for a in argv)}`  ",
        f"Machine: {_report.machine()}.  ",
        f"Medians of {args.repeats} calls ({SMALL_REPEATS} at N <= 1e4) after a warm-up (at {args.scale_n:.0e}: the second of "
        f"two calls, float32, tiled engine with tiles of about {args.scale_tile:.0e} points, build not timed separately;",
        "kNN: one call of each);",
        "bare kNN = `cKDTree(p).query(p, k=16, workers=-1)` in random order; floor = the same on the Morton-sorted",
        "copy `p[hgjax.spatial_order(p)]` (tree build included, sort not), both timed in turn in one process;",
        "/ kNN and / floor = time / that yardstick of the same N in the same run;",
        "/ floor here = in the method's own process, rounds of (the floor, then one call of the method): median of",
        "those calls / median of those floors (side by side: the same process and load; the targets are read here);",
        "own search = in the same rounds, every k-d tree the method's call builds and every query it makes, recorded",
        "once and replayed alone (`_report.SearchLog`); / own search = median of the method's calls / median of those;",
        "kernel CPU / search CPU = the process CPU time (all threads) of `hgjax.score` alone on the method's",
        "neighbourhoods of the Morton-sorted copy, over that of the own search's replays (a search that keeps every",
        "core busy leaves the kernel no idle core: the method's time / own search is then at least 1 + this);",
        f"clouds {args.dtype}{' (x64 on)' * (args.dtype == 'float64')} below {args.scale_n:.0e}, float32 at {args.scale_n:.0e};",
        "build = host neighbourhood build of that method (index + query); JAX part = total - build;",
        "peak = peak RSS of the process that ran the method (MB; the kNN process holds both orders).",
        "",
        "| N | method | median s | / kNN | / floor | floor here s | / floor here | own search s | / own search "
        "| kernel CPU / search CPU | build s | JAX part / build | points/s | compile s | peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n in sizes:
        knn = results[("knn", n)]
        if "error" in knn:
            lines.append(f"| {n:.0e} | kNN k=16 | error: {knn['error']} | | | | | | | | | | | | |")
        base, floor = knn.get("median", math.nan), knn.get("floor", math.nan)
        lines.append(f"| {n:.0e} | bare kNN k=16 | {base:.3f} | 1.00 | {base / floor:.2f} |{' |' * 7} {n / base:,.0f} | | "
                     f"{knn.get('peak_mb', math.nan):.0f} |")
        lines.append(f"| {n:.0e} | floor: Morton kNN k=16 | {floor:.3f} | {floor / base:.2f} | 1.00 | | | | | | | | "
                     f"{n / floor:,.0f} | | |")
        for m in methods:
            r = results.get((m, n))
            if r is None:
                continue
            if "error" in r:
                lines.append(f"| {n:.0e} | {m} | error: {r['error']} | | | | | | | | | | | | |")
                continue
            if isinstance(hgjax.METHODS[m.partition(":")[0]], hgjax.Sampler):  # samplers: no neighbourhood build
                build, jax_part = "", ""
            else:
                ratio = (r["median"] - r["build"]) / r["build"] if r["build"] > 0 else math.nan  # nan at 1e7
                build, jax_part = (f"{r['build']:.3f}", f"{ratio:.2f}") if not math.isnan(ratio) else ("", "")
            here = (f"{r['floor_here']:.3f} | {r['paired'] / r['floor_here']:.2f}" if "floor_here" in r else " | ")
            search = r.get("search", math.nan)
            here += f" | {search:.3f} | {r['paired'] / search:.2f}" if not math.isnan(search) else " | | "
            share = r.get("kernel_cpu", math.nan) / r.get("search_cpu", math.nan)
            here += f" | {share:.2f}" if not math.isnan(share) else " | "
            lines.append(f"| {n:.0e} | {m} | {r['median']:.3f} | {r['median'] / base:.2f} | "
                         f"{r['median'] / floor:.2f} | {here} | {build} | {jax_part} | {n / r['median']:,.0f} | "
                         f"{r['compile']:.2f} | {r['peak_mb']:.0f} |")
    big = max(sizes)
    scale_rows = [(m, results[(m, big)]) for m in methods if "us_per_point" in results.get((m, big), {})]
    if scale_rows:
        lines += ["", f"Time per point, float32, {big:.0e} (tiled engine, tiles of about {args.scale_tile:.0e} "
                  "points: `hgjax.tiles.resample(p, 0.2, method=m, tile=edge)`, edge from the box extent) against "
                  f"{args.scale_ref:.0e} in one process (`hgjax.resample`, float32, same process, median of "
                  f"{args.repeats} calls); target ratio <= 1.3; peak = peak RSS of the process after the "
                  f"{big:.0e} calls, before the reference (MB):", "",
                  f"| method | engine | tiles | largest tile | tile edge | us/point {args.scale_ref:.0e} | us/point "
                  f"{big:.0e} | ratio | peak MB |", "|---|---|---|---|---|---|---|---|---|"]
        for m, r in scale_rows:
            edge = "" if r.get("tile") is None else f"{r['tile']:.4g}"
            lines.append(f"| {m} | {r['engine']} | {r['tiles']} | {r.get('largest_tile', big):,} | {edge} | "
                         f"{r['us_per_point_1e6']:.3f} | {r['us_per_point']:.3f} | "
                         f"{r['us_per_point'] / r['us_per_point_1e6']:.2f} | {r['peak_mb']:.0f} |")
    naive_rows = [(m, results[(f"naive:{m}", 10**4)]) for m in ("hkc", "lhf") if (f"naive:{m}", 10**4) in results]
    if naive_rows:
        lines += ["", "Naive NumPy loop at N = 1e4 (tests/naive.py; the first points timed in this run, "
                  "extrapolated to all N):", "", "| method | points timed | naive s (extrapolated) | hgjax s | speed-up |",
                  "|---|---|---|---|---|"]
        for m, r in naive_rows:
            fast = results[(m, 10**4)]["median"]
            lines.append(f"| {m} | {NAIVE_POINTS[m]} | {r['median']:.1f} | {fast:.3f} | {r['median'] / fast:,.0f}x |")
    return lines


def _plot(results, methods, sizes, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for m in ["knn"] + list(methods):
        xs = [n for n in sizes if "median" in results.get((m, n), {})]
        if xs:
            ax.loglog(xs, [results[(m, n)]["median"] for n in xs], "o-" if m != "knn" else "k--",
                      label="bare kNN k=16" if m == "knn" else m)
    xs = [n for n in sizes if "floor" in results.get(("knn", n), {})]
    if xs:
        ax.loglog(xs, [results[("knn", n)]["floor"] for n in xs], "k:", label="floor: Morton kNN k=16")
    ax.set_xlabel("points N")
    ax.set_ylabel("median time (s)")
    ax.set_title(f"hgjax end to end, {_device()}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
