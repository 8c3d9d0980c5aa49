"""Round 8 candidate (issue 44): MSS with a clean-cloud expert that the cloud's noise level switches to.

The candidate's logit of one point (bench/mss_training/mss_candidates8.md, fixed before training):

    f = f_clean(u)   where the cloud's noise level < T0,
    f = f_MSS(x)     elsewhere,

with f_MSS the shipped model (``hgjax.scores.mss.mlp`` with its shipped weights) over MSS's inputs x
(F + 1,); the noise level ``mss.noise_level``, measured once per cloud on the seeded sample (tiles
agree); u = MSS's F features and LHF's invariant gamma at 8 and 16 points (the paper's hypergraph
high-band share, on prefixes of the same 32 nearest points); f_clean a perceptron of MSS's shape
(two hidden layers of ``mss.HIDDEN`` units) fitted from scratch by ``train_edges.train`` on the
training clouds of ``train_edges.cloud`` taken without noise (the same shapes and samplings). The
gate is fixed by design, not learned: on a cloud that reads T0 or more the candidate is the shipped
model exactly, so its noise robustness is kept by construction. T0 lies between the noise levels that
the clean training clouds read and those of .1 spacing of noise (``levels``).

Usage (from the repository root):
  python bench/mss_training/clean_expert.py levels                  # noise levels of training clouds
  python bench/mss_training/clean_expert.py train --out mss_c13     # C13's recipe
  python bench/mss_training/clean_expert.py validate --weights shipped mss_c13 --per-noise 112 --noises 0
                                                                    # held-out clouds (every regime, sheets)
  python bench/mss_training/clean_expert.py judge --weights mss_c13 # the labelled columns, once
"""

from __future__ import annotations

import functools
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import regime  # noqa: E402
import train_edges  # noqa: E402

import hgjax  # noqa: E402
from hgjax.scores import mss  # noqa: E402

T0 = 0.03  # the noise level below which a cloud is clean (its expert's domain)
F = regime.F  # MSS's inputs x: its features, then the noise level
NU = F - 1 + len(regime.LENGTHS)  # the clean expert's inputs u: MSS's features, LHF's gamma at each length
WEIGHTS = ("W1", "B1", "W2", "B2", "W3", "B3")
cloud_inputs = functools.partial(regime.cloud_inputs, irregularity=False)  # [x (F,), gamma (2,), 0, noise]
U_COLUMNS = np.r_[0:F - 1, F:F + len(regime.LENGTHS)]  # u's columns in a row of cloud_inputs


def expert_inputs(rows):
    """(..., NU) u of rows of :func:`cloud_inputs` (NumPy or JAX)."""
    return rows[..., U_COLUMNS]


def clean_features(points) -> np.ndarray:
    """(N, NU) the clean expert's inputs u of every point."""
    return expert_inputs(cloud_inputs(points))


def logit(params, row):
    """The candidate's logit of one row of :func:`cloud_inputs`; ``params``: the expert's weights, then (T0,)."""
    *clean, t0 = params
    return jnp.where(row[-1] < t0[0], mss.mlp(clean, expert_inputs(row)), mss.mlp(mss.weights(row.dtype), row[:F]))


def write(weights, folder: pathlib.Path, argv) -> pathlib.Path:
    return regime.write_module(folder / "_clean_weights.py", "the round-8 clean expert",
                               f"python bench/mss_training/clean_expert.py {' '.join(argv)}", {"T0": T0}, WEIGHTS,
                               weights)


def load(folder) -> list:
    """The candidate's params from ``folder/_clean_weights.py``; ``shipped``: a gate that never opens (the
    shipped MSS exactly)."""
    if str(folder) == "shipped":
        hidden = mss.HIDDEN
        return [np.zeros((NU, hidden)), np.zeros(hidden), np.zeros((hidden, hidden)), np.zeros(hidden),
                np.zeros((hidden, 1)), np.zeros(1), np.zeros(1)]
    module = train_edges.weights_module(pathlib.Path(folder) / "_clean_weights.py")
    return [np.asarray(getattr(module, k), np.float64) for k in WEIGHTS] + [np.array([module.T0])]


def levels(families, regimes_, n_clouds: int = 360) -> list[str]:
    """Lines: the noise level's range (min, 5th, 50th, 95th percentile, max) over the first ``n_clouds`` training
    clouds of seed 0, by the noise each was given (spacings) and by sampling regime."""
    seen = {}
    for i in range(n_clouds):
        points, _, _, name, _ = train_edges.cloud(i, 0, families=families, regimes=regimes_)
        noise = float(name.split("p=")[1].split()[0])
        head, second = name.split()[:2]  # "boxes<seed> <regime> ...", "<regime>-<family><seed> ...", "<family><seed> ..."
        kind = second if head.startswith("boxes") else head.split("-")[0] if "-" in head else "random"
        nb = hgjax.neighbourhoods(points, "mss")
        seen.setdefault(noise, {}).setdefault(kind, []).append(float(mss.noise_level(nb.points, nb.idx)))
    lines = []
    for noise in sorted(seen):
        for kind, values in sorted(seen[noise].items()):
            pct = np.percentile(values, [0, 5, 50, 95, 100]).round(3).tolist()
            lines.append(f"noise {noise} spacings, {kind} ({len(values)} clouds): noise level {pct}")
    return lines


def main(argv=None):
    parser = regime.candidate_parser(__doc__, ("levels", "train", "validate", "judge"))
    parser.add_argument("--noises", type=float, nargs="+", default=list(train_edges.VALIDATION_NOISES),
                        help="validate: the held-out noises (spacings)")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    families = train_edges.FAMILIES if args.no_sheets else train_edges.SHEET_FAMILIES
    regimes = tuple(args.regimes)
    t0 = time.time()
    if args.command == "levels":
        print("\n".join(levels(families, regimes)))
    elif args.command == "train":
        weights, losses, n = train_edges.train(args.clouds, args.steps, args.seed, verbose=True, families=families,
                                               regimes=regimes, features=clean_features, noise=0.0)
        path = write(weights, args.out, sys.argv[1:] if argv is None else argv)
        print(f"{n} rows, loss {losses[0]:.5f} -> {losses[-1]:.5f} -> {path}")
    elif args.command == "validate":
        folders = args.weights or ["shipped"]
        results = train_edges.validate([load(f) for f in folders], args.seed, args.per_noise, families=families,
                                       regimes=regimes, logit_fn=logit, features=cloud_inputs,
                                       noises=tuple(args.noises))
        regime.print_validation(folders, results, regimes)
    else:
        params = load(args.weights[0])
        regime.judge(lambda p: regime.scores(p, params, False, logit), args.out)
    print(f"{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
