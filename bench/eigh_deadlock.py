"""Reproducer for the jaxlib CPU eigh deadlock (jax 0.10.2, no XLA_FLAGS).

LHF with ``variant="reference"`` computes an n x n ``eigh`` per point for each of its two
lengths. Three layouts, the first two with jaxlib's LAPACK ``jnp.linalg.eigh``: both lengths
in one compiled kernel serialised by an ``optimization_barrier`` (hgjax's previous layout,
which needed XLA_FLAGS); both lengths in one kernel traced under ``jit`` over the whole
cloud; and hgjax's layout (:func:`hgjax.scores.lhf.single`: NumPy's eigh through a host
callback, :func:`hgjax.spectrum.host_eigh`, one length per compiled kernel). Each case runs in a subprocess with a time
limit and without XLA_FLAGS; a hang shows as a timeout.

    python bench/eigh_deadlock.py [--n 200000] [--repeats 2] [--timeout 90]

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
from hgjax import _stream
from hgjax.scores import lhf
jax.config.update("jax_enable_x64", True)
LENGTHS = (6, 12)
p = hgjax.eval.box_union_cloud(seed=int(sys.argv[2]), n_points=int(sys.argv[1])).points
nb = hgjax.neighbourhoods(p, "lhf", variant="reference", lengths=LENGTHS)
def barrier(offsets, valid):
    signal, out = jax.numpy.where(valid[:, None], offsets, 0), []
    for n in LENGTHS:
        signal = jax.lax.optimization_barrier((signal, out))[0] if out else signal
        out.append(lhf._reference(signal[:n]))
    return jax.numpy.stack(out)
if sys.argv[3] != "split":
    hgjax.spectrum.host_eigh = jax.numpy.linalg.eigh  # jaxlib's LAPACK eigh
if sys.argv[3] == "barrier":
    g = _stream.map_neighbourhoods(barrier, nb)
elif sys.argv[3] == "joint":
    g = jax.jit(lambda nb: lhf.single(nb, lengths=LENGTHS, variant="reference"))(nb)
else:
    g = lhf.single(nb, lengths=LENGTHS, variant="reference")
print(float(np.asarray(g).sum()))
"""
LAYOUTS = {"split": "hgjax: NumPy eigh by host callback, one length per kernel",
           "joint": "jaxlib eigh, both lengths in one program (jit over the whole cloud)",
           "barrier": "jaxlib eigh, both lengths in one kernel with an optimization_barrier (previous)"}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--timeout", type=int, default=90)
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    rows = []
    for layout in LAYOUTS:
        for seed in range(args.repeats):
            start = time.perf_counter()
            try:
                subprocess.run([sys.executable, "-c", CASE, str(args.n), str(seed), layout], env=env, check=True,
                               timeout=args.timeout, capture_output=True)
                outcome = "finished"
            except subprocess.TimeoutExpired:
                outcome = f"HUNG (killed after {args.timeout} s)"
            rows.append((layout, seed, outcome, time.perf_counter() - start))
            print(rows[-1], flush=True)
    out = pathlib.Path(__file__).parent / "results" / "eigh_deadlock.md"
    lines = [f"# LHF reference eigh deadlock (jax {jax.__version__}, no XLA_FLAGS)", "",
             f"Command: `python bench/eigh_deadlock.py --n {args.n} --repeats {args.repeats} --timeout {args.timeout}`"
             f" on a {os.cpu_count()}-core CPU; box-union cloud of N = {args.n}, lengths (6, 12).", "",
             "| kernel layout | seed | outcome | wall time (incl. start-up and neighbourhoods) |", "|---|---|---|---|"]
    lines += [f"| {LAYOUTS[lay]} | {s} | {o} | {t:.1f} s |" for lay, s, o, t in rows]
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
