"""Regenerate the README pictures: fandisk, an armchair and the bunny, resampled by HKC,
HKF, LHF and EA, written to bench/results/fig_<name>.png.

Run from the repository root: ``PYTHONPATH=. python bench/figures.py`` (needs the ``plot`` extra).
A quick check that writes elsewhere:
``PYTHONPATH=. python bench/figures.py --shapes fandisk --samples 2000 --out /tmp/figs``.
"""

import argparse
import pathlib
import sys

import jax
import numpy as np

import hgjax
from hgjax.io import read_points
from hgjax.plot import show_resampling

ROOT = pathlib.Path(__file__).resolve().parents[1]
MESHES = ROOT.parent / "shared" / "data" / "meshes"
OUT = ROOT / "bench" / "results"
# name: (mesh file, camera view (elevation, azimuth))
SHAPES = {
    "fandisk": ("fandisk.obj", (30.0, -50.0)),
    "chair": ("chair_armchair_kaolin.obj", (20.0, -60.0)),
    "bunny": ("bunny.ply", (10.0, 80.0)),
}
METHODS = ("hkc", "hkf", "lhf", "ea")
SAMPLES, RATIO, SEED = 12000, 0.15, 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", default=list(SHAPES), choices=list(SHAPES))
    parser.add_argument("--samples", type=int, default=SAMPLES)
    parser.add_argument("--out", type=pathlib.Path, default=OUT)
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.shapes:
        file, view = SHAPES[name]
        data = read_points(MESHES / file, samples=args.samples, seed=SEED)
        pts = data.points
        if name in ("bunny", "chair"):  # these meshes are y-up; show them z-up
            pts = pts[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])
        kept = {m: hgjax.resample(pts, RATIO, method=m, key=jax.random.key(SEED)) for m in METHODS}
        path = args.out / f"fig_{name}.png"
        show_resampling(pts, kept, view=view, path=path, panel_size=3.2,
                        title=f"{file}: {args.samples} surface samples, {RATIO:.0%} kept")
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
