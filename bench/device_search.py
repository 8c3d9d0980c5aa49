"""The traced neighbour search (``search="jax"``) beside the host's k-d tree, and the jitted resample.

Usage:
  python bench/device_search.py --sizes 10000,100000,1000000 --repeats 3 --out bench/results/device_search.md

Every method whose build takes ``search`` (``hgjax.METHODS``), each size in a fresh process (its
peak resident memory is that method's), on the float32 box surface (``_report.box_cloud``). Each
round times, in turn: the floor (``cKDTree`` kNN16 on the Morton-sorted copy, tree build
included), the host build (``hgjax.neighbourhoods(p, m)``), the traced build compiled once and
called with no sizes (the k-nearest kinds) or the columns an eager build recorded (balls and
graphs; the device path), the whole
resample jitted (``jax.jit(lambda q: hgjax.resample(q, 0.2, method=m, search="jax", ...))``,
for the methods that keep their top scores), the host resample, and the engine with its tiles
built by the traced search (``hgjax.tiles.resample(p, 0.2, method=m, search="jax")``, the
GPU/TPU default, where the method's tiles can). Each result is checked against the host's:
neighbour sets equal; kept indices that differ (ties of float scores at the cut may differ when
the scores are computed inside one fused program). Medians over the rounds after a warm-up;
ratios to the floor measured beside each call. Sizing: the first, cold eager traced build of the
process (seconds, XLA compilations and their seconds) and the first call of the jitted build
(compiled then). The same script runs on a GPU (``bench/gpu_check.sh``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

RATIO = 0.2
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"  # one per XLA compilation
PARAMS = {"gfr": {"mode": "top"}}  # GFR's deterministic top scores: the selection a traced resample can run


def _timed(fn) -> float:
    import jax

    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def searchable() -> list[str]:
    """The methods whose neighbourhoods the traced search builds."""
    import hgjax

    return [name for name, entry in hgjax.METHODS.items()
            if isinstance(entry, hgjax.Method) and "search" in entry.params["build"]]


def measure(n: int, method: str, repeats: int) -> dict:
    """One method at one size, in this process."""
    import jax
    import numpy as np

    import hgjax

    p = _report.box_cloud(n, np.float32)
    q = _report.morton_copy(p)
    entry = hgjax.METHODS[method]
    extra = PARAMS.get(method, {})
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, seconds, **_: compiles.append(seconds) if event == COMPILE_EVENT else None)
    t = time.perf_counter()
    eager = hgjax.neighbourhoods(p, method, search="jax")  # cold: the sizes (a ball's or graph's columns) found
    jax.block_until_ready(eager.idx)
    sizing = {"seconds": time.perf_counter() - t, "compiles": len(compiles), "compile s": sum(compiles)}
    cells = {k: v for k, v in eager.params if k == "capacity"}  # the columns a ball or graph needs; none for kNN
    build = jax.jit(lambda x: hgjax.neighbourhoods(x, method, search="jax", **cells))
    t = time.perf_counter()
    traced = build(p)
    jax.block_until_ready(traced.idx)
    sizing["jit first call s"] = time.perf_counter() - t
    host = hgjax.neighbourhoods(p, method)
    same = bool(np.array_equal(np.asarray(traced.idx), host.idx)) and int(traced.overflow) == 0
    kept = hgjax.resample(p, RATIO, method=method, **extra)
    calls = {"host build": lambda: hgjax.neighbourhoods(p, method).idx, "traced build": lambda: build(p).idx,
             "host resample": lambda: hgjax.resample(p, RATIO, method=method, **extra)}
    differ = {}
    if entry.select is None or hgjax.engine.keeps_top(entry, extra):
        whole = jax.jit(lambda x: hgjax.resample(x, RATIO, method=method, search="jax", **cells, **extra))
        calls["jitted resample"] = lambda: whole(p)
        differ["jitted resample"] = len(set(kept.tolist()) - set(np.asarray(whole(p)).tolist()))
    calls["engine, traced tiles"] = lambda: hgjax.tiles.resample(p, RATIO, method=method, search="jax", **extra)
    differ["engine, traced tiles"] = len(set(kept.tolist()) - set(calls["engine, traced tiles"]().tolist()))
    times = {"floor": [], **{name: [] for name in calls}}
    for _ in range(repeats):
        for name, fn in calls.items():
            times["floor"].append(_report.knn16_seconds(q))
            times[name].append(_timed(fn))
    return {"n": n, "method": method, **{k: statistics.median(v) for k, v in times.items()},
            "cells": cells, "sizing": sizing, "same": same,
            "differ": differ, "peak_mb": _report.peak_mb()}


def _ratio(r: dict, name: str) -> str:
    return f"{r[name] / r['floor']:.2f}" if name in r else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--methods", default=None, help="comma-separated (default: every method that takes search)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # N,method: measure in this process
    args = ap.parse_args()
    if args.one:
        n, method = args.one.split(",")
        print(json.dumps(measure(int(n), method, args.repeats)))
        return
    methods = args.methods.split(",") if args.methods else searchable()
    rows = []
    for n in map(int, args.sizes.split(",")):
        for m in methods:
            r = _report.spawn(Path(__file__), ["--one", f"{n},{m}", "--repeats", args.repeats])
            rows.append({"n": n, "method": m, **r})
            print(json.dumps(rows[-1]), flush=True)
            if args.out:  # rewritten after every row: a run cut short keeps the rows it measured
                _write(args.out, rows)
    print("\n".join(_table(rows)))


def _table(rows: list[dict]) -> list[str]:
    table = ["| N | method | floor s | host build | traced build | jitted resample | jitted resample s |"
             " host resample | engine, traced tiles | columns | traced sets == host | kept differing"
             " (jitted; engine) | cold eager build s (compiles, compile s) | jit first call s | peak MB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            table.append(f"| {r['n']:,} | {r['method']} | {r['error']} |" + " |" * 12)
            continue
        d, s = r["differ"], r["sizing"]
        cells = ", ".join(str(v) for v in r["cells"].values()) or "-"
        seconds = f"{r['jitted resample']:.3f}" if "jitted resample" in r else "-"
        table.append(f"| {r['n']:,} | {r['method']} | {r['floor']:.3f} | {_ratio(r, 'host build')} |"
                     f" {_ratio(r, 'traced build')} | {_ratio(r, 'jitted resample')} | {seconds} |"
                     f" {_ratio(r, 'host resample')} | {_ratio(r, 'engine, traced tiles')} | {cells} | {r['same']} |"
                     f" {d.get('jitted resample', '-')}; {d.get('engine, traced tiles', '-')} |"
                     f" {s['seconds']:.1f} ({s['compiles']}, {s['compile s']:.1f}) | {s['jit first call s']:.1f} |"
                     f" {r['peak_mb']:.0f} |")
    return table


def _write(out: Path, rows: list[dict]) -> None:
    _report.write(out, "device_search.py", None, title="The traced neighbour search beside the host's",
                  paragraphs=[_report.machine(), "Times are medians / the floor measured beside each call"
                              f" (the floor in seconds); kept differing: of the {RATIO:g} N kept by the host"
                              " resample, how many the other path does not keep; peak MB: the process of"
                              " that row (one per method and size)."],
                  table=_table(rows))


if __name__ == "__main__":
    main()
