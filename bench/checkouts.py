"""``hgjax.resample`` of two checkouts of hgjax, alternating, each beside the floor of its own process.

Usage:
  python bench/checkouts.py --old /work/main --n 1000000 --methods hkc,hkf --rounds 3 \
      --out bench/results/speed_hkc_stream.md
  python bench/checkouts.py --old /work/main --scan ../shared/data/scans/scan_table_mug.ply --methods gfr \
      --out bench/results/speed_gfr_mug.md      # a real scan (float32) instead of the box

Each round runs one child process per checkout (old first, then this one, alternating), with
``PYTHONPATH`` set to the checkout. A child builds the float32 box surface
(``_report.box_cloud(n)``, or the ``--scan`` read by ``hgjax.io``, float32), runs every method once to compile, then times the floor
(``cKDTree(q).query(q, k=16, workers=-1)`` on the Morton-sorted copy ``q``, tree build included)
and one ``hgjax.resample(p, 0.2, method=m, key=jax.random.key(0))`` per method, wall and process CPU time (all threads),
and reports the kept indices' digest. Ratios are to the floor of the same process; the table gives
medians over the rounds, and whether both checkouts kept the same points.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _report  # noqa: E402


def child(n: int, methods: list[str], scan: Path | None = None) -> dict:
    """Floor and per-method wall and CPU seconds, and kept-index digests, in this process."""
    import jax
    import numpy as np
    from scipy.spatial import cKDTree

    import hgjax

    key = jax.random.key(0)  # the random methods' draws (GFR); the others ignore it

    p = _report.box_cloud(n, np.float32) if scan is None else np.asarray(hgjax.io.read_points(scan).points, np.float32)
    q = p[hgjax.spatial_order(p)]
    for m in methods:
        hgjax.resample(p, 0.2, method=m, key=key)
    out = {"hgjax": hgjax.__file__}
    for name in ["floor"] + methods:
        t, c = time.perf_counter(), time.process_time()
        kept = cKDTree(q).query(q, k=16, workers=-1) if name == "floor" else hgjax.resample(p, 0.2, method=name, key=key)
        out[name] = (time.perf_counter() - t, time.process_time() - c)
        if name != "floor":
            out[name + " kept"] = hashlib.sha256(np.sort(np.asarray(kept)).tobytes()).hexdigest()[:16]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", type=Path, help="the other checkout's root (required)")
    ap.add_argument("--n", type=int, default=10**6)
    ap.add_argument("--methods", default="hkc,hkf")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--scan", type=Path, default=None, help="a point file to run on instead of the box surface")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    methods = args.methods.split(",")
    if args.child:
        print(json.dumps(child(args.n, methods, args.scan)))
        return
    if args.old is None:
        ap.error("--old is required")
    checkouts = {"old": args.old.resolve(), "new": HERE.parent}
    runs = {k: [] for k in checkouts}
    for r in range(args.rounds):
        for name, root in checkouts.items():
            env = {**os.environ, "PYTHONPATH": str(root)}
            cloud = ["--scan", str(args.scan.resolve())] if args.scan else ["--n", str(args.n)]
            proc = subprocess.run([sys.executable, __file__, "--child", "--methods", args.methods, *cloud],
                                  env=env, capture_output=True, text=True)
            if proc.returncode:
                sys.exit(f"{name} child failed:\n{proc.stderr}")
            runs[name].append(json.loads(proc.stdout.strip().splitlines()[-1]))
            print(f"round {r} {name}: " + ", ".join(f"{m} {runs[name][-1][m][0]:.2f} s" for m in ["floor"] + methods),
                  file=sys.stderr, flush=True)
    lines = ["| checkout | method | s | / floor | CPU / floor CPU | kept the same points as old |",
             "|---|---|---|---|---|---|"]
    for name, root in checkouts.items():
        for m in ["floor"] + methods:
            wall = statistics.median(run[m][0] for run in runs[name])
            ratio = statistics.median(run[m][0] / run["floor"][0] for run in runs[name])
            cpu = statistics.median(run[m][1] / run["floor"][1] for run in runs[name])
            same = "" if m == "floor" else str(all(a[m + " kept"] == b[m + " kept"]
                                                     for a in runs["old"] for b in runs[name]))
            lines.append(f"| {name} ({root}) | {m} | {wall:.3f} | {ratio:.2f} | {cpu:.2f} | {same} |")
    print("\n".join(lines))
    if args.out:
        cloud = f"{args.scan.name} (float32)" if args.scan else f"N = {args.n:,}, float32 box surface"
        paragraphs = [f"Machine: {_report.machine()}.",
                      f"{cloud}; medians of {args.rounds} rounds, each checkout in its own "
                      "process per round (alternating), every ratio to the floor of the same process."]
        _report.write(args.out, "checkouts.py", None, title=f"Two checkouts on {args.scan.name if args.scan else f'N = {args.n:,}'}",
                      paragraphs=paragraphs, table=lines)


if __name__ == "__main__":
    main()
