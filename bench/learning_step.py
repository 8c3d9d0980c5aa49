"""A learning step as JAX users run it: a batch of moving clouds, neighbourhoods rebuilt inside ``jit``.

Usage:
  python bench/learning_step.py --batch 32 --n 4096 --methods ea,lhf,mss --repeats 5 --out bench/results/learning_step.md

For each method, in a fresh process: ``--batch`` float32 clouds of ``--n`` points (the box surface of
``_report.box_cloud`` and ``batch - 1`` seeded rotations of it), each sheared by its own learnable
parameter s (z += s x); one step is

    value, grad = jax.jit(jax.value_and_grad(loss))(s)
    loss(s) = sum over clouds of (soft_weights(neighbourhoods(p(s), m, search="jax"), ratio, method=m) * z).sum()

with the neighbourhoods rebuilt by the traced search from the moved points under ``jax.vmap``
(no sizes passed), so a compiled step serves every s. Reported: the first call (compile and run)
and its XLA compilations, the compilations of the later steps (with other s: none expected), and the median step over ``--repeats`` steps, each with a new s, beside the floor (a
cKDTree kNN16 query with its tree build, on the Morton-sorted copy of all ``batch x n`` points,
timed before each step).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _report  # noqa: E402

RATIO = 0.2
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


def batch_clouds(batch: int, n: int):
    """(batch, n, 3) float32: the box surface and ``batch - 1`` seeded random rotations of it."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    p = _report.box_cloud(n, np.float32).astype(np.float64)
    turns = Rotation.random(batch - 1, random_state=0).as_matrix() if batch > 1 else np.zeros((0, 3, 3))
    return np.stack([p] + [p @ r.T for r in turns]).astype(np.float32)


def measure(method: str, batch: int, n: int, repeats: int) -> dict:
    """One method's step, in this process."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import hgjax

    clouds = jnp.asarray(batch_clouds(batch, n))
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, seconds, **_: compiles.append(seconds) if event == COMPILE_EVENT else None)

    def one(p, s):
        moved = p.at[:, 2].add(s * p[:, 0])
        weights = hgjax.soft_weights(hgjax.neighbourhoods(moved, method, search="jax"), RATIO, method=method)
        return (weights * moved[:, 2]).sum()

    step = jax.jit(jax.value_and_grad(lambda s: jax.vmap(one)(clouds, s).sum()))
    shears = [jnp.full((batch,), 0.01 * (i + 1), jnp.float32) for i in range(repeats + 1)]
    jax.block_until_ready(shears)
    compiles.clear()
    t = time.perf_counter()
    value, grad = jax.block_until_ready(step(shears[0]))
    first = time.perf_counter() - t
    first_compiles = len(compiles)
    q = _report.morton_copy(np.asarray(clouds).reshape(-1, 3))
    floors, steps = [], []
    for s in shears[1:]:
        floors.append(_report.knn16_seconds(q))
        t = time.perf_counter()
        value, grad = jax.block_until_ready(step(s))
        steps.append(time.perf_counter() - t)
    finite = bool(np.isfinite(np.asarray(value)) and np.isfinite(np.asarray(grad)).all())
    return {"method": method, "batch": batch, "n": n, "first s": first, "compiles": first_compiles,
            "later compiles": len(compiles) - first_compiles,
            "step s": statistics.median(steps), "floor s": statistics.median(floors),
            "ratio": statistics.median(a / b for a, b in zip(steps, floors)), "finite": finite,
            "device": jax.devices()[0].device_kind}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--n", type=int, default=4096)
    ap.add_argument("--methods", default="ea,lhf,mss")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # measure this method in this process
    args = ap.parse_args()
    if args.one:
        print(json.dumps(measure(args.one, args.batch, args.n, args.repeats)))
        return
    rows = []
    for m in args.methods.split(","):
        rows.append(_report.spawn(Path(__file__), ["--one", m, "--batch", args.batch, "--n", args.n,
                                                   "--repeats", args.repeats]))
        rows[-1].setdefault("method", m)
        print(json.dumps(rows[-1]), flush=True)
    table = ["| method | batch x N | device | first call s | compiles (first; later) | step s (median) | floor s |"
             " step / floor | value and grad finite |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            table.append(f"| {r['method']} | error: {r['error']} |" + " |" * 7)
            continue
        table.append(f"| {r['method']} | {r['batch']} x {r['n']:,} | {r['device']} | {r['first s']:.1f} |"
                     f" {r['compiles']}; {r['later compiles']} | {r['step s']:.3f} | {r['floor s']:.3f} | {r['ratio']:.1f} | {r['finite']} |")
    print("\n".join(table))
    if args.out:
        _report.write(args.out, "learning_step.py", None, title="A learning step: moving clouds, traced neighbourhoods,"
                      " soft weights, value_and_grad", paragraphs=[_report.machine(), __doc__.split("\n\n", 2)[2]],
                      table=table)


if __name__ == "__main__":
    main()
