"""MSS against EA end to end, side by side in ONE process (issue 22: at most 2x EA at 1e6).

Both run ``hgjax.resample(points, 0.2, method=...)`` on the same cloud
(``hgjax.eval.box_surface``, float64): one warm-up call each, then ``--rounds`` rounds in
which EA and MSS take turns, so the load of a shared machine hits both alike. Reported: the
median time of each and the median of the per-round ratios MSS / EA.

Usage (from the repository root):
  python bench/mss_speed.py                    # N = 1e6 -> bench/results/mss_speed.md
  python bench/mss_speed.py --n 100000 --out /tmp/x
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

import jax

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402
import hgjax  # noqa: E402

jax.config.update("jax_enable_x64", True)
METHODS = ("ea", "mss")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "bench" / "results")
    args = parser.parse_args(argv)
    points = hgjax.eval.box_surface(args.n, seed=0)
    for m in METHODS:
        hgjax.resample(points, 0.2, method=m)  # warm-up: compiles
    times = {m: [] for m in METHODS}
    for r in range(args.rounds):
        for m in METHODS:
            t = time.perf_counter()
            hgjax.resample(points, 0.2, method=m)
            times[m].append(time.perf_counter() - t)
        print(f"round {r}: " + ", ".join(f"{m} {times[m][-1]:.2f} s" for m in METHODS), flush=True)
    ratios = [b / a for a, b in zip(times["ea"], times["mss"])]
    table = ["| N | ea median s | mss median s | mss / ea (median of per-round ratios) | ratios |", "|---|---|---|---|---|",
             f"| {args.n:.0e} | {statistics.median(times['ea']):.2f} | {statistics.median(times['mss']):.2f} | "
             f"**{statistics.median(ratios):.2f}** | {', '.join(f'{x:.2f}' for x in ratios)} |"]
    _report.write(args.out / "mss_speed.md", "mss_speed.py", argv, title="MSS against EA, end to end, side by side",
                  paragraphs=[f"`hgjax.resample(points, 0.2, method=...)` on `box_surface({args.n}, seed=0)` "
                              f"(float64), {args.rounds} rounds after one warm-up each, EA and MSS taking turns "
                              "in one process on a 2-core machine shared with other work (absolute times vary "
                              "with its load; the per-round ratio is the figure)."], table=table)


if __name__ == "__main__":
    main()
