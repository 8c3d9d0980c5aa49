"""hgjax's FPS and voxel samplers against Open3D's, side by side in one process.

Usage:
  python bench/samplers.py                      # -> bench/results/samplers.md
  python bench/samplers.py --repeats 3 --out /tmp/samplers.md

Each case is timed as the median of ``--repeats`` calls after one warm-up call (hgjax's
JAX path would compile there; the default CPU path is fpsample). Open3D is a benchmark-only
requirement (``pip install open3d``), not a dependency of hgjax. Open3D gets a
``PointCloud`` built beforehand (not timed); hgjax gets the NumPy array. One voxel row times
both from the NumPy array to NumPy points, Open3D's conversions included.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing

import _report  # noqa: E402
import hgjax  # noqa: E402
from hgjax.eval import box_union_cloud  # noqa: E402
from hgjax.io import read_points  # noqa: E402

MUG = HERE.parent.parent / "shared" / "data" / "scans" / "scan_table_mug.ply"


def median_time(fn, repeats: int) -> float:
    """Median wall time of ``repeats`` calls of ``fn`` after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def cases(mug_path: Path):
    """(name, hgjax call, Open3D call, kept by hgjax, kept by Open3D) for each case."""
    import open3d as o3d

    synthetic = box_union_cloud(seed=0, n_points=100_000).points
    mug = read_points(mug_path).points
    o3d_syn = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(synthetic, np.float64)))
    o3d_mug = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(mug, np.float64)))
    size = 0.01
    n_voxels = len(o3d_mug.voxel_down_sample(size).points)
    ratio = n_voxels / len(mug)  # the count Open3D's grid gives, reached by hgjax's search
    return [
        (f"FPS, synthetic N = {len(synthetic):,}, keep 20 %",
         lambda: hgjax.farthest_point_sample(synthetic, 0.2),
         lambda: o3d_syn.farthest_point_down_sample(20_000), 20_000, 20_000),
        (f"FPS, mug scan N = {len(mug):,}, keep 10,000",
         lambda: hgjax.farthest_point_sample(mug, 10_000 / len(mug)),
         lambda: o3d_mug.farthest_point_down_sample(10_000), 10_000, 10_000),
        (f"voxel, mug scan, voxel size {size}",
         lambda: hgjax.voxel_sample(mug, voxel_size=size),
         lambda: o3d_mug.voxel_down_sample(size), len(hgjax.voxel_sample(mug, voxel_size=size)), n_voxels),
        (f"voxel, mug scan, voxel size {size}, NumPy (N, 3) in, NumPy points out (Open3D's conversions timed)",
         lambda: mug[hgjax.voxel_sample(mug, voxel_size=size)],
         lambda: np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(mug)).voxel_down_sample(size).points),
         len(hgjax.voxel_sample(mug, voxel_size=size)), n_voxels),
        (f"voxel, mug scan, target count {n_voxels:,} (hgjax searches the size)",
         lambda: hgjax.voxel_sample(mug, ratio),
         lambda: o3d_mug.voxel_down_sample(size), len(hgjax.voxel_sample(mug, ratio)), n_voxels),
    ]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--mug", type=Path, default=MUG)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "samplers.md")
    args = parser.parse_args(argv)
    import jax
    import open3d as o3d

    rows = []
    for name, ours, theirs, n_ours, n_theirs in cases(args.mug):
        t_ours, t_theirs = median_time(ours, args.repeats), median_time(theirs, args.repeats)
        rows.append(f"| {name} | {t_ours:.4f} | {t_theirs:.4f} | {t_ours / t_theirs:.2f} | {n_ours:,} | {n_theirs:,} |")
        print(rows[-1], flush=True)
    _report.write(args.out, "samplers.py", argv, title="Samplers: hgjax against Open3D", paragraphs=[
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()},"
        f" NumPy {np.__version__}, JAX {jax.__version__} ({jax.default_backend()}), Open3D {o3d.__version__},"
        f" hgjax FPS backend `{hgjax.samplers.fps_backend('auto')}`.",
        f"Median wall time in seconds of {args.repeats} calls after one warm-up, both libraries in one process;"
        " ratio = hgjax / Open3D (below 1: hgjax faster). hgjax returns indices (exactly the count asked for);"
        " Open3D returns a new cloud (voxel: the centroid of each voxel, grid origin half a voxel below the"
        " minimum, so its count differs slightly)."],
        table=["| case | hgjax s | Open3D s | ratio | hgjax kept | Open3D kept |",
               "| --- | ---: | ---: | ---: | ---: | ---: |", *rows])

if __name__ == "__main__":
    main()
