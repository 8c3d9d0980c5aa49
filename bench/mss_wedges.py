"""MSS and EA on folded sheets: two flat rectangles meeting at one crease of a given dihedral angle.

A synthetic diagnostic of issue 22 (MSS below EA on clean two-plane clouds): for each dihedral angle
(the angle between the two sheets; 180 is flat), sampling regime and noise, ``SEEDS`` folded sheets
(random size, random rotation, ``hgjax.eval.solids.mesh_cloud`` labels: within the default band of the
crease) are scored by MSS and EA. Points within ``BORDER`` spacings of the sheet's open border are left
out of the scores in the "crease" columns (the border is no crease, and the question is the ordering
about the crease) and counted as non-edge in the "with border" columns.

Usage (from the repository root):
  python bench/mss_wedges.py                  # the shipped weights
  python bench/mss_wedges.py --weights DIR    # DIR/_mss_weights.py instead
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import hgjax  # noqa: E402
from hgjax.eval import solids  # noqa: E402
from hgjax.scores import mss  # noqa: E402
import train_edges  # noqa: E402

ANGLES = (30, 45, 60, 90, 120, 135, 150, 160)
NOISES = (0.0, 0.25)
SEEDS = 3
BORDER = 2.0
N_POINTS = 5000


def folded_sheet(dihedral_deg: float, rng) -> trimesh.Trimesh:
    """Two rectangles of widths a, b and length L sharing the edge along x, at the dihedral angle."""
    a, b = rng.uniform(0.5, 1.0, 2)
    length = rng.uniform(1.0, 2.0)
    t = np.deg2rad(dihedral_deg)
    v = np.array([[0, 0, 0], [length, 0, 0], [0, a, 0], [length, a, 0],
                  [0, b * np.cos(t), b * np.sin(t)], [length, b * np.cos(t), b * np.sin(t)]], float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [0, 5, 1], [0, 4, 5]])
    return trimesh.Trimesh(v, faces, process=False)


def border_distance(points_clean, mesh) -> np.ndarray:
    edges = mesh.edges_sorted
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    border = mesh.vertices[unique[counts == 1]]
    return hgjax.eval.synthetic._distance_to_segments(points_clean, border)


def run(weights):
    params = [jnp.asarray(a) for a in weights]
    logits = jax.jit(jax.vmap(mss.mlp, in_axes=(None, 0)))
    rows = []
    for regime in hgjax.eval.REGIMES:
        for noise in NOISES:
            for angle in ANGLES:
                acc = []
                for s in range(SEEDS):
                    rng = np.random.default_rng([angle, s, 7])
                    mesh = folded_sheet(angle, rng)
                    seed = int(rng.integers(1 << 30))
                    clean = solids.mesh_cloud(mesh, n_points=N_POINTS, seed=seed, regime=regime, rotate=False)
                    c = solids.mesh_cloud(mesh, n_points=N_POINTS, seed=seed, regime=regime, noise=noise,
                                          noise_kind="iso")
                    inner = border_distance(clean.points, mesh) > BORDER * c.resolution
                    model = np.asarray(logits(params, jnp.asarray(train_edges.cloud_features(c.points))))
                    ea = np.asarray(hgjax.score(hgjax.neighbourhoods(c.points, "ea"), "ea"))
                    y = c.edge_mask
                    acc.append([f(sc[m], y[m]) for m in (inner, np.ones_like(inner))
                                for sc in (model, ea) for f in (train_edges.mcc_at_e, hgjax.eval.average_precision)])
                a = np.mean(acc, 0)
                rows.append((regime, noise, angle, a))
    return rows


def table(rows) -> str:
    lines = ["| regime | noise | dihedral (deg) | crease: MSS MCC / AP | crease: EA MCC / AP | "
             "with border: MSS MCC / AP | with border: EA MCC / AP |", "|---|---|---|---|---|---|---|"]
    for regime, noise, angle, a in rows:
        lines.append(f"| {regime} | {noise} | {angle} | {a[0]:.3f} / {a[1]:.3f} | {a[2]:.3f} / {a[3]:.3f} | "
                     f"{a[4]:.3f} / {a[5]:.3f} | {a[6]:.3f} / {a[7]:.3f} |")
    crease = np.array([r[3] for r in rows])
    lines.append(f"| mean | | | {crease[:, 0].mean():.3f} / {crease[:, 1].mean():.3f} | "
                 f"{crease[:, 2].mean():.3f} / {crease[:, 3].mean():.3f} | {crease[:, 4].mean():.3f} / "
                 f"{crease[:, 5].mean():.3f} | {crease[:, 6].mean():.3f} / {crease[:, 7].mean():.3f} |")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--weights", type=pathlib.Path, default=None, help="folder holding a _mss_weights.py")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    weights = mss.weights(np.float64) if args.weights is None else train_edges.load_weights(args.weights)
    print(table(run(weights)))


if __name__ == "__main__":
    main()
