"""A JAX user's trial of ``search="jax"`` under ``jit`` with no sizes passed: the host's array, or an error.

Usage:
  python bench/traced_jit.py --n 20000 --out bench/results/traced_jit.md

The README's cloud (``hgjax.eval.box_union_cloud(seed=0)``, float32), every scoring method in a
fresh process: ``jax.jit(lambda p: hgjax.resample(p, 0.2, method=m, search="jax"))`` (GFR with
``mode="top"``; PCA-AC, whose Ward selection runs on the host, as its jitted traced neighbourhoods
and score, then ``hgjax.keep``) beside ``hgjax.resample(p, 0.2, method=m)`` on the host: the share of the host's
kept points it keeps, whether the two arrays are equal (order included), the first call's seconds
(compilation included) and the median of three warm calls. Then the same compiled program on a
copy 16 times denser (the cloud scaled by 1/4: a surface holds 16 times the points per area), and
its arrays against the host's there. Last, the run-time check that stops a jitted program whose ball or
graph row outgrew its columns (:func:`hgjax.neighbours.backend.guard`, a host callback): the jitted EA build
timed with it and with it replaced by the identity, in alternating rounds.
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

METHODS = ("ea", "lhf", "mss", "pca_ac", "hkc", "hkf", "gfr")
PARAMS = {"gfr": {"mode": "top"}}


def measure(n: int, method: str) -> dict:
    """One method in this process."""
    import jax
    import numpy as np

    import hgjax

    p = hgjax.eval.box_union_cloud(seed=0, n_points=n).points.astype(np.float32)
    extra = PARAMS.get(method, {})
    if method == "pca_ac":  # a host selection: the jitted traced build and score, then the host's keep
        scored = jax.jit(lambda q: hgjax.score(hgjax.neighbourhoods(q, method, search="jax"), method))

        def jitted(q):
            return hgjax.keep(np.asarray(scored(q)), 0.2, method=method)
    else:
        jitted = jax.jit(lambda q: hgjax.resample(q, 0.2, method=method, search="jax", **extra))
    out = {}
    for name, cloud in (("cloud", p), ("16x denser", p / 4)):
        host = np.asarray(hgjax.resample(cloud, 0.2, method=method, **extra))
        t = time.perf_counter()
        try:
            got = np.asarray(jitted(cloud))
        except Exception as error:  # a ball or graph row wider than its columns stops the program
            out[name] = {"error": str(error).splitlines()[-1][:120], "seconds": time.perf_counter() - t}
            continue
        first = time.perf_counter() - t
        warm = []
        for _ in range(3):
            t = time.perf_counter()
            jax.block_until_ready(jitted(cloud))
            warm.append(time.perf_counter() - t)
        out[name] = {"overlap": len(np.intersect1d(host, got)) / len(host), "equal": bool(np.array_equal(host, got)),
                     "first s": first, "warm s": statistics.median(warm)}
    return out


def guard_cost(n: int, rounds: int = 7) -> dict:
    """Median seconds of the jitted EA build with the overflow check and without it, alternating."""
    import jax
    import numpy as np

    import hgjax
    from hgjax.neighbours import backend

    p = hgjax.eval.box_union_cloud(seed=0, n_points=n).points.astype(np.float32)
    checked = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax").idx)
    guard = backend.guard
    backend.guard = lambda overflow: overflow
    try:
        unchecked = jax.jit(lambda q: hgjax.neighbourhoods(q, "ea", search="jax").idx)
        unchecked(p).block_until_ready()
    finally:
        backend.guard = guard
    checked(p).block_until_ready()
    times = {"checked": [], "unchecked": []}
    for _ in range(rounds):
        for name, fn in (("checked", checked), ("unchecked", unchecked)):
            t = time.perf_counter()
            fn(p).block_until_ready()
            times[name].append(time.perf_counter() - t)
    return {name: statistics.median(v) for name, v in times.items()}


def _cell(r: dict) -> str:
    if "error" in r:
        return f"raised: {r['error']} | | "
    return f"{r['overlap']:.4f} | {r['equal']} | {r['first s']:.1f} | {r['warm s']:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(guard_cost(args.n) if args.one == "guard" else measure(args.n, args.one)))
        return
    table = ["| method | overlap | arrays equal | first call s | warm s | 16x denser: overlap | arrays equal |"
             " first call s | warm s |", "|---|---|---|---|---|---|---|---|---|"]
    for m in args.methods.split(","):
        r = _report.spawn(Path(__file__), ["--n", args.n, "--one", m])
        print(m, json.dumps(r), flush=True)
        if "error" in r:
            table.append(f"| {m} | failed: {r['error']} |" + " |" * 7)
        else:
            table.append(f"| {m} | {_cell(r['cloud'])} | {_cell(r['16x denser'])} |")
    cost = _report.spawn(Path(__file__), ["--n", args.n, "--one", "guard"])
    check = (f"The overflow check on the jitted EA build: {cost['checked']:.3f} s with it, {cost['unchecked']:.3f} s"
             f" without it (medians of 7 alternating rounds)." if "error" not in cost else f"check: {cost['error']}")
    print("\n".join(table + [check]))
    if args.out:
        _report.write(args.out, "traced_jit.py", None, title="search='jax' under jit with no sizes passed",
                      paragraphs=[_report.machine(), f"{args.n:,} points of the README's cloud, float32; overlap:"
                                  " the share of the host's kept points the jitted resample keeps; the 16x denser"
                                  " cloud runs through the program compiled for the first (its first call s: no"
                                  " compilation).", check], table=table)


if __name__ == "__main__":
    main()
