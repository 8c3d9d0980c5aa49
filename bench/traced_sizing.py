"""Sizing the traced balls (HKC/HKF) and graph (GFR) for ``jit``: the allocation's cost, and the update's.

Usage:
  python bench/traced_sizing.py --sizes 10000,20000 --rounds 3 --out bench/results/traced_sizing.md

The README's cloud (``hgjax.eval.box_union_cloud(seed=0)``, float32), per method and size, each
round in a fresh process with a fresh, empty compilation cache (``jax_compilation_cache_dir`` a new
temporary folder): the sizing call ``hgjax.capacity(points, method)`` (the columns a jitted build
needs, counted by the host search), its first (cold) call and the median of three warm calls, and
the XLA compilations it triggers (``jax.monitoring``'s backend-compile events). In the first round
also: the eager traced build ``hgjax.neighbourhoods(points, method, search="jax")`` (first call
and warm median, its compilations), the jitted update
``jax.jit(lambda p: hgjax.neighbourhoods(p, method, search="jax", capacity=cols))`` (first call,
warm median of three on moved points, compilations over the moves) and the host build beside it
(median of three). ``uptime``'s load averages are recorded beside each round: the machine is shared.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

METHODS = ("hkc", "hkf", "gfr")
TRACED = ("jit(_balls)", "jit(_search)", "jit(_pairs_of)", "jit(_rows)")  # the traced builds' programs


def _load() -> str:
    """``uptime``'s load averages (1, 5, 15 minutes)."""
    return ", ".join(f"{x:.1f}" for x in os.getloadavg())


def _timed(fn, *args):
    import jax

    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return time.perf_counter() - t, out


def measure(method: str, n: int, full: bool) -> dict:
    """One round in this process, from an empty compilation cache."""
    import tempfile

    import jax

    jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp(prefix="hgjax-sizing-"))
    import numpy as np

    import hgjax

    compiles, seconds = [], []

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(kwargs.get("fun_name", event))
            seconds.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listener)
    p = hgjax.eval.box_union_cloud(seed=0, n_points=n).points.astype(np.float32)
    out = {"load before": _load()}
    cold, cols = _timed(hgjax.capacity, p, method)
    out.update({"capacity": cols, "sizing cold s": cold, "sizing compiles": len(compiles)})
    out["sizing warm s"] = statistics.median(_timed(hgjax.capacity, p, method)[0] for _ in range(3))
    if full:
        del compiles[:], seconds[:]
        first, nb = _timed(lambda q: hgjax.neighbourhoods(q, method, search="jax"), p)
        out.update({"eager first s": first, "eager compiles": len(compiles), "eager compile s": sum(seconds),
                    "eager programs": dict(collections.Counter(compiles)), "eager columns": nb.idx.shape[-1]})
        out["eager warm s"] = statistics.median(
            _timed(lambda q: hgjax.neighbourhoods(q, method, search="jax"), p)[0] for _ in range(3))
        update = jax.jit(lambda q: hgjax.neighbourhoods(q, method, search="jax", capacity=cols).idx)
        del compiles[:]
        out["update first s"], got = _timed(update, p)
        moved = [p + np.float32(t) * np.sin(7 * p) for t in (0.002, 0.004, 0.006)]
        out["update warm s"] = statistics.median(_timed(update, q)[0] for q in moved)
        out["update compiles"] = compiles.count("jit(<lambda>)")
        host = [_timed(lambda q: hgjax.neighbourhoods(q, method).idx, q) for q in moved]
        out["host s"] = statistics.median(t for t, _ in host)
        out["update equals host"] = bool(np.array_equal(np.asarray(got), hgjax.neighbourhoods(p, method).idx)) and all(
            np.array_equal(np.asarray(update(q)), h) for q, (_, h) in zip(moved, host))
    out["load after"] = _load()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10000,20000")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--one", nargs=3, default=None, help=argparse.SUPPRESS)  # method n full: in this process
    args = ap.parse_args()
    if args.one:
        method, n, full = args.one
        print(json.dumps(measure(method, int(n), full == "1")))
        return
    sizing = ["| method | N | capacity | sizing cold s (rounds) | median | warm s | compiles | load (1, 5, 15 min)"
              " |", "|---|---|---|---|---|---|---|---|"]
    builds = ["| method | N | eager traced build: first s | compiles (of them in XLA s) | traced programs | warm s |"
              " jitted update: first s | warm s | compiles over 4 calls | host build s | update == host | load |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for n in (int(float(s)) for s in args.sizes.split(",")):
        for m in args.methods.split(","):
            rounds = [_report.spawn(Path(__file__), ["--one", m, n, int(r == 0)]) for r in range(args.rounds)]
            print(m, n, json.dumps(rounds), flush=True)
            bad = [r["error"] for r in rounds if "error" in r]
            if bad:
                sizing.append(f"| {m} | {n} | failed: {bad[0]} |" + " |" * 5)
                builds.append(f"| {m} | {n} | failed |" + " |" * 10)
                continue
            colds = [r["sizing cold s"] for r in rounds]
            sizing.append(f"| {m} | {n:,} | {rounds[0]['capacity']} | {', '.join(f'{c:.2f}' for c in colds)} |"
                          f" {statistics.median(colds):.2f} | {statistics.median(r['sizing warm s'] for r in rounds):.2f}"
                          f" | {max(r['sizing compiles'] for r in rounds)} |"
                          f" {'; '.join(r['load before'] for r in rounds)} |")
            r = rounds[0]
            traced = ", ".join(f"{k[4:-1]} {v}" for k, v in r["eager programs"].items() if k in TRACED)
            builds.append(f"| {m} | {n:,} | {r['eager first s']:.1f} | {r['eager compiles']}"
                          f" ({r['eager compile s']:.1f}) | {traced} | {r['eager warm s']:.2f}"
                          f" | {r['update first s']:.1f} | {r['update warm s']:.2f} | {r['update compiles']} |"
                          f" {r['host s']:.2f} | {r['update equals host']} | {r['load before']} |")
    print("\n".join(sizing + [""] + builds))
    if args.out:
        _report.write(args.out, "traced_sizing.py", None, title="Sizing the traced balls and graph for jit",
                      paragraphs=[_report.machine(), "The README's cloud, float32. Each round a fresh process with an"
                                  " empty compilation cache. Sizing: `hgjax.capacity(points, method)`, the columns a"
                                  " jitted `search=\"jax\"` build needs, counted by the host search (no traced"
                                  " program compiled); cold = its first call in the process, warm = median of 3;"
                                  " compiles = XLA backend compilations during the cold call. Load: `os.getloadavg()`"
                                  " (1, 5, 15 minutes) before each round, on a 2-core machine shared with other work."]
                      + ["\n".join(sizing),
                         "First round only: the eager traced build (`hgjax.neighbourhoods(points, method,"
                         " search=\"jax\")`, which counts its rows before writing them: one compilation of its"
                         " traced program per shape bucket, almost all of its first call), the jitted update"
                         " at the allocation (`jax.jit(lambda p: hgjax.neighbourhoods(p, method, search=\"jax\","
                         " capacity=cols))`: first call with its compilation, warm median over three moved"
                         " copies of the cloud, its compilations over the four calls) and the host build of the"
                         " same moved clouds (median of 3); update == host: the same idx on all four clouds."],
                      table=builds)


if __name__ == "__main__":
    main()
