"""Rounds 5 and 6 of bench/results/mss_candidates5.md and 6: MSS with its logit the mean of several models' logits.

The shipped model is the first member (unless ``--without-shipped``); ``--weights`` adds the others
(folders holding a ``_mss_weights.py`` written by ``bench/train_edges.py --out``). ``held-out``:
:func:`train_edges.validate` of the shipped model, of each other member alone and of the ensemble, on
the held-out clouds of seed 0 (no member trained on them), in the sampling regimes of ``--regimes``;
``labelled``: ``bench/edge_detectors.py`` (MSS and EA) with MSS the ensemble; ``wedges``:
``bench/mss_wedges.py``'s folded sheets with MSS the ensemble. The package is not changed: the
ensemble replaces ``mss.mlp`` and ``mss.weights`` inside this process only.

Usage (from the repository root):
  python bench/mss_ensemble.py held-out --weights /tmp/mss_c6 --per-noise 112
  python bench/mss_ensemble.py labelled --weights /tmp/mss_c6 --out /tmp/c6_labelled
  python bench/mss_ensemble.py labelled --weights /tmp/mss_c7 --without-shipped --out /tmp/c7_labelled
                                                # one candidate model alone
  python bench/mss_ensemble.py held-out --without-shipped --weights /tmp/mss_c9 /tmp/mss_c10 --regimes even
  python bench/mss_ensemble.py wedges --without-shipped --weights /tmp/mss_c9 /tmp/mss_c10
"""

from __future__ import annotations

import argparse
import pathlib
import sys
from unittest import mock

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import edge_detectors  # noqa: E402
import mss_wedges  # noqa: E402
import train_edges  # noqa: E402
from hgjax.scores import mss  # noqa: E402

PARTS = 6  # arrays per member: W1, b1, W2, b2, W3, b3
SINGLE = mss.mlp  # one member's logit


def mean_logit(params, x):
    """The mean of :func:`mss.mlp` over the members whose arrays follow each other in ``params``."""
    members = len(params) // PARTS
    return sum(SINGLE(params[PARTS * i:PARTS * (i + 1)], x) for i in range(members)) / members


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("check", choices=("held-out", "labelled", "wedges"))
    parser.add_argument("--weights", type=pathlib.Path, nargs="+", required=True,
                        help="folders of the members beside the shipped model")
    parser.add_argument("--without-shipped", action="store_true", help="the --weights members only")
    parser.add_argument("--per-noise", type=int, default=112, help="held-out clouds per noise (default 112)")
    parser.add_argument("--regimes", nargs="+", default=list(train_edges.REGIMES),
                        choices=train_edges.solids.MESH_REGIMES,
                        help="held-out: the sampling regimes of the clouds, in turn (default: random grid)")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("/tmp"),
                        help="labelled: folder of the edge_detectors.md written")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)  # every check in float64, the shipped weights included
    shipped = [np.asarray(a) for a in mss.weights(np.float64)]
    others = [train_edges.load_weights(f) for f in args.weights]
    ensemble = ([] if args.without_shipped else shipped) + [a for w in others for a in w]
    with mock.patch.object(mss, "mlp", mean_logit):
        if args.check == "held-out":
            models = [shipped, *others, ensemble]
            names = ["shipped", *map(str, args.weights), f"ensemble of {len(ensemble) // PARTS}"]
            for name, result in zip(names, train_edges.validate(models, 0, args.per_noise,
                                                                regimes=tuple(args.regimes))):
                print(f"held-out synthetic clouds, band x1: {name}")
                print(train_edges.validation_table(result[1.0], 4), flush=True)
        elif args.check == "wedges":
            print(mss_wedges.table(mss_wedges.run(ensemble)))
        else:
            with mock.patch.object(mss, "weights", lambda dtype: [jnp.asarray(a, dtype) for a in ensemble]):
                edge_detectors.main(["--methods", "mss,ea", "--out", str(args.out)])


if __name__ == "__main__":
    main()
