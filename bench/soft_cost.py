"""Cost of gradients through soft resampling: forward vs forward + gradient, per smooth score.

For each smooth score (``hgjax.soft_score``) and each size N, on an edge-labelled box-union
cloud (:func:`hgjax.eval.box_union_cloud`, noise 0.1 resolution), the host neighbourhoods
are built once (``hgjax.neighbourhoods``), then two jitted functions of the points are timed
after compilation (median of ``--repeats`` runs):

* forward: ``soft_weights(nb, ratio, method=...)`` (smooth score + soft top-k), (N,) weights;
* forward + gradient: ``jax.value_and_grad`` of sum(c * weights) with respect to the points
  (``nb.points``), the voxel spacing ``nb.scale`` where the method has one, and the float
  parameters (temperature, tau where the method has it).

Usage (writes bench/results/soft_cost.md):

    python bench/soft_cost.py [--sizes 10000 100000] [--repeats 5] [--dtype float32] [--methods hkc ea]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import hgjax  # noqa: E402

RATIO = 0.2
METHODS = ("hkc", "lhf", "ea", "gfr")  # soft "hkf" is the same function as soft "hkc"


def median_time(fn, args, repeats):
    jax.block_until_ready(fn(*args))  # compile and warm up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def run(method, n, repeats, dtype):
    cloud = hgjax.eval.box_union_cloud(seed=0, n_points=n, noise=0.1)
    pts = cloud.points.astype(dtype)
    t = time.perf_counter()
    nb = hgjax.neighbourhoods(pts, method)
    host = time.perf_counter() - t
    c = jnp.asarray(np.random.default_rng(0).random(n), dtype)
    has_tau = "tau" in hgjax.METHODS[method].params["soft_score"]

    def weights(p, scale, temperature, tau):
        params = {"tau": tau} if has_tau else {}
        return hgjax.soft_weights(hgjax.Neighbourhoods(p, nb.idx, scale), RATIO, method=method,
                                  temperature=temperature, **params)

    def loss(p, scale, temperature, tau):
        return jnp.sum(c * weights(p, scale, temperature, tau))

    args = (jnp.asarray(nb.points), None if nb.scale is None else jnp.asarray(nb.scale), dtype(0.05), dtype(0.1))
    argnums = (0, 1, 2, 3) if nb.scale is not None else (0, 2, 3)
    fwd = median_time(jax.jit(weights), args, repeats)
    grad = median_time(jax.jit(jax.value_and_grad(loss, argnums=argnums)), args, repeats)
    return host, fwd, grad, nb.idx.shape[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=sorted(hgjax.METHODS))
    parser.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                                      "soft_cost.md"))
    a = parser.parse_args()
    if a.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    dtype = np.dtype(a.dtype).type
    rows = []
    for n in a.sizes:
        for method in a.methods:
            host, fwd, grad, k = run(method, n, a.repeats, dtype)
            rows.append(f"| {method} | {n:,} | {k} | {host:.3f} | {fwd:.3f} | {grad:.3f} | {grad / fwd:.1f} |")
            print(rows[-1], flush=True)
    cmd = "python bench/soft_cost.py " + " ".join(sys.argv[1:])
    lines = [
        "# Soft resampling: cost of the gradient",
        "",
        f"Command: `{cmd.strip()}`",
        "",
        f"Machine: {os.cpu_count()} CPU cores, {platform.processor() or platform.machine()}, "
        f"jax {jax.__version__} on {jax.devices()[0].platform}; dtype {a.dtype}; ratio {RATIO}; "
        f"box-union clouds (seed 0, noise 0.1 resolution). Seconds, median of {a.repeats} runs after "
        "compilation. `host` = building the neighbourhoods once (SciPy, not differentiated); "
        "`forward` = jitted `soft_weights` (smooth score + soft top-k); `fwd+grad` = jitted "
        "`value_and_grad` of sum(c * weights) with respect to the points, the voxel spacing d (HKC), temperature and tau.",
        "",
        "| score | N | K | host (s) | forward (s) | fwd+grad (s) | ratio |",
        "|---|---:|---:|---:|---:|---:|---:|",
        *rows,
        "",
    ]
    with open(a.out, "w") as f:
        f.write("\n".join(lines))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
