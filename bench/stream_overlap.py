"""Host kNN and device kernel overlapped or one after the other, beside the floor, in one process.

Usage:
  python bench/stream_overlap.py --n 1000000 --repeats 5 --out bench/results/speed_stream_overlap.md

One process, float32 box surface (``bench/_report.box_cloud``). Each round times, in turn: the
floor (``cKDTree(q).query(q, k=16, workers=-1)`` on the Morton-sorted copy ``q``, tree build
included), then for LHF and EA one ``hgjax.resample(p, 0.2, method=m)`` as the library runs it
("overlapped": each batch of neighbourhoods goes to the device as soon as it is built, while the
host builds the next) and one with every neighbourhood of the tile built first and then streamed
through the same kernel ("sequential", ``hgjax._stream.map_rows``). Both give the same indices
(checked). Medians over the rounds after a warm-up round, wall and process CPU time (all threads).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import _report  # noqa: E402


def _sequential(cloud, cell, plan_, stream=None):
    """:func:`hgjax.tiles.tile_scores` with every core neighbourhood built before the kernel starts."""
    import numpy as np

    from hgjax import _stream, pipeline, spatial, tiles

    entry = pipeline.METHODS[plan_.method]

    def rows_of(index, rows):
        parts = list(entry.rows(index, rows, plan_.build, plan_.dtype))
        idx = spatial.pad_parts(index, [p[1] for p in parts], None, "neighbourhood", rows.size)
        row_args = tuple(np.concatenate(a) for a in zip(*(p[2] for p in parts)))
        return (idx, row_args), np.concatenate([p[3] for p in parts])

    gids, core, index, rows, (idx, row_args) = tiles._covered(cloud, cell, plan_.halo, plan_.build["dedupe"], rows_of)
    kernel, narrow = entry.kernel(plan_.score)
    values = _stream.map_rows(kernel, index.points, rows, idx, row_args=row_args, dtype=plan_.dtype, narrow=narrow,
                              **(stream or {}))
    return gids[core], tiles._per_point(index, rows, core, values)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10**6)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    import numpy as np
    from scipy.spatial import cKDTree

    import hgjax
    from hgjax import tiles

    p = _report.box_cloud(args.n, np.float32)
    q = p[hgjax.spatial_order(p)]
    overlapped = tiles.tile_scores
    runs = ["floor"] + [f"{m} {how}" for m in ("lhf", "ea") for how in ("overlapped", "sequential")]
    wall, cpu, kept = {r: [] for r in runs}, {r: [] for r in runs}, {}
    for rnd in range(args.repeats + 1):
        for run in runs:
            method, _, how = run.partition(" ")
            tiles.tile_scores = _sequential if how == "sequential" else overlapped
            t, c = time.perf_counter(), time.process_time()
            out = cKDTree(q).query(q, k=16, workers=-1) if run == "floor" else hgjax.resample(p, 0.2, method=method)
            w, c = time.perf_counter() - t, time.process_time() - c
            if run != "floor":
                assert method not in kept or np.array_equal(kept[method], out), f"{run} kept other points"
                kept[method] = out
            if rnd:
                wall[run].append(w)
                cpu[run].append(c)
        print(f"round {rnd}: " + ", ".join(f"{r} {wall[r][-1]:.3f} s" for r in runs if wall[r]), file=sys.stderr,
              flush=True)
    tiles.tile_scores = overlapped
    fw, fc = statistics.median(wall["floor"]), statistics.median(cpu["floor"])
    table = ["| run | wall s | / floor | CPU s | CPU / floor CPU | each round's wall / floor |", "|---|---|---|---|---|---|"]
    for run in runs:
        w, c = statistics.median(wall[run]), statistics.median(cpu[run])
        rounds = ", ".join(f"{x / f:.2f}" for x, f in zip(wall[run], wall["floor"]))
        table.append(f"| {run} | {w:.3f} | {w / fw:.2f} | {c:.3f} | {c / fc:.2f} | {rounds} |")
    paragraphs = [f"Machine: {_report.machine()}.",
                  f"N = {args.n:,}, float32 box surface; medians of {args.repeats} rounds after a warm-up round, "
                  "each round in the order of the table, all in one process; CPU = process CPU time (all threads)."]
    print("\n".join(table))
    if args.out:
        _report.write(args.out, "stream_overlap.py", None, title=f"Overlapping the host kNN with the kernel at "
                      f"N = {args.n:,}", paragraphs=paragraphs, table=table)


if __name__ == "__main__":
    main()
