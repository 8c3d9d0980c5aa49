"""Kept sets of a real scan in local and in UTM-like coordinates: library (x64 on and off) and CLI.

Usage:
  python bench/georeferenced.py        # -> bench/results/georeferenced.md

The table-and-mug scan (a seeded subset of ``--points`` points, spacing about 3 mm) is
resampled at ratio 0.2 as it is and translated by (512345.678, 4123456.789, 87.5), a UTM-like
offset. Every method's two kept sets are compared: overlap = |A & B| / |A|. Library:
``hgjax.resample`` with float64 input, JAX x64 on (float64) and off (float32 after the float64
local frame, a PrecisionWarning). CLI: ``hgjax resample in.npy -o out.npy`` (default float32
computation; a .npy output holds the kept indices).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import jax
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing

import _report  # noqa: E402
import hgjax  # noqa: E402

SCAN = HERE.parent.parent / "shared" / "data" / "scans" / "scan_table_mug.ply"
OFFSET = np.array([512_345.678, 4_123_456.789, 87.5])
METHODS = ("hkc", "hkf", "lhf", "ea", "gfr", "pca_ac", "fps", "voxel")


def overlap(a, b) -> float:
    return np.intersect1d(a, b).size / len(a)


def library(points, method, x64: bool):
    key = jax.random.key(0) if hgjax.METHODS[method].needs_key else None
    with jax.enable_x64(x64), warnings.catch_warnings():
        warnings.simplefilter("ignore", hgjax.PrecisionWarning)
        return np.asarray(hgjax.resample(points, 0.2, method=method, key=key))


def cli(path: Path, method: str, out: Path):
    subprocess.run([sys.executable, "-m", "hgjax", "resample", str(path), "-o", str(out), "--method", method,
                    "--ratio", "0.2", "--quiet"], check=True, capture_output=True)
    return np.load(out)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=60_000)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "georeferenced.md")
    args = parser.parse_args(argv)
    scan = hgjax.io.read_points(SCAN).points.astype(np.float64)
    local = scan[np.sort(np.random.default_rng(0).choice(len(scan), args.points, replace=False))]
    local -= local.min(axis=0)
    utm = local + OFFSET
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        np.save(tmp / "local.npy", local)
        np.save(tmp / "utm.npy", utm)
        for m in METHODS:
            lib = [overlap(library(local, m, x64), library(utm, m, x64)) for x64 in (True, False)]
            on_cli = overlap(cli(tmp / "local.npy", m, tmp / "a.npy"), cli(tmp / "utm.npy", m, tmp / "b.npy"))
            rows.append(f"| {m} | {lib[0]:.4f} | {lib[1]:.4f} | {on_cli:.4f} |")
            print(rows[-1], flush=True)
    _report.write(args.out, "georeferenced.py", argv, title="Georeferenced coordinates: kept sets in local and"
                  " UTM-like frames", paragraphs=[
                      f"jax {jax.__version__}. {args.points:,} points of the table-and-mug scan (seeded subset), minimum"
                      f" at the origin, against the same points + ({OFFSET[0]}, {OFFSET[1]}, {OFFSET[2]}); ratio 0.2;"
                      " overlap = |A & B| / |A| of the kept indices (target >= 0.99). Random methods use key 0"
                      " (library) and the CLI's default seed."],
                  table=["| method | library, x64 on | library, x64 off (float32) | CLI (float32) |",
                         "| --- | ---: | ---: | ---: |", *rows])

if __name__ == "__main__":
    main()
