"""Compilations across cloud sizes: a new N must not recompile the kernels.

In one process, resamples 10 box-union clouds of different N (geometric, 1e4 to 2e5) with
each scoring method, counting XLA backend compilations per method (``jax.monitoring``) and
timing, at each N, the first call against the median of repeated calls on the same cloud.
Each method first resamples one warm-up cloud of another size (N = 5000), which pays its
compilations (counted with the rest); a new N after that must compile nothing.

    python bench/compile.py [--methods hkc hkf lhf ea gfr pca_ac] [--repeats 3]

Writes bench/results/compile.md.
"""

import argparse
import os
import pathlib
import statistics
import time

import jax
import numpy as np

import hgjax

_compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: _compiles.append(duration) if event == "/jax/core/compile/backend_compile_duration"
    else None)

SIZES = np.geomspace(1e4, 2e5, 10).astype(int)
WARM_UP = 5000
SELECT = {"gfr": {"mode": "top"}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=["hkc", "hkf", "lhf", "ea", "gfr", "pca_ac"])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    clouds = {n: hgjax.eval.box_union_cloud(seed=int(n), n_points=int(n)).points for n in SIZES}
    warm_up = hgjax.eval.box_union_cloud(seed=1, n_points=WARM_UP).points
    rows = []
    for method in args.methods:
        params = SELECT.get(method, {})
        before = len(_compiles)
        hgjax.resample(warm_up, 0.2, method=method, **params)
        ratios = []
        for n, p in clouds.items():
            start = time.perf_counter()
            hgjax.resample(p, 0.2, method=method, **params)
            first = time.perf_counter() - start
            again = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                hgjax.resample(p, 0.2, method=method, **params)
                again.append(time.perf_counter() - start)
            ratios.append((n, first, statistics.median(again)))
        count = len(_compiles) - before
        rows.append((method, count, ratios))
        worst = max(r[1] / r[2] for r in ratios)
        print(method, "compilations", count, "worst first/repeat", round(worst, 2), flush=True)
    out = pathlib.Path(__file__).parent / "results" / "compile.md"
    lines = ["# Compilations across cloud sizes", "",
             f"Command: `python bench/compile.py --methods {' '.join(args.methods)} --repeats {args.repeats}`"
             f" (jax {jax.__version__}, {os.cpu_count()} cores, float64).", "",
             f"Ten box-union clouds, N = {', '.join(str(n) for n in SIZES)}, resampled at ratio 0.2 in one process."
             " Each method first resamples a warm-up cloud of N = 5000, which pays its compilations (counted)."
             " 'first / repeat' is the first call at each new N over the median of the repeated calls on the same"
             " cloud.", "",
             "| method | compilations | first / repeat at each N |", "|---|---|---|"]
    for method, count, ratios in rows:
        cells = ", ".join(f"{f / r:.2f}" for _, f, r in ratios)
        lines.append(f"| {method} | {count} | {cells} |")
    lines += ["", "Repeated-call medians (s): "]
    for method, _, ratios in rows:
        lines.append(f"- {method}: " + ", ".join(f"{n}: {r:.3f}" for n, _, r in ratios))
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
