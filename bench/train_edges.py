"""Train MSS's edge model (hgjax.scores.mss) on synthetic shapes only; write its weights.

Training clouds (all from ``--seed``): the six mesh families of ``hgjax.eval.solids`` and the
box unions of ``hgjax.eval.box_union_cloud``, in turn; random and grid sampling in turn;
noise p in ``NOISES`` spacings, isotropic or along the normals; a random rotation. Labels
are the generators' exact sharp-edge bands; points near creases of 10 to 20 degrees are left
out. Each cloud gives ``ROWS`` rows at most (up to half of them edge points, drawn at random)
and carries the same total weight, split equally between its edge and non-edge rows (a cloud
without edges gives all of it to its non-edge rows).

The model is a two-hidden-layer tanh MLP over ``mss.inputs`` (the point's features and the
cloud's noise level, standardised with the training rows' mean and deviation, folded into the
first layer), fitted by full-batch Adam (written out below: no optimiser library) on the
weighted logistic loss with a small L2 penalty. Everything is deterministic for a seed (float64 on the CPU).

After training (or with ``--validate-only``, of the shipped weights) the model and EA are
reported on held-out clouds (the clouds of seed + HELD_OUT, never trained on) at each noise
of ``VALIDATION_NOISES``: mean MCC keeping exactly E and AP, and on how many clouds the model
is >= EA in both. These, not the labelled clouds, choose between candidate models.

Usage (from the repository root):
  python bench/train_edges.py                   # writes hgjax/scores/_mss_weights.py and
                                                # prints the held-out table
  python bench/train_edges.py --clouds 14 --steps 300 --out /tmp/x   # a small run
  python bench/train_edges.py --validate-only    # the shipped model on the held-out clouds
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
HELD_OUT = 10_000  # the validation clouds are those of the seed ``seed + HELD_OUT``
VALIDATION_NOISES = (0.0, 0.25, 0.5, 1.0)


def cloud(i: int, seed: int, noise: float | None = None):
    """Training cloud ``i`` of the set of ``seed``: (points, edge, ignore, name); ``noise`` (spacings) drawn
    from ``NOISES`` unless given."""
    rng = np.random.default_rng([seed, i])
    family = FAMILIES[i % len(FAMILIES)]
    regime = hgjax.eval.REGIMES[(i // len(FAMILIES)) % 2]
    drawn = float(NOISES[int(rng.integers(len(NOISES)))])
    noise = drawn if noise is None else noise
    kind = solids.NOISE_KINDS[int(rng.integers(2))]
    n = int(rng.integers(*N_POINTS))
    shape_seed = int(rng.integers(1 << 30))
    if family == "boxes":
        c = hgjax.eval.box_union_cloud(seed=shape_seed, n_points=n, rotate=True, noise=noise, regime=regime)
        return c.points, c.edge_mask, np.zeros(len(c.points), bool), f"{c.name} p={noise} iso"
    c = solids.solid_cloud(seed=shape_seed, family=family, n_points=n, regime=regime, noise=noise, noise_kind=kind)
    return c.points, c.edge_mask, c.ignore, f"{c.name} p={noise} {kind}"


def cloud_features(points):
    """(N, F + 1) ``mss.inputs`` of every point (its features and the cloud's noise level)."""
    nb = hgjax.neighbourhoods(points, "mss")
    noise = mss.noise_level(nb.points, nb.idx)
    return np.asarray(_stream.map_neighbourhoods(mss.inputs, nb, args=(noise,)))


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


def mcc_at_e(scores, labels) -> float:
    """MCC keeping exactly E = labels.sum() points, the largest scores (ties by index)."""
    e, n = int(labels.sum()), len(labels)
    kept = np.zeros(n, bool)
    kept[np.argsort(-scores, kind="stable")[:e]] = True
    tp, fp = int((kept & labels).sum()), int((kept & ~labels).sum())
    fn, tn = e - tp, n - e - fp
    den = np.sqrt(float(tp + fp) * (tp + fn) * (tn + fp) * (tn + fn))
    return float((tp * tn - fp * fn) / den) if den > 0 else 0.0


def validate(weights, seed: int, per_noise: int = 28):
    """Held-out synthetic metrics: {noise: [(model MCC, model AP, EA MCC, EA AP) per cloud]}.

    The clouds are those of ``cloud`` for the seed ``seed + HELD_OUT`` (shapes never trained
    on), ``per_noise`` of them (every family, both regimes) at each noise of
    ``VALIDATION_NOISES``; points near creases of 10 to 20 degrees are left out.
    """
    params = [jnp.asarray(a) for a in weights]
    logits = jax.jit(jax.vmap(mss.mlp, in_axes=(None, 0)))
    out = {}
    for noise in VALIDATION_NOISES:
        rows = []
        for i in range(per_noise):
            points, edge, ignore, _ = cloud(i, seed + HELD_OUT, noise)
            if not edge[~ignore].any():
                continue
            model = np.asarray(logits(params, jnp.asarray(cloud_features(points))))[~ignore]
            ea = np.asarray(hgjax.score(hgjax.neighbourhoods(points, "ea"), "ea"))[~ignore]
            y = edge[~ignore]
            rows.append((mcc_at_e(model, y), hgjax.eval.average_precision(model, y), mcc_at_e(ea, y),
                         hgjax.eval.average_precision(ea, y)))
        out[noise] = rows
    return out


def validation_table(metrics) -> str:
    """Markdown rows of :func:`validate`'s means, per noise and overall, and the clouds where the model >= EA."""
    lines = ["| noise (spacings) | clouds | model MCC / AP | EA MCC / AP | model >= EA (MCC and AP) |",
             "|---|---|---|---|---|"]
    every = [r for per_noise in metrics.values() for r in per_noise]
    for noise, rows in [*metrics.items(), ("all", every)]:
        a = np.asarray(rows)
        wins = int(np.sum((a[:, 0] >= a[:, 2]) & (a[:, 1] >= a[:, 3])))
        lines.append(f"| {noise} | {len(a)} | {a[:, 0].mean():.3f} / {a[:, 1].mean():.3f} | "
                     f"{a[:, 2].mean():.3f} / {a[:, 3].mean():.3f} | {wins} of {len(a)} |")
    return "\n".join(lines)


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
    parser.add_argument("--validate-only", action="store_true",
                        help="no training: report the shipped weights on the held-out clouds")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    t0 = time.time()
    if args.validate_only:
        weights = mss.weights(np.float64)
    else:
        weights, losses, rows = train(args.clouds, args.steps, args.seed, verbose=True)
        path = (args.out / "_mss_weights.py") if args.out else ROOT / "hgjax" / "scores" / "_mss_weights.py"
        write_weights(weights, path, sys.argv[1:] if argv is None else argv)
        print(f"{rows} rows, loss {losses[0]:.4f} -> {losses[-1]:.4f}, {time.time() - t0:.0f} s -> {path}")
    print("held-out synthetic clouds:")
    print(validation_table(validate(weights, args.seed)), flush=True)
    print(f"{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
