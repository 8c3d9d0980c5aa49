"""Train MSS's edge model (hgjax.scores.mss) on synthetic shapes only; write its weights.

Training clouds (all from ``--seed``): the six mesh families of ``hgjax.eval.solids`` and the
box unions of ``hgjax.eval.box_union_cloud``, in turn; random and grid sampling in turn;
noise p in ``NOISES`` spacings, isotropic or along the normals; a random rotation. Labels
are the generators' exact sharp-edge bands; points near creases of 10 to 20 degrees are left
out. Each cloud gives ``ROWS`` rows at most (up to half of them edge points, drawn at random)
and carries the same total weight, split equally between its edge and non-edge rows (a cloud
without edges gives all of it to its non-edge rows).

The model is a two-hidden-layer tanh MLP over ``mss.features`` (standardised with the
training rows' mean and deviation, folded into the first layer), fitted by full-batch Adam
(written out below: no optimiser library) on the weighted logistic loss with a small L2
penalty. Everything is deterministic for a seed (float64 on the CPU).

Usage (from the repository root):
  python bench/train_edges.py                   # writes hgjax/scores/_mss_weights.py and
                                                # bench/results/train_edges.md
  python bench/train_edges.py --clouds 14 --steps 300 --out /tmp/x   # a small run
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import hgjax  # noqa: E402
from hgjax import _stream  # noqa: E402
from hgjax.eval import solids  # noqa: E402
from hgjax.scores import mss  # noqa: E402

FAMILIES = solids.FAMILIES + ("boxes",)
NOISES = (0.0, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0)
L2 = 1e-4
LEARNING_RATE = 1e-2
BETAS = (0.9, 0.999)
EPS = 1e-8
N_POINTS = (3000, 7000)
ROWS = 1000  # training rows per cloud: up to half edge points, the rest non-edge, drawn at random


def cloud(i: int, seed: int):
    """Training cloud ``i`` of the set of ``seed``: (points, edge, ignore, name)."""
    rng = np.random.default_rng([seed, i])
    family = FAMILIES[i % len(FAMILIES)]
    regime = hgjax.eval.REGIMES[(i // len(FAMILIES)) % 2]
    noise = float(NOISES[int(rng.integers(len(NOISES)))])
    kind = solids.NOISE_KINDS[int(rng.integers(2))]
    n = int(rng.integers(*N_POINTS))
    shape_seed = int(rng.integers(1 << 30))
    if family == "boxes":
        c = hgjax.eval.box_union_cloud(seed=shape_seed, n_points=n, rotate=True, noise=noise, regime=regime)
        return c.points, c.edge_mask, np.zeros(len(c.points), bool), f"{c.name} p={noise} iso"
    c = solids.solid_cloud(seed=shape_seed, family=family, n_points=n, regime=regime, noise=noise, noise_kind=kind)
    return c.points, c.edge_mask, c.ignore, f"{c.name} p={noise} {kind}"


def cloud_features(points):
    """(N, F) ``mss.features`` of every point."""
    nb = hgjax.neighbourhoods(points, "mss")
    return np.asarray(_stream.map_neighbourhoods(mss.features, nb))


def dataset(n_clouds: int, seed: int):
    """(X (R, F), y (R,), w (R,), names) over the clouds 0 .. n_clouds - 1."""
    xs, ys, ws, names = [], [], [], []
    for i in range(n_clouds):
        points, edge, ignore, name = cloud(i, seed)
        rows = np.random.default_rng([seed, i, 1]).permutation(np.flatnonzero(~ignore))
        rows = np.sort(np.concatenate([rows[edge[rows]][:ROWS // 2], rows[~edge[rows]][:ROWS // 2]]))
        x, y = cloud_features(points)[rows], edge[rows]
        pos, neg = int(y.sum()), int((~y).sum())
        w = np.where(y, 0.5 / max(pos, 1), (0.5 if pos else 1.0) / max(neg, 1))
        xs.append(x), ys.append(y), ws.append(w), names.append(name)
    w = np.concatenate(ws)
    return np.concatenate(xs), np.concatenate(ys).astype(np.float64), w / w.sum(), names


def init(n_features: int, seed: int):
    """Glorot-uniform weights, zero biases, from ``seed``."""
    rng = np.random.default_rng([seed, 1])
    sizes = (n_features, mss.HIDDEN, mss.HIDDEN, 1)
    params = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        limit = np.sqrt(6.0 / (a + b))
        params += [rng.uniform(-limit, limit, (a, b)), np.zeros(b)]
    return [jnp.asarray(p) for p in params]


def loss(params, x, y, w):
    logit = jax.vmap(mss.mlp, in_axes=(None, 0))(params, x)
    nll = jnp.sum(w * (jax.nn.softplus(logit) - y * logit))
    return nll + L2 * sum(jnp.sum(p * p) for p in params[::2])


def adam(params, x, y, w, steps: int, verbose: bool = False):
    """``steps`` full-batch Adam steps with a cosine-decayed learning rate; (params, losses)."""
    grad = jax.jit(jax.value_and_grad(loss))
    m = [jnp.zeros_like(p) for p in params]
    v = [jnp.zeros_like(p) for p in params]
    losses = []
    for t in range(1, steps + 1):
        value, g = grad(params, x, y, w)
        lr = LEARNING_RATE * 0.5 * (1 + np.cos(np.pi * (t - 1) / steps))
        m = [BETAS[0] * a + (1 - BETAS[0]) * b for a, b in zip(m, g)]
        v = [BETAS[1] * a + (1 - BETAS[1]) * b * b for a, b in zip(v, g)]
        params = [p - lr * (a / (1 - BETAS[0] ** t)) / (jnp.sqrt(b / (1 - BETAS[1] ** t)) + EPS)
                  for p, a, b in zip(params, m, v)]
        losses.append(float(value))
        if verbose and (t % 250 == 0 or t == 1):
            print(f"step {t}: loss {losses[-1]:.5f}", flush=True)
    return params, losses


def train(n_clouds: int, steps: int, seed: int, verbose: bool = False):
    """Fit the model; returns (weights as float64 NumPy arrays, losses, the training set's size)."""
    x, y, w, _ = dataset(n_clouds, seed)
    mean, std = x.mean(0), x.std(0) + 1e-12
    params = init(x.shape[1], seed)
    params, losses = adam(params, jnp.asarray((x - mean) / std), jnp.asarray(y), jnp.asarray(w), steps, verbose)
    w1, b1 = np.asarray(params[0]), np.asarray(params[1])
    folded = [w1 / std[:, None], b1 - (mean / std) @ w1] + [np.asarray(p) for p in params[2:]]
    return folded, losses, len(y)


def write_weights(weights, path: pathlib.Path, argv):
    names = ("W1", "B1", "W2", "B2", "W3", "B3")
    lines = ['"""Weights of MSS\'s edge model (hgjax.scores.mss), written by `python bench/train_edges.py'
             + (" " + " ".join(argv) if argv else "") + '`; do not edit."""', ""]
    for name, a in zip(names, weights):
        lines.append(f"{name} = {np.asarray(a, np.float64).tolist()!r}")
    path.write_text("\n".join(lines) + "\n")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clouds", type=int, default=210, help="training clouds (default 210)")
    parser.add_argument("--steps", type=int, default=1500, help="Adam steps (default 1500)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=pathlib.Path, default=None,
                        help="folder for the weights module (default: hgjax/scores/_mss_weights.py)")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    t0 = time.time()
    weights, losses, rows = train(args.clouds, args.steps, args.seed, verbose=True)
    path = (args.out / "_mss_weights.py") if args.out else ROOT / "hgjax" / "scores" / "_mss_weights.py"
    write_weights(weights, path, sys.argv[1:] if argv is None else argv)
    print(f"{rows} rows, loss {losses[0]:.4f} -> {losses[-1]:.4f}, {time.time() - t0:.0f} s -> {path}")


if __name__ == "__main__":
    main()
