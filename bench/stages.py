"""Where the time of ``hgjax.resample`` goes, stage by stage, beside the floor in the same process.

Usage:
  python bench/stages.py --n 1000000 --methods hkc,hkf,lhf,ea --repeats 3 --out bench/results/speed_hkc_stages.md

One process, float32 box surface (``hgjax.eval.box_surface(n, seed=0)``). Each round times, in
turn: the floor (``cKDTree(q).query(q, k=16, workers=-1)`` on the Morton-sorted copy
``q = p[hgjax.spatial_order(p)]``, tree build included), the bare kNN17 query on the same tree
(what LHF and EA query), with HKC or HKF the bare kNN64 query (the width their invariant build
queries), with gfr the bounded kNN109 query of GFR's balls (k = max_nn + 9 within the default
radius, on the same tree), and one ``hgjax.resample(p, 0.2, method=m)`` per method with the library's stage
functions wrapped by timers (inclusive times: a stage's time contains the stages called inside
it, marked by indentation; a generator's time is that of its steps; a stage run in a background
thread, the next batch's tree query, is timed there and overlaps the stages of the main thread).
Times are medians over the rounds after a warm-up round (compiles), wall and process CPU time
(all threads). The JAX kernel rows of HKC/HKF split the kernel on one streamed chunk of real
neighbourhoods (padded to the widest): the gather only, the centred scatter, the local frame,
frame + voxel counts, and the whole kernel, each a separate jitted program (its outputs written
out), least CPU time of the rounds, scaled to N rows. After each resample the method's public
build ``hgjax.neighbourhoods(p, m)`` is timed as a whole (the last row of the stage table), to
read beside the engine's own build inside the resample (the index and the rows generator).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import functools
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

# The engine's own stages, reported by hgjax.resample's public on_stage hook (hgjax.engine.STAGES["tiles"]).
ENGINE_STAGES = [("plan (bounds, grid, resolved parameters)", "plan"), ("tiles (neighbourhoods and scores)", "tiles"),
                 ("keep (global selection)", "keep")]
# (label, module path, attribute, depth): internal probes inside those stages, wrapped by timers, in the order
# of a call; they name the library's current internals and move with them.
PUBLIC = "public build: `hgjax.neighbourhoods(p, m)`, its own call after the resample"
STAGES = [
    ("resample (whole call)", "hgjax.engine._run", "run", 0),
    ("sample statistics (d_factor)", "hgjax.neighbours.spatial", "nearest_distances", 1),
    ("tile_scores (index, neighbourhoods, kernel)", "hgjax.engine._grid", "tile_scores", 1),
    ("gather (tile points in the frame, float64)", "hgjax.engine._grid.Cloud", "gather", 2),
    ("SpatialIndex (Morton sort, dedupe, tree)", "hgjax.neighbours.spatial.SpatialIndex", "__init__", 2),
    ("spatial_order (Morton codes and sort)", "hgjax.neighbours.spatial", "spatial_order", 3),
    ("device_points (the tile's points to the device)", "hgjax._stream", "device_points", 2),
    ("rows: LHF/EA k-nearest batches (generator steps)", "hgjax.scores.ea", "tile_rows", 2),
    ("rows: HKC/HKF cube batches (generator steps)", "hgjax.scores.cubic_kernel", "row_batches", 2),
    ("neighbours: exact kNN17 + tie ranking (LHF/EA; HKC/HKF: kNN18 of spacings)",
     "hgjax.neighbours.spatial.SpatialIndex", "neighbours", 3),
    ("tree queries (nearest: LHF/EA kNN17, in the background thread; HKC/HKF batch kNN~64)",
     "hgjax.neighbours.spatial.SpatialIndex", "nearest", 3),
    ("local_spacing", "hgjax.neighbours.spatial", "local_spacing", 3),
    ("chunked_knn (spacing of rows outside the batch)", "hgjax.neighbours.spatial", "chunked_knn", 4),
    ("cube: the ball rows", "hgjax.neighbours.spatial.SpatialIndex", "cube", 3),
    ("_cube_query (re-queries of wider rows)", "hgjax.neighbours.spatial.SpatialIndex", "_cube_query", 4),
    ("_ranked (tie ranking: lexsort)", "hgjax.neighbours.spatial.SpatialIndex", "_ranked", 3),
    ("covers (halo check)", "hgjax.engine._grid.Cloud", "covers", 2),
    ("NarrowStream.push (HKC/HKF rows routed by width, chunks dispatched as built)", "hgjax._stream.NarrowStream",
     "push", 2),
    ("NarrowStream.collect (the last chunks, then waiting for the kernel)", "hgjax._stream.NarrowStream", "collect", 2),
    ("Stream.push (chunks dispatched as built)", "hgjax._stream.Stream", "push", 2),
    ("Stream.collect (the last chunk, then waiting for the kernel)", "hgjax._stream.Stream", "collect", 2),
    ("_tile_graph (GFR graph and exact pair sums)", "hgjax.scores.gfr", "_tile_graph", 1),
    ("_kept (bounded kNN queries, k = max_nn + 9: what each location keeps, and cuts)", "hgjax.neighbours.radius_graph", "_kept",
     2),
    ("_kept_back (the kept lists read the other way)", "hgjax.neighbours.radius_graph", "_kept_back", 2),
    ("_in_ball (0 < q < r from the tree's distances)", "hgjax.neighbours.radius_graph", "_in_ball", 3),
    ("pair_sums (exact sums of c, c q, c q^2: the moment kernel's row sums)", "hgjax.scores.gfr", "pair_sums", 2),
    ("pair_lengths (q kernel: float64 q)", "hgjax.scores.gfr", "pair_lengths", 3),
    ("ExactSum.of", "hgjax.engine.select.ExactSum", "of", 3),
    ("_tile_norms (GFR flows and row sums)", "hgjax.scores.gfr", "_tile_norms", 1),
    ("laplacian_norms (flow kernel, rows summed on the device)", "hgjax.scores.gfr", "laplacian_norms", 2),
    ("row_sums (rows summed in global-id order on the host)", "hgjax.scores.gfr", "row_sums", 3),
    ("per_point (scores of the core points)", "hgjax.engine._grid", "per_point", 2),
    ("LHF tiled_select (Gamma_a, Gamma_b, mix)", "hgjax.scores.lhf", "tiled_select", 1),
    ("selection (exact top-k)", "hgjax.engine.select", "top_pairs", 1),
]


def _install(totals: dict, cpu: dict) -> None:
    """Wrap every stage function with timers adding wall and process CPU seconds into ``totals[label]``
    and ``cpu[label]`` (outermost call only). A generator function is timed step by step: the
    time of each ``next`` (building one batch), not the time its consumer holds it."""
    import importlib
    import inspect

    active = collections.Counter()
    done = set()
    for label, path, attr, _ in STAGES:
        if (path, attr) in done:
            continue
        done.add((path, attr))
        last = path.rpartition(".")[2]
        mod_path, _, cls = path.rpartition(".") if last.lstrip("_")[0].isupper() else (path, "", "")
        owner = importlib.import_module(mod_path)
        if cls:
            owner = getattr(owner, cls)
        fn = getattr(owner, attr)
        labels = tuple(lab for lab, p, a, _ in STAGES if (p, a) == (path, attr))

        def timed(call, key, labels_):
            active[key] += 1
            t, c = time.perf_counter(), time.process_time()
            try:
                return call()
            finally:
                active[key] -= 1
                if not active[key]:
                    for lab in labels_:
                        totals[lab] += time.perf_counter() - t
                        cpu[lab] += time.process_time() - c

        if inspect.isgeneratorfunction(fn):
            def wrapped(*args, _fn=fn, _key=(path, attr), _labels=labels, **kwargs):
                steps = _fn(*args, **kwargs)
                while True:
                    try:
                        item = timed(lambda: next(steps), _key, _labels)
                    except StopIteration:
                        return
                    yield item
        else:
            def wrapped(*args, _fn=fn, _key=(path, attr), _labels=labels, **kwargs):
                return timed(lambda: _fn(*args, **kwargs), _key, _labels)

        setattr(owner, attr, wrapped)
        methods = importlib.import_module("hgjax.engine._registry").METHODS  # entries hold their hooks by reference
        for name, entry in methods.items():
            tiling = getattr(entry, "tiling", None)
            if tiling is None:
                continue
            hooks = {f.name: wrapped for f in dataclasses.fields(tiling) if getattr(tiling, f.name) is fn}
            passes = tiling.passes
            if passes is not None and any(getattr(passes, f.name) is fn for f in dataclasses.fields(passes)):
                hooks["passes"] = dataclasses.replace(passes, **{f.name: wrapped for f in dataclasses.fields(passes)
                                                                 if getattr(passes, f.name) is fn})
            if hooks:
                methods[name] = dataclasses.replace(entry, tiling=dataclasses.replace(tiling, **hooks))


def _kernel_split(p, method: str, repeats: int) -> dict:
    """Seconds per N rows of the HKC/HKF kernel's parts on one streamed chunk of real rows."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from hgjax import _stream
    from hgjax.neighbours import balls, spatial
    from hgjax.scores import _common, cubic_kernel, hkc, hkf

    index = spatial.SpatialIndex(spatial.local_frame(p)[0], dedupe=True)
    params = balls.resolve(balls.build_params(), spatial.sample_stats(index))
    c = _stream.chunk_rows()
    rows = np.arange(index.n // 2, index.n // 2 + c)
    parts = list(balls.row_batches(index, rows, params))
    width = max(max(int((p[1] < index.n).sum(axis=1).max()), 1) for p in parts)
    idx = np.concatenate([np.pad(p[1], ((0, 0), (0, max(width - p[1].shape[1], 0))), constant_values=index.n)[:, :width]
                          for p in parts])
    scale = np.concatenate([p[2] for p in parts])
    hi = jnp.asarray(index.points.astype(p.dtype))
    n = index.n
    own, nbr, d = jnp.asarray(rows.astype(np.int32)), jnp.asarray(idx), jnp.asarray(scale.astype(p.dtype))
    full = (hkc if method == "hkc" else hkf)._kernel(3, "invariant")

    def gather_only(o, v, d):
        return o

    def frame_only(o, v, d):
        return cubic_kernel.oriented(o, v, d)

    def counts(o, v, d):
        return cubic_kernel.kernel_signal(o, v, d, 3, "invariant")

    def cov_only(o, v, d):
        return _common.centred_entries(o / d, v)[1]

    parts = {"gather (offsets out)": gather_only, "centred scatter (6 entries out)": cov_only,
             "frame: scatter + Jacobi + turn (offsets out)": frame_only, "frame + voxel counts (27 out)": counts,
             "whole kernel (score out)": full}
    out = {}
    for name, fn in parts.items():
        run = jax.jit(functools.partial(_stream._gathered, fn))
        jax.block_until_ready(run(hi, None, n, own, nbr, (d,), ()))
        times = []
        for _ in range(repeats):
            t = time.process_time()
            jax.block_until_ready(run(hi, None, n, own, nbr, (d,), ()))
            times.append(time.process_time() - t)
        out[name] = min(times) * index.n / c
    out["columns"] = idx.shape[1]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10**6)
    ap.add_argument("--methods", default="hkc,hkf,lhf,ea")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    import jax
    import numpy as np
    from scipy.spatial import cKDTree

    import hgjax

    methods = args.methods.split(",")
    p = _report.box_cloud(args.n, np.float32)
    q = p[hgjax.spatial_order(p)]
    if "gfr" in methods:  # the default invariant radius (10 resolutions), bounded as hgjax.neighbours.radius_graph._kept bounds it
        from hgjax.neighbours import radius_graph
        stats = hgjax.neighbours.spatial.sample_stats(hgjax.neighbours.spatial.SpatialIndex(q.astype(np.float64), dedupe=True))
        gfr_bound = np.sqrt(radius_graph.squared_radius(radius_graph.RADIUS_FACTOR, stats)) * (1 + 1e-5)
    per = {m: collections.defaultdict(list) for m in methods}
    per_cpu = {m: collections.defaultdict(list) for m in methods}
    yard, yard_cpu = collections.defaultdict(list), collections.defaultdict(list)
    totals, cpu = collections.defaultdict(float), collections.defaultdict(float)
    _install(totals, cpu)
    for r in range(args.repeats + 1):
        tree = None

        def floor():
            nonlocal tree
            tree = cKDTree(q)
            tree.query(q, k=16, workers=-1)

        yardsticks = [("floor", floor), ("kNN17 query (tree reused)", lambda: tree.query(q, k=17, workers=-1))]
        if {"hkc", "hkf"} & set(methods):
            yardsticks += [("kNN64 query (tree reused)", lambda: tree.query(q, k=64, workers=-1)),
                           ("kNN64 with its tree (as SpatialIndex builds it)",
                            lambda: cKDTree(q, leafsize=16, balanced_tree=False).query(q, k=64, workers=-1))]
        if "gfr" in methods:
            yardsticks += [("GFR's ball query: kNN109 within the radius (tree reused)",
                            lambda: tree.query(q, k=109, distance_upper_bound=gfr_bound, workers=-1))]
        for name, fn in yardsticks:
            t, c = time.perf_counter(), time.process_time()
            fn()
            yard[name].append(time.perf_counter() - t)
            yard_cpu[name].append(time.process_time() - c)
        tree = None
        for m in methods:
            totals.clear()
            cpu.clear()
            engine = {}
            hgjax.resample(p, 0.2, method=m, key=jax.random.key(0),
                           on_stage=lambda name, seconds: engine.__setitem__(name, seconds))
            if r:
                for label, name in ENGINE_STAGES:
                    per[m][label].append(engine.get(name, 0.0))
                for label, _, _, _ in STAGES:
                    per[m][label].append(totals.get(label, 0.0))
                    per_cpu[m][label].append(cpu.get(label, 0.0))
            t, c = time.perf_counter(), time.process_time()
            hgjax.neighbourhoods(p, m)
            if r:
                per[m][PUBLIC].append(time.perf_counter() - t)
                per_cpu[m][PUBLIC].append(time.process_time() - c)
        print(f"round {r}: floor {yard['floor'][-1]:.3f} s", file=sys.stderr, flush=True)
    med = lambda v: statistics.median(v[1:] if len(v) > 1 else v)  # noqa: E731
    floor, floor_cpu = med(yard["floor"]), med(yard_cpu["floor"])
    lines = ["| stage | " + " | ".join(f"{m} s | {m} / floor | {m} CPU / floor CPU" for m in methods) + " |",
             "|---|" + "---|---|---|" * len(methods)]
    for label, _ in ENGINE_STAGES:  # on_stage reports wall seconds only
        vals = [statistics.median(per[m][label]) for m in methods]
        lines.append(f"| engine stage: {label} | " + " | ".join(f"{v:.3f} | {v / floor:.2f} | - " for v in vals) + " |")

    def row(name: str, vals: list) -> str:
        """A stage row: each method's (wall s, CPU s) as seconds, / floor and CPU / floor CPU."""
        return f"| {name} | " + " | ".join(f"{v:.3f} | {v / floor:.2f} | {c / floor_cpu:.2f}" for v, c in vals) + " |"

    for label, _, _, depth in STAGES:
        vals = [(statistics.median(per[m][label]), statistics.median(per_cpu[m][label])) for m in methods]
        if not any(v > 0.0005 for v, _ in vals):
            continue
        lines.append(row("&nbsp;&nbsp;" * 2 * depth + label, vals))
    lines.append(row(PUBLIC, [(statistics.median(per[m][PUBLIC]), statistics.median(per_cpu[m][PUBLIC]))
                              for m in methods]))
    yard_lines = ["| yardstick | s | / floor | CPU s | CPU / floor CPU |", "|---|---|---|---|---|"]
    for name, v in yard.items():
        c = med(yard_cpu[name])
        yard_lines.append(f"| {name} | {med(v):.3f} | {med(v) / floor:.2f} | {c:.3f} | {c / floor_cpu:.2f} |")
    kern_lines = []
    for m in methods:
        if m in ("hkc", "hkf"):
            split = _kernel_split(p, m, args.repeats)
            cols = split.pop("columns")
            kern_lines += [f"| {m} ({cols} columns) | {name} | {v:.3f} | {v / floor_cpu:.2f} |"
                           for name, v in split.items()]
    paragraphs = [
        f"Machine: {_report.machine()}.",
        f"N = {args.n:,}, float32 box surface; medians of {args.repeats} rounds after a warm-up round, all in one "
        "process. Stage times are inclusive (indented stages are inside the one above); / floor = stage time / "
        "the floor of the same run (wall), and CPU / floor CPU the same with the process CPU time of each (all "
        "threads; less sensitive to other jobs on a shared machine than wall time).",
    ]
    table = yard_lines + [""] + lines
    if kern_lines:
        table += ["", "JAX kernel parts (one chunk of real rows, each part its own jitted program, scaled to N rows):",
                  "", "| method | part | CPU s per N rows | / floor CPU |", "|---|---|---|---|"] + kern_lines
    text = "\n".join(table)
    print(text)
    if args.out:
        _report.write(args.out, "stages.py", None, title=f"Where the time goes at N = {args.n:,}",
                      paragraphs=paragraphs, table=table)


if __name__ == "__main__":
    main()
