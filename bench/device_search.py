"""The traced neighbour search (``search="jax"``) beside the host's k-d tree, and the jitted resample.

Usage:
  python bench/device_search.py --sizes 10000,100000 --repeats 3 --out bench/results/device_search.md

One process, float32 box surface (``_report.box_cloud``). Each round times, in turn: the floor
(``cKDTree`` kNN16 on the Morton-sorted copy, tree build included), the host build of each
k-nearest method's neighbourhoods (``hgjax.neighbourhoods(p, m)``), the same with
``search="jax"`` compiled once and called with the cell capacity and edge an eager build recorded
(the device path), and the whole resample jitted (``jax.jit(lambda q: hgjax.resample(q, 0.2,
method=m, search="jax", ...))``), each result checked equal to the host's (neighbour sets; kept
set). Medians over the rounds after a warm-up; ratios to the floor measured beside each call. Peak
resident memory of the process at the end. The same script runs on a GPU (``bench/gpu_check.sh``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

METHODS = ("ea", "lhf", "mss")


def _timed(fn) -> float:
    import jax

    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def measure(n: int, repeats: int) -> list[dict]:
    import jax
    import numpy as np

    import hgjax

    p = _report.box_cloud(n, np.float32)
    q = _report.morton_copy(p)
    rows = []
    for m in METHODS:
        host = hgjax.neighbourhoods(p, m)
        eager = hgjax.neighbourhoods(p, m, search="jax")
        cells = {k: v for k, v in eager.params if k.startswith("cell_")}
        build = jax.jit(lambda x, m=m: hgjax.neighbourhoods(x, m, search="jax", **cells))
        whole = jax.jit(lambda x, m=m: hgjax.resample(x, 0.2, method=m, search="jax", **cells))
        traced = build(p)
        same = bool(np.array_equal(np.asarray(traced.idx), host.idx)) and int(traced.overflow) == 0
        kept = set(np.asarray(whole(p)).tolist()) == set(hgjax.resample(p, 0.2, method=m).tolist())
        times = {"floor": [], "host build": [], "traced build": [], "jitted resample": [], "host resample": []}
        for _ in range(repeats):
            for name, fn in (("host build", lambda: hgjax.neighbourhoods(p, m).idx),
                             ("traced build", lambda: build(p).idx), ("jitted resample", lambda: whole(p)),
                             ("host resample", lambda: hgjax.resample(p, 0.2, method=m))):
                times["floor"].append(_report.knn16_seconds(q))
                times[name].append(_timed(fn))
        med = {k: statistics.median(v) for k, v in times.items()}
        rows.append({"n": n, "method": m, **med, "cells": cells, "same": same, "kept": kept})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows = [r for n in map(int, args.sizes.split(",")) for r in measure(n, args.repeats)]
    table = ["| N | method | floor s | host build / floor | traced build / floor | jitted resample / floor |"
             " host resample / floor | cell capacity, edge | traced sets == host | kept set == host |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = r["floor"]
        table.append(f"| {r['n']:,} | {r['method']} | {f:.3f} | {r['host build'] / f:.2f} | {r['traced build'] / f:.2f} |"
                     f" {r['jitted resample'] / f:.2f} | {r['host resample'] / f:.2f} |"
                     f" {r['cells']['cell_capacity']}, {r['cells']['cell_edge']:.3g} | {r['same']} | {r['kept']} |")
    text = "\n".join(table)
    print(text)
    if args.out:
        _report.write(args.out, "device_search.py", None, title="The traced neighbour search beside the host's",
                      paragraphs=[_report.machine(), f"Peak resident memory of the process: {_report.peak_mb():.0f} MB."],
                      table=table)


if __name__ == "__main__":
    main()
