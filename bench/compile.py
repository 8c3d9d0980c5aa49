"""Compilations across cloud sizes: a new N must not recompile the kernels.

In one process, resamples 10 box-union clouds of different N (geometric, 1e4 to 2e5) with
each scoring method, counting XLA backend compilations per method (``jax.monitoring``) and
timing, at each N, the first call against the median of repeated calls on the same cloud.
Each method first resamples one warm-up cloud of another size (N = 5000), which pays its
compilations (counted with the rest); a new N after that must compile nothing.

    python bench/compile.py [--methods hkc hkf lhf ea gfr pca_ac] [--repeats 3]

Writes bench/results/compile.md.

``--grad`` instead times the compilation of a soft-resampling loss, sum(c * soft_weights),
forward against ``jax.value_and_grad`` (gradients with respect to the points), for each method
of ``--methods`` on one box-union cloud of N = 2000: ``jax.jit(f).lower(points).compile()``
after ``jax.clear_caches()``, medians of ``--repeats``. Writes bench/results/compile_grad.md.

    python bench/compile.py --grad --methods lhf hkc ea --repeats 3

``--cold`` times each method's first eager ``hgjax.resample`` of a 3,000-point box-union cloud
(float64 NumPy input, JAX's defaults: x64 off, no persistent cache) in a fresh process per
method, against its second call, with the XLA compilations it made and their backend seconds
(issue 47, item 7: the first call within 3 s), and the whole run of
``notebooks/soft_resampling.ipynb`` (nbclient, a fresh kernel each time; item 7: within 60 s).
Writes bench/results/compile_cold.md.

    python bench/compile.py --cold --methods hkc hkf lhf ea gfr pca_ac mss --repeats 3
"""

import argparse
import dataclasses
import json
import os
import pathlib
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import hgjax

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _report  # noqa: E402

_compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: _compiles.append(duration) if event == "/jax/core/compile/backend_compile_duration"
    else None)

SIZES = np.geomspace(1e4, 2e5, 10).astype(int)
WARM_UP = 5000
SELECT = {"gfr": {"mode": "top"}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=["hkc", "hkf", "lhf", "ea", "gfr", "pca_ac"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--grad", action="store_true", help="forward against value_and_grad compile times")
    parser.add_argument("--cold", action="store_true", help="first eager call per method in a fresh process")
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)  # --cold: this method, in this process
    args = parser.parse_args()
    if args.one:
        return print(json.dumps(cold_call(args.one)))
    if args.cold:
        return cold_calls(args)
    jax.config.update("jax_enable_x64", True)
    if args.grad:
        return grad_compiles(args)
    clouds = {n: hgjax.eval.box_union_cloud(seed=int(n), n_points=int(n)).points for n in SIZES}
    warm_up = hgjax.eval.box_union_cloud(seed=1, n_points=WARM_UP).points
    rows = []
    for method in args.methods:
        params = SELECT.get(method, {})
        before = len(_compiles)
        hgjax.resample(warm_up, 0.2, method=method, **params)
        ratios = []
        for n, p in clouds.items():
            start = time.perf_counter()
            hgjax.resample(p, 0.2, method=method, **params)
            first = time.perf_counter() - start
            again = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                hgjax.resample(p, 0.2, method=method, **params)
                again.append(time.perf_counter() - start)
            ratios.append((n, first, statistics.median(again)))
        count = len(_compiles) - before
        rows.append((method, count, ratios))
        worst = max(r[1] / r[2] for r in ratios)
        print(method, "compilations", count, "worst first/repeat", round(worst, 2), flush=True)
    out = pathlib.Path(__file__).parent / "results" / "compile.md"
    lines = ["# Compilations across cloud sizes", "",
             f"Command: `python bench/compile.py --methods {' '.join(args.methods)} --repeats {args.repeats}`"
             f" (jax {jax.__version__}, {os.cpu_count()} cores, float64).", "",
             f"Ten box-union clouds, N = {', '.join(str(n) for n in SIZES)}, resampled at ratio 0.2 in one process."
             " Each method first resamples a warm-up cloud of N = 5000, which pays its compilations (counted)."
             " 'first / repeat' is the first call at each new N over the median of the repeated calls on the same"
             " cloud.", "",
             "| method | compilations | first / repeat at each N |", "|---|---|---|"]
    for method, count, ratios in rows:
        cells = ", ".join(f"{f / r:.2f}" for _, f, r in ratios)
        lines.append(f"| {method} | {count} | {cells} |")
    lines += ["", "Repeated-call medians (s): "]
    for method, _, ratios in rows:
        lines.append(f"- {method}: " + ", ".join(f"{n}: {r:.3f}" for n, _, r in ratios))
    out.write_text("\n".join(lines) + "\n")


def _compile_seconds(fn, points) -> float:
    jax.clear_caches()
    start = time.perf_counter()
    jax.jit(fn).lower(points).compile()
    return time.perf_counter() - start


def grad_compiles(args) -> None:
    """Compile seconds of a soft-resampling loss, forward and value_and_grad, per method."""
    cloud = jnp.asarray(hgjax.eval.box_union_cloud(seed=0, n_points=2000).points)
    c = jnp.asarray(np.random.default_rng(0).random(cloud.shape[0]))
    rows = []
    for method in args.methods:
        nb = hgjax.neighbourhoods(np.asarray(cloud), method)
        loss = lambda p, nb=nb, method=method: jnp.sum(  # noqa: E731
            c * hgjax.soft_weights(dataclasses.replace(nb, points=p), 0.2, method=method))
        forward = statistics.median(_compile_seconds(loss, cloud) for _ in range(args.repeats))
        grad = statistics.median(_compile_seconds(jax.value_and_grad(loss), cloud) for _ in range(args.repeats))
        rows.append((method, forward, grad))
        print(method, "forward", round(forward, 2), "value_and_grad", round(grad, 2), flush=True)
    lines = ["# Compile time of a soft-resampling loss: forward against value_and_grad", "",
             f"Command: `python bench/compile.py --grad --methods {' '.join(args.methods)} --repeats {args.repeats}`"
             f" (jax {jax.__version__}, {os.cpu_count()} cores, float64).", "",
             "loss(points) = sum(c * soft_weights(nb with points, 0.2, method)) on a box-union cloud of N = 2000;"
             " seconds of `jax.jit(f).lower(points).compile()` after `jax.clear_caches()`, medians of"
             f" {args.repeats}. Target (issue 23): LHF's value_and_grad at most 4x its forward.", "",
             "| method | forward s | value_and_grad s | grad / forward |", "|---|---|---|---|"]
    lines += [f"| {m} | {f:.2f} | {g:.2f} | {g / f:.2f} |" for m, f, g in rows]
    (pathlib.Path(__file__).parent / "results" / "compile_grad.md").write_text("\n".join(lines) + "\n")


COLD_N = 3000
NOTEBOOK = pathlib.Path(__file__).resolve().parents[1] / "notebooks" / "soft_resampling.ipynb"


def _notebook_seconds(path: pathlib.Path) -> float:
    """Seconds to run a notebook whole in a fresh kernel (nbclient)."""
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    start = time.perf_counter()
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(path.parent)}}).execute()
    return time.perf_counter() - start


def cold_call(method: str) -> dict:
    """Seconds of this fresh process's first and second eager resample with ``method``, and its compilations."""
    jax.config.update("jax_enable_x64", False)  # JAX's defaults, whatever the environment sets
    jax.config.update("jax_compilation_cache_dir", None)
    points = hgjax.eval.box_union_cloud(seed=0, n_points=COLD_N).points
    params = SELECT.get(method, {})
    start = time.perf_counter()
    hgjax.resample(points, 0.2, method=method, **params)
    first = time.perf_counter() - start
    compiles = list(_compiles)
    start = time.perf_counter()
    hgjax.resample(points, 0.2, method=method, **params)
    return {"first": first, "second": time.perf_counter() - start, "compilations": len(compiles),
            "compile_s": sum(compiles)}


def cold_calls(args) -> None:
    """Each method's first call in ``--repeats`` fresh processes; medians."""
    rows = []
    for method in args.methods:
        runs = [_report.spawn(pathlib.Path(__file__).resolve(), ["--one", method]) for _ in range(args.repeats)]
        failed = [r["error"] for r in runs if "error" in r]
        if failed:
            raise RuntimeError(f"{method}: {failed[0]}")
        row = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        rows.append((method, row))
        print(method, json.dumps(row), flush=True)
    notebook = statistics.median(_notebook_seconds(NOTEBOOK) for _ in range(args.repeats))
    print(NOTEBOOK.name, round(notebook, 1), flush=True)
    lines = ["# The first eager call of each method, from a cold start", "",
             f"Command: `python bench/compile.py --cold --methods {' '.join(args.methods)} --repeats {args.repeats}`"
             f" (jax {jax.__version__}, {os.cpu_count()} cores).", "",
             f"A box-union cloud of N = {COLD_N} (float64 NumPy), `hgjax.resample(points, 0.2, method=m)` in a fresh"
             " process per run (JAX's defaults: x64 off, no persistent compilation cache; hgjax imported before the"
             f" clock starts), medians of {args.repeats} processes. Compilations: XLA backend compiles during the first"
             " call, and their summed seconds. Target (issue 47, item 7): the first call within 3 s.", "",
             "| method | first call s | second call s | compilations | backend compile s |", "|---|---|---|---|---|"]
    lines += [f"| {m} | {r['first']:.2f} | {r['second']:.3f} | {r['compilations']:.0f} | {r['compile_s']:.2f} |"
              for m, r in rows]
    lines += ["", f"`notebooks/{NOTEBOOK.name}` run whole (nbclient, a fresh kernel each run, cells' compilations"
              f" included): {notebook:.1f} s, the median of {args.repeats}."]
    (pathlib.Path(__file__).parent / "results" / "compile_cold.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
