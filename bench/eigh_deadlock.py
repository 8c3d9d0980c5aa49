"""Reproducer for the jaxlib CPU eigh deadlock that hgjax once worked around with XLA_FLAGS.

Runs batched LAPACK eigh in the patterns hgjax uses (LHF reference: two lengths of n x n
eigh per point; EA: 3 x 3 eigvalsh) on many chunks, with XLA's default CPU scheduler (no
XLA_FLAGS), each case in a subprocess with a time limit. A hang shows as a timeout.

    python bench/eigh_deadlock.py [--n 200000] [--repeats 3] [--timeout 600]

Writes bench/results/eigh_deadlock.md.
"""

import argparse
import os
import pathlib
import subprocess
import sys
import time

import jax

CASE = """
import sys, numpy as np, jax, hgjax
jax.config.update("jax_enable_x64", True)
p = hgjax.eval.box_union_cloud(seed=int(sys.argv[2]), n_points=int(sys.argv[1])).points
method = sys.argv[3]
params = dict(variant="reference") if method == "lhf" else {}
nb = hgjax.neighbourhoods(p, method, **params)
s = hgjax.score(nb, method, ratio=0.2, **params) if method == "lhf" else hgjax.score(nb, method)
print(float(np.asarray(s).sum()))
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--timeout", type=int, default=600)
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    rows = []
    for method in ("lhf", "ea"):
        for seed in range(args.repeats):
            start = time.perf_counter()
            try:
                subprocess.run([sys.executable, "-c", CASE, str(args.n), str(seed), method], env=env, check=True,
                               timeout=args.timeout, capture_output=True)
                outcome = "finished"
            except subprocess.TimeoutExpired:
                outcome = f"HUNG (killed after {args.timeout} s)"
            rows.append((method, seed, outcome, time.perf_counter() - start))
            print(rows[-1], flush=True)
    out = pathlib.Path(__file__).parent / "results" / "eigh_deadlock.md"
    lines = [f"# eigh deadlock reproducer (jax {jax.__version__}, no XLA_FLAGS)", "",
             f"Command: `python bench/eigh_deadlock.py --n {args.n} --repeats {args.repeats} --timeout {args.timeout}`",
             f"on a {os.cpu_count()}-core CPU.", "",
             "| score | seed | outcome | wall time |", "|---|---|---|---|"]
    lines += [f"| {'lhf reference' if m == 'lhf' else m} | {s} | {o} | {t:.1f} s |" for m, s, o, t in rows]
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
