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
  python bench/mss_training/train_edges.py                  # writes hgjax/scores/_mss_weights.py and
                                                            # prints the held-out table
  python bench/mss_training/train_edges.py --clouds 14 --steps 300 --out small   # a small run
  python bench/mss_training/train_edges.py --validate-only  # the shipped model on the held-out clouds
  python bench/mss_training/train_edges.py --validate-only --weights shipped run_a run_b --bands 1.0 0.5
                                                            # several models on the same held-out clouds,
                                                            # labels at the training band and at half of it

Options of the candidates of bench/mss_training/mss_candidates3.md (none adopted; the defaults are the
shipped recipe): ``--target graded`` (the target is the mean of the labels of the bands ``GRADED`` x
the default one, so that the logit falls with the distance to the crease), ``--sheets`` (folded sheets,
two rectangles at one crease of 30 to 170 degrees with an open non-edge border, as one more family, in
training and held-out clouds), ``--near F`` (a fraction F of each cloud's non-edge rows drawn within two
spacings of an edge). Round 4 (bench/mss_training/mss_candidates4.md): ``--target mixed`` (graded targets for the
clouds of less than ``MIXED_BELOW`` spacings of noise, band targets above), ``--target blend`` (``BLEND``
times the graded target plus the rest of the band target) and ``--per-noise`` (a larger held-out check).
Round 5 (bench/mss_training/mss_candidates5.md): ``--varying`` (clouds of varying density, ``hgjax.eval.solids``'
third regime, in the cycle of the mesh families' regimes). Round 6 (bench/mss_training/mss_candidates6.md):
``--regimes`` (the cycle of sampling regimes, any of ``solids.MESH_REGIMES``; ``--varying`` is
``--regimes random grid varying``).
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import trimesh
from scipy.spatial import cKDTree

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import hgjax  # noqa: E402
from hgjax import _stream  # noqa: E402
from hgjax.eval import solids  # noqa: E402
from hgjax.scores import mss  # noqa: E402

FAMILIES = solids.FAMILIES + ("boxes",)
REGIMES = hgjax.eval.REGIMES  # the training clouds' sampling, in turn (--regimes)
SHEET_FAMILIES = FAMILIES + ("sheet",)  # with --sheets: folded sheets (two rectangles at one crease) too
GRADED = (0.5, 1.0, 1.5)  # --target graded: the mean of the labels of bands this many times the default one
MIXED_BELOW = 0.5  # --target mixed: graded targets for the clouds of less noise (spacings), band targets above
BLEND = 0.25  # --target blend: the graded target's share beside the band target's
# (noise in spacings below which the target is graded, the graded target's share there)
TARGETS = {"band": (0.0, 0.0), "graded": (np.inf, 1.0), "mixed": (MIXED_BELOW, 1.0), "blend": (np.inf, BLEND)}
NOISES = (0.0, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0)
L2 = 1e-4
LEARNING_RATE = 1e-2
BETAS = (0.9, 0.999)
EPS = 1e-8
N_POINTS = (3000, 7000)
ROWS = 1000  # training rows per cloud: up to half edge points, the rest non-edge, drawn at random
HELD_OUT = 10_000  # the validation clouds are those of the seed ``seed + HELD_OUT``
VALIDATION_NOISES = (0.0, 0.25, 0.5, 1.0)


def folded_sheet(rng: np.random.Generator) -> trimesh.Trimesh:
    """An open mesh of two rectangles (widths 0.5 to 1, length 1 to 2) sharing one edge at a dihedral angle
    drawn uniformly from 30 to 170 degrees: one straight crease of any sharpness and an open border, which is
    no sharp edge (its points are non-edge)."""
    a, b = rng.uniform(0.5, 1.0, 2)
    length = rng.uniform(1.0, 2.0)
    t = np.deg2rad(rng.uniform(30.0, 170.0))
    v = np.array([[0, 0, 0], [length, 0, 0], [0, a, 0], [length, a, 0],
                  [0, b * np.cos(t), b * np.sin(t)], [length, b * np.cos(t), b * np.sin(t)]], float)
    return trimesh.Trimesh(v, np.array([[0, 1, 3], [0, 3, 2], [0, 5, 1], [0, 4, 5]]), process=False)


def cloud(i: int, seed: int, noise: float | None = None, families=FAMILIES, grading=(0.0, 0.0), band_factor=1.0,
          regimes=REGIMES):
    """Training cloud ``i`` of the set of ``seed``: (points, edge, ignore, name, target); ``noise`` (spacings)
    drawn from ``NOISES`` unless given. ``target`` is ``edge`` as floats, or, below ``grading = (noise,
    share)``'s noise, ``share`` times the graded target (the mean of the edge labels of the bands ``GRADED`` times
    the default band: 1 nearest the crease, falling to 0 at 1.5 bands, a target that orders the points by their
    distance to the crease) plus 1 - ``share`` times ``edge``. ``band_factor`` scales the band
    of ``edge`` (1: the generators' default). ``regimes``: the sampling regimes the clouds take in turn (box unions
    take "random" for "varying" and "even")."""
    rng = np.random.default_rng([seed, i])
    family = families[i % len(families)]
    regime = regimes[(i // len(families)) % len(regimes)]
    drawn = float(NOISES[int(rng.integers(len(NOISES)))])
    noise = drawn if noise is None else noise
    kind = solids.NOISE_KINDS[int(rng.integers(2))]
    n = int(rng.integers(*N_POINTS))
    shape_seed = int(rng.integers(1 << 30))
    band = hgjax.eval.synthetic.GRID_DELTA if regime == "grid" else hgjax.eval.synthetic.DEFAULT_DELTA
    if family == "boxes":
        regime = "grid" if regime == "grid" else "random"  # box unions come in the two uniform regimes
        def make(delta):
            c = hgjax.eval.box_union_cloud(seed=shape_seed, n_points=n, rotate=True, noise=noise, regime=regime,
                                           delta=delta)
            return c.points, c.edge_mask, np.zeros(len(c.points), bool)
        name = f"boxes{shape_seed} {regime} p={noise} iso"
    else:
        mesh = (folded_sheet(np.random.default_rng([shape_seed, 5])) if family == "sheet"
                else solids.random_solid(shape_seed, family))

        def make(delta):
            c = solids.mesh_cloud(mesh, n_points=n, seed=shape_seed, regime=regime, noise=noise, noise_kind=kind,
                                  delta=delta)
            return c.points, c.edge_mask, c.ignore
        name = f"{'' if regime == 'random' else regime + '-'}{family}{shape_seed} p={noise} {kind}"
    band *= band_factor
    points, edge, ignore = make(band)
    target = edge.astype(np.float64)
    below, share = grading
    if noise < below:
        graded = np.mean([make(f * band)[1] if f != 1.0 else edge for f in GRADED], axis=0)
        target = share * graded + (1 - share) * target
    return points, edge, ignore, name, target


def cloud_features(points):
    """(N, F + 1) ``mss.inputs`` of every point (its features and the cloud's noise level)."""
    nb = hgjax.neighbourhoods(points, "mss")
    noise = mss.noise_level(nb.points, nb.idx)
    return np.asarray(_stream.map_neighbourhoods(mss.inputs, nb, args=(noise,)))


def dataset(n_clouds: int, seed: int, families=FAMILIES, grading=(0.0, 0.0), near=0.0, regimes=REGIMES,
            features=cloud_features, noise: float | None = None):
    """(X (R, F), target (R,), w (R,), names) over the clouds 0 .. n_clouds - 1.

    ``features(points) -> (N, F)``: the model's inputs of every point. ``near``: the fraction of a cloud's
    non-edge rows drawn among its points within two spacings of an edge (the negatives that decide the ranking
    about a crease); the rest at random. ``noise``: every cloud's noise (spacings; the same shapes and
    samplings), or None for each its own draw from ``NOISES``."""
    xs, ys, ws, names = [], [], [], []
    for i in range(n_clouds):
        points, edge, ignore, name, target = cloud(i, seed, noise, families=families, grading=grading,
                                                   regimes=regimes)
        rows = np.random.default_rng([seed, i, 1]).permutation(np.flatnonzero(~ignore))
        negatives = rows[~edge[rows]]
        if near > 0 and edge.any():
            close = near_edges(points, edge, negatives)
            first = negatives[close][:int(near * ROWS // 2)]
            negatives = np.concatenate([first, negatives[~np.isin(negatives, first)]])
        rows = np.sort(np.concatenate([rows[edge[rows]][:ROWS // 2], negatives[:ROWS // 2]]))
        x, y, t = features(points)[rows], edge[rows], target[rows]
        pos, neg = int(y.sum()), int((~y).sum())
        w = np.where(y, 0.5 / max(pos, 1), (0.5 if pos else 1.0) / max(neg, 1))
        xs.append(x), ys.append(t), ws.append(w), names.append(name)
    w = np.concatenate(ws)
    return np.concatenate(xs), np.concatenate(ys).astype(np.float64), w / w.sum(), names


def near_edges(points, edge, candidates):
    """(len(candidates),) bool: the ``candidates`` within two spacings (the cloud's intrinsic resolution)
    of an edge point."""
    d, _ = cKDTree(points[edge]).query(points[candidates])
    spacing = hgjax.neighbours.spatial.intrinsic_resolution(points)
    return d <= 2.0 * spacing


def init(n_features: int, seed: int, hidden: int = mss.HIDDEN, stream: int = 1):
    """Glorot-uniform weights, zero biases, of a perceptron of two ``hidden``-unit layers, from the random stream
    (``seed``, ``stream``)."""
    rng = np.random.default_rng([seed, stream])
    sizes = (n_features, hidden, hidden, 1)
    params = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        limit = np.sqrt(6.0 / (a + b))
        params += [rng.uniform(-limit, limit, (a, b)), np.zeros(b)]
    return [jnp.asarray(p) for p in params]


def loss(params, x, y, w, logit_fn=mss.mlp, penalised=None):
    """The weighted logistic loss of ``logit_fn(params, row)`` over the rows of ``x``, plus L2 times the squared
    sum of ``penalised`` (default: the weight matrices, ``params[::2]``)."""
    logit = jax.vmap(logit_fn, in_axes=(None, 0))(params, x)
    nll = jnp.sum(w * (jax.nn.softplus(logit) - y * logit))
    return nll + L2 * sum(jnp.sum(p * p) for p in (params[::2] if penalised is None else penalised(params)))


def adam(params, x, y, w, steps: int, verbose: bool = False, objective=loss):
    """``steps`` full-batch Adam steps with a cosine-decayed learning rate on ``objective(params, x, y, w)``;
    (params, losses)."""
    grad = jax.jit(jax.value_and_grad(objective))
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


def train(n_clouds: int, steps: int, seed: int, verbose: bool = False, families=FAMILIES, grading=(0.0, 0.0),
          near=0.0, regimes=REGIMES, features=cloud_features, noise: float | None = None):
    """Fit the model over ``features`` (:func:`dataset`'s); returns (weights as float64 NumPy arrays, losses, the
    training set's size)."""
    x, y, w, _ = dataset(n_clouds, seed, families, grading, near, regimes, features, noise)
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


def validate(weights, seed: int, per_noise: int = 28, families=FAMILIES, bands=(1.0,), regimes=REGIMES,
             features=cloud_features, logit_fn=mss.mlp, noises=VALIDATION_NOISES):
    """Held-out synthetic metrics: {band: {noise: [(model MCC, model AP, EA MCC, EA AP) per cloud]}}, or a list of
    those for a list of models (``weights`` a list of weight lists, the features computed once). A model scores a
    point by ``logit_fn(weights, row)`` of its row of ``features(points)`` (default: MSS's).

    The clouds are those of ``cloud`` for the seed ``seed + HELD_OUT`` (shapes never trained
    on), ``per_noise`` of them (every family, every one of ``regimes``) at each noise of
    ``noises`` (default ``VALIDATION_NOISES``); points near creases of 10 to 20 degrees are left out. ``bands``: the
    edge labels' band widths in units of the default band (1: the training labels; 0.5: the points
    nearest the crease, which only a ranking by distance to the crease finds).
    """
    many = isinstance(weights[0], (list, tuple))
    models = [[jnp.asarray(a) for a in w] for w in (weights if many else [weights])]
    logits = jax.jit(jax.vmap(logit_fn, in_axes=(None, 0)))
    out = [{b: {} for b in bands} for _ in models]
    for noise in noises:
        rows = [{b: [] for b in bands} for _ in models]
        for i in range(per_noise):
            points, edge, ignore, _, _ = cloud(i, seed + HELD_OUT, noise, families, regimes=regimes)
            if not edge[~ignore].any():
                continue
            x = jnp.asarray(features(points))
            scores = [np.asarray(logits(p, x)) for p in models]
            ea = np.asarray(hgjax.score(hgjax.neighbourhoods(points, "ea"), "ea"))
            for b in bands:
                e, ig = (edge, ignore) if b == 1.0 else cloud(i, seed + HELD_OUT, noise, families, band_factor=b,
                                                              regimes=regimes)[1:3]
                keep = ~(ignore | ig)
                y = e[keep]
                if not y.any():
                    continue
                ea_m = (mcc_at_e(ea[keep], y), hgjax.eval.average_precision(ea[keep], y))
                for r, s in zip(rows, scores):
                    r[b].append((mcc_at_e(s[keep], y), hgjax.eval.average_precision(s[keep], y)) + ea_m)
        for o, r in zip(out, rows):
            for b in bands:
                o[b][noise] = r[b]
    if many:
        return out
    return out[0] if len(bands) > 1 else out[0][bands[0]]


def validation_table(metrics, digits: int = 3) -> str:
    """Markdown rows of :func:`validate`'s means (``digits`` decimals), per noise and overall, and the clouds where
    the model >= EA."""
    lines = ["| noise (spacings) | clouds | model MCC / AP | EA MCC / AP | model >= EA (MCC and AP) |",
             "|---|---|---|---|---|"]
    every = [r for per_noise in metrics.values() for r in per_noise]
    for noise, rows in [*metrics.items(), ("all", every)]:
        a = np.asarray(rows)
        wins = int(np.sum((a[:, 0] >= a[:, 2]) & (a[:, 1] >= a[:, 3])))
        m = [f"{x:.{digits}f}" for x in a.mean(axis=0)]
        lines.append(f"| {noise} | {len(a)} | {m[0]} / {m[1]} | {m[2]} / {m[3]} | {wins} of {len(a)} |")
    return "\n".join(lines)


def write_weights(weights, path: pathlib.Path, argv):
    names = ("W1", "B1", "W2", "B2", "W3", "B3")
    lines = ['"""Weights of MSS\'s edge model (hgjax.scores.mss), written by '
             '`python bench/mss_training/train_edges.py' + (" " + " ".join(argv) if argv else "")
             + '`; do not edit."""', ""]
    for name, a in zip(names, weights):
        lines.append(f"{name} = {np.asarray(a, np.float64).tolist()!r}")
    path.write_text("\n".join(lines) + "\n")


def weights_module(path: pathlib.Path):
    """The module of a written weights file (``path``), loaded without importing it by name."""
    spec = importlib.util.spec_from_file_location("_candidate_weights", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_weights(folder: pathlib.Path):
    """The six arrays of ``folder/_mss_weights.py`` as float64 NumPy arrays."""
    module = weights_module(folder / "_mss_weights.py")
    return [np.asarray(getattr(module, k), np.float64) for k in ("W1", "B1", "W2", "B2", "W3", "B3")]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clouds", type=int, default=210, help="training clouds (default 210)")
    parser.add_argument("--steps", type=int, default=1500, help="Adam steps (default 1500)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=pathlib.Path, default=None,
                        help="folder for the weights module (default: hgjax/scores/_mss_weights.py)")
    parser.add_argument("--validate-only", action="store_true",
                        help="no training: report the shipped weights on the held-out clouds")
    parser.add_argument("--target", choices=tuple(TARGETS), default="band",
                        help="band: 1 within the edge band, else 0 (default); graded: see GRADED; mixed: graded "
                             "below MIXED_BELOW spacings of noise, band above; blend: BLEND x graded + "
                             "(1 - BLEND) x band")
    parser.add_argument("--sheets", action="store_true", help="folded sheets as one more family (training and "
                        "held-out clouds)")
    parser.add_argument("--varying", action="store_true", help="clouds of varying density as a third regime of the "
                        "mesh families (training and held-out clouds; box unions stay uniform)")
    parser.add_argument("--regimes", nargs="+", choices=solids.MESH_REGIMES, default=None,
                        help="the sampling regimes of the training and held-out clouds, in turn (default: random "
                             "grid; box unions take random for varying and even)")
    parser.add_argument("--near", type=float, default=0.0,
                        help="fraction of the non-edge rows drawn within two spacings of an edge (default 0)")
    parser.add_argument("--weights", type=pathlib.Path, nargs="+", default=None,
                        help="with --validate-only: folders of a _mss_weights.py to report instead of the shipped "
                             "('shipped' for the shipped weights)")
    parser.add_argument("--bands", type=float, nargs="+", default=[1.0],
                        help="with --validate-only: held-out label bands, in units of the default band (default 1)")
    parser.add_argument("--digits", type=int, default=3, help="decimals of the held-out tables (default 3)")
    parser.add_argument("--per-noise", type=int, default=28,
                        help="with --validate-only: held-out clouds per noise (default 28: 20 with edges)")
    args = parser.parse_args(argv)
    families = SHEET_FAMILIES if args.sheets else FAMILIES
    if args.varying and args.regimes:
        parser.error("--varying is --regimes random grid varying: give one of them")
    regimes = REGIMES + ("varying",) if args.varying else tuple(args.regimes or REGIMES)
    jax.config.update("jax_enable_x64", True)
    t0 = time.time()
    if args.validate_only:
        folders = args.weights or ["shipped"]
        weights = [mss.weights(np.float64) if str(f) == "shipped" else load_weights(pathlib.Path(f)) for f in folders]
        results = validate(weights, args.seed, args.per_noise, families=families, bands=tuple(args.bands),
                           regimes=regimes)
        kind = "".join([" with sheets"] * args.sheets + [f" ({', '.join(regimes)})"] * (regimes != REGIMES))
        for folder, per_band in zip(folders, results):
            for band, metrics in per_band.items():
                print(f"held-out synthetic clouds{kind}, band x{band}: {folder}")
                print(validation_table(metrics, args.digits), flush=True)
        print(f"{time.time() - t0:.0f} s")
        return
    else:
        weights, losses, rows = train(args.clouds, args.steps, args.seed, verbose=True, families=families,
                                      grading=TARGETS[args.target], near=args.near, regimes=regimes)
        path = (args.out / "_mss_weights.py") if args.out else ROOT / "hgjax" / "scores" / "_mss_weights.py"
        write_weights(weights, path, sys.argv[1:] if argv is None else argv)
        print(f"{rows} rows, loss {losses[0]:.4f} -> {losses[-1]:.4f}, {time.time() - t0:.0f} s -> {path}")
    print("held-out synthetic clouds:")
    print(validation_table(validate(weights, args.seed, families=families, regimes=regimes)), flush=True)
    print(f"{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
