"""Where the tiled engine's time per point goes, against one process at 1e6, stage by stage, in one process.

Usage:
  python bench/tiles_overhead.py --n 4e6 --methods ea --repeats 2 --out /tmp/tiles_overhead.md

For each method, one process alternates ``hgjax.resample(q, 0.2, method=m)`` on the float32
box surface of 1e6 points (``q``) with ``hgjax.tiles.resample(p, 0.2, method=m, tile=edge)`` on
the box surface of ``--n`` points (``p``), the edge from the box extent so that the occupied
tiles hold about ``--per-tile`` points (``_report.tile_edge``); after a warm-up of each, every
round times one call of each (the 1e6 call before and after the tiled one). Each stage
(``on_stage`` of the engine: ``plan``, ``tiles``, ``keep``), the wall time and the process CPU
time (all threads) are divided by the call's N: microseconds per point, medians over the
rounds. CPU time is the steadier figure on a shared machine: a loaded machine stretches the
wall time of both calls, and unevenly. The ratio is the tiled per-point time over the 1e6 one.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

RATIO = 0.2
REFERENCE_N = 10**6
STAGES = ("plan", "tiles", "keep", "wall", "cpu")


def _timed(points, method: str, tile) -> dict:
    """Microseconds per point of one call: each stage, the wall time, the CPU time."""
    from hgjax import tiles

    got = {}
    wall, cpu = time.perf_counter(), time.process_time()
    tiles._resample(points, RATIO, method, tile, None, None, False, {}, on_stage=got.__setitem__)
    got["wall"], got["cpu"] = time.perf_counter() - wall, time.process_time() - cpu
    return {k: v / points.shape[0] * 1e6 for k, v in got.items()}


def measure(n: int, method: str, per_tile: float, repeats: int) -> dict:
    """Median us/point per stage of the 1e6 one-process calls and of the tiled calls, and the tiling."""
    import numpy as np

    from hgjax import tiles

    one, p = _report.box_cloud(REFERENCE_N, np.float32), _report.box_cloud(n, np.float32)
    edge = _report.tile_edge(p, per_tile)
    cloud = tiles.plan(p, RATIO, method=method, tile=edge)[1]
    shape = {"edge": edge, "tiles": len(cloud.members), "largest": max(v.size for v in cloud.members.values())}
    del cloud
    _timed(one, method, None), _timed(p, method, edge)  # warm-up: compiles
    rounds = {"one": [], "tiled": []}
    for _ in range(repeats):
        rounds["one"].append(_timed(one, method, None))
        rounds["tiled"].append(_timed(p, method, edge))
        rounds["one"].append(_timed(one, method, None))
    med = {k: {s: statistics.median(r.get(s, 0.0) for r in v) for s in STAGES} for k, v in rounds.items()}
    return {"shape": shape, **med}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=float, default=4e6, help="N of the tiled cloud (default 4e6)")
    parser.add_argument("--methods", default="ea", help="comma list (default ea)")
    parser.add_argument("--per-tile", type=float, default=1e6, help="points per occupied tile (default 1e6)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default="/tmp/tiles_overhead.md")
    args = parser.parse_args(argv)
    n = int(args.n)
    table = ["| method | call | N | tiles | largest tile | plan | tiles | keep | wall | CPU | wall / 1e6 | CPU / 1e6 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for method in args.methods.split(","):
        r = measure(n, method, args.per_tile, args.repeats)
        for call, size, shape in (("one process", REFERENCE_N, ("1", "")), ("tiled", n, (
                str(r["shape"]["tiles"]), f"{r['shape']['largest']:,}"))):
            m = r["one" if call == "one process" else "tiled"]
            ratio = [m[s] / r["one"][s] for s in ("wall", "cpu")]
            table.append(f"| {method} | {call} | {size:.0e} | {shape[0]} | {shape[1]} | "
                         + " | ".join(f"{m[s]:.3f}" for s in STAGES) + f" | {ratio[0]:.2f} | {ratio[1]:.2f} |")
        print(table[-2], table[-1], sep="\n", flush=True)
    _report.write(Path(args.out), "tiles_overhead.py", argv, title="Tiled engine: time per point by stage",
                  paragraphs=[f"Machine: {_report.machine()}.",
                              f"Microseconds per point, medians of {args.repeats} rounds (module docstring)."],
                  table=table)


if __name__ == "__main__":
    main()
