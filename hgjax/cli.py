"""The ``hgjax`` command line: resample, score, compare and demo.

Exit codes: 0 on success; 2 when the arguments or the input are invalid (a bad option, a
ratio outside (0, 1], an unknown method or variant, an unreadable or pointless input file,
an output extension that cannot be written, an input too small for the method); 1 when
something fails while computing or writing the result. Messages go to stderr, results
and tables to stdout; expected errors never print a Python traceback.
"""

from __future__ import annotations

import argparse
import ast
import csv
import inspect
import os
import sys
import time

import numpy as np

EPILOG = """\
examples:
  hgjax demo                                       all methods on a built-in box-union cloud
  hgjax resample scan.ply -o kept.ply --method hkc --ratio 0.2
  hgjax resample part.stl -o kept.npy --samples 50000 --method lhf
  hgjax score scan.pcd -o scores.csv --method hkf
  hgjax compare bunny.ply -o out/ --methods hkc,hkf,lhf,fps

Inputs: PLY, OBJ, STL, OFF, GLB/GLTF (meshes are sampled to --samples points), XYZ/TXT,
NPY and PCD. Points are computed in float32 by default; --dtype float64 turns on JAX's
x64 mode. Exit codes: 0 success, 1 failure while computing or writing, 2 invalid
arguments or input.
"""


class UsageError(Exception):
    """An invalid argument or input detected by the CLI (exit code 2)."""


def _ratio(text: str) -> float:
    from hgjax import _validate

    try:
        return _validate.check_ratio(float(text))
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err) if "(0, 1]" in str(err) else f"not a number: {text!r}")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1; got {value}")
    return value


def _param(text: str) -> tuple[str, object]:
    name, sep, value = text.partition("=")
    if not sep or not name.isidentifier():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE; got {text!r}")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


def _method_names() -> list[str]:
    from hgjax import METHODS

    return sorted(METHODS)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``hgjax`` command (exposed for documentation tools)."""
    from hgjax import __version__

    methods = _method_names()
    parser = argparse.ArgumentParser(prog="hgjax", description="Point-cloud resampling with hypergraph signal"
                                     " processing (HKC, HKF, LHF) and baselines, in JAX.",
                                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"hgjax {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--seed", type=int, default=0, help="seed of mesh sampling, subsets and random methods"
                        " (default 0)")
    common.add_argument("--dtype", choices=["float32", "float64"], default="float32",
                        help="computation dtype (default float32; float64 enables JAX x64)")
    common.add_argument("--quiet", "--no-progress", dest="progress", action="store_false",
                        help="no progress bar on stderr")

    def with_input(p):
        p.add_argument("input", metavar="IN", help="point cloud or mesh file")
        p.add_argument("--samples", type=_positive_int, default=None,
                       help="points sampled on a mesh (default 20000), or a seeded subset of a cloud")

    def with_method(p, names, default="hkc"):
        p.add_argument("--method", choices=names, default=default, help=f"one of {', '.join(names)}"
                       f" (default {default})")
        p.add_argument("--variant", default=None, help="score variant, e.g. invariant or reference")
        p.add_argument("-p", "--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help="extra method parameter, e.g. -p lengths=(10,30) (repeatable)")

    p = sub.add_parser("resample", parents=[common], help="keep a fraction of the points",
                       description="Keep ceil(ratio N) points. Output from the extension: .ply (kept points"
                       " with their attributes and the method's score), .xyz/.txt, or .npy (indices).")
    with_input(p)
    p.add_argument("-o", "--output", required=True, help="output file (.ply, .xyz, .txt or .npy)")
    with_method(p, methods)
    p.add_argument("--ratio", type=_ratio, default=0.2, help="fraction kept, in (0, 1] (default 0.2)")
    p.add_argument("--key", type=int, default=None, help="seed of jax.random.key for random methods"
                   " (default: --seed)")

    scored = [m for m in methods if _score_function(m) is not None]
    p = sub.add_parser("score", parents=[common], help="write per-point scores",
                       description="Write the method's per-point score: .ply (all points with a score"
                       " property), .npy (N,) or .csv (x, y, z, score). Methods whose score has"
                       " several parts (PCA-AC) write score_0, score_1, ...")
    with_input(p)
    p.add_argument("-o", "--output", required=True, help="output file (.ply, .npy or .csv)")
    with_method(p, scored)
    p.add_argument("--ratio", type=_ratio, default=0.2, help="ratio for scores that need one (LHF)")

    p = sub.add_parser("compare", parents=[common], help="run several methods and tabulate them",
                       description="Run several methods on one input; print a markdown table and, with"
                       " -o DIR, write compare.md, compare.csv and compare.png (needs matplotlib).")
    with_input(p)
    p.add_argument("-o", "--output", default=None, metavar="DIR", help="output folder")
    p.add_argument("--methods", default=",".join(methods), help="comma-separated methods (default: all)")
    p.add_argument("--ratio", type=_ratio, default=0.2, help="fraction kept (default 0.2)")

    p = sub.add_parser("demo", parents=[common], help="all methods on a built-in edge-labelled cloud",
                       description="Sample a union of boxes with known sharp edges, run every method and"
                       " print the point counts, the time and the precision of kept edge points.")
    p.add_argument("--n-points", type=_positive_int, default=20000, help="cloud size (default 20000)")
    p.add_argument("--ratio", type=_ratio, default=0.2, help="fraction kept (default 0.2)")
    return parser


def _score_function(method: str):
    """The public per-point score of a method (``hgjax.scores.<method>``), or None."""
    from hgjax import scores

    fn = getattr(scores, method, None)
    return fn if inspect.isfunction(fn) else None


def _score_columns(result) -> dict[str, np.ndarray]:
    """A score function's output as named (N,) columns: ``score``, or ``score_0``, ... for a tuple
    (e.g. PCA-AC's cluster number and surface variation)."""
    if isinstance(result, tuple):
        return {f"score_{i}": np.asarray(r) for i, r in enumerate(result)}
    return {"score": np.asarray(result)}


def _accepts(fn, name: str) -> bool:
    return fn is not None and name in inspect.signature(fn).parameters


def _method_params(args, fn, *, with_progress: bool) -> dict:
    params = dict(args.param)
    if args.variant is not None:
        params["variant"] = args.variant
    if with_progress and _accepts(fn, "progress"):
        params["progress"] = args.progress
    return params


def _load(args):
    from hgjax import io

    try:
        data = io.read_points(args.input, samples=args.samples, seed=args.seed)
    except io.PointCloudReadError as err:
        raise UsageError(str(err)) from None
    return data, data.points.astype(args.dtype)


def _key(args):
    import jax

    return jax.random.key(args.seed if getattr(args, "key", None) is None else args.key)


def _run_method(points, ratio, method, params, key):
    import hgjax

    start = time.perf_counter()
    idx = np.asarray(hgjax.resample(points, ratio, method=method, key=key, **params))
    return idx, time.perf_counter() - start


def cmd_resample(args) -> None:
    from hgjax import io

    ext = os.path.splitext(args.output)[1].lower()
    if ext not in io.WRITE_EXTENSIONS + (".npy",):
        raise UsageError(f"cannot write {args.output}: expected .ply, .xyz, .txt or .npy")
    data, points = _load(args)
    score_fn = _score_function(args.method)
    # The score is passed the progress flag; resample gets it only when its score takes it.
    idx, seconds = _run_method(points, args.ratio, args.method,
                               _method_params(args, score_fn, with_progress=True), _key(args))
    if ext == ".npy":
        io.write_indices(args.output, idx)
    else:
        kept = data.subset(idx)
        attributes = dict(kept.attributes)
        if ext == ".ply" and score_fn is not None:
            extra = {"ratio": args.ratio} if _accepts(score_fn, "ratio") else {}
            result = score_fn(points, **_method_params(args, score_fn, with_progress=False), **extra)
            attributes.update({name: col[idx] for name, col in _score_columns(result).items()})
        io.write_points(args.output, kept.points, attributes=attributes)
    print(f"{args.method}: kept {idx.size} of {len(data)} points in {seconds:.2f} s -> {args.output}",
          file=sys.stderr)


def cmd_score(args) -> None:
    from hgjax import io

    ext = os.path.splitext(args.output)[1].lower()
    if ext not in (".ply", ".npy", ".csv"):
        raise UsageError(f"cannot write {args.output}: expected .ply, .npy or .csv")
    data, points = _load(args)
    fn = _score_function(args.method)
    params = _method_params(args, fn, with_progress=True)
    if _accepts(fn, "ratio"):
        params["ratio"] = args.ratio
    start = time.perf_counter()
    columns = _score_columns(fn(points, **params))
    seconds = time.perf_counter() - start
    if ext == ".ply":
        io.write_points(args.output, data.points, attributes={**data.attributes, **columns})
    elif ext == ".npy":
        table = np.column_stack(list(columns.values()))
        np.save(args.output, table[:, 0] if table.shape[1] == 1 else table)
    else:
        with open(args.output, "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(["x", "y", "z", *columns])
            writer.writerows(np.column_stack([data.points, *columns.values()]).tolist())
    print(f"{args.method}: scored {len(data)} points in {seconds:.2f} s -> {args.output}", file=sys.stderr)


def _coverage(points: np.ndarray, idx: np.ndarray) -> tuple[float, float]:
    """Mean and max distance from every point to its nearest kept point."""
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(points[idx]).query(points, k=1, workers=-1)
    return float(dist.mean()), float(dist.max())


def cmd_compare(args) -> None:
    import hgjax

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = sorted(set(methods) - set(hgjax.METHODS))
    if unknown or not methods:
        raise UsageError(f"unknown method(s) {unknown}; expected a comma-separated subset of {sorted(hgjax.METHODS)}")
    data, points = _load(args)
    res = hgjax.intrinsic_resolution(data.points)
    rows, kept = [], {}
    for method in methods:
        params = {"progress": args.progress} if _accepts(_score_function(method), "progress") else {}
        idx, seconds = _run_method(points, args.ratio, method, params, _key(args))
        mean, worst = _coverage(data.points, idx)
        kept[method] = idx
        rows.append([method, idx.size, len(data), f"{seconds:.3f}", f"{mean / res:.3f}", f"{worst / res:.3f}"])
    header = ["method", "kept", "points", "seconds", "mean gap (res)", "max gap (res)"]
    table = "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                      + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows])
    print(f"{args.input}: ratio {args.ratio}, resolution {res:.4g} (gap = distance from a point to the"
          f" nearest kept point)\n\n{table}")
    if args.output is None:
        return
    os.makedirs(args.output, exist_ok=True)
    with open(os.path.join(args.output, "compare.md"), "w") as fh:
        fh.write(table + "\n")
    with open(os.path.join(args.output, "compare.csv"), "w", newline="") as fh:
        csv.writer(fh).writerows([header] + rows)
    try:
        from hgjax.plot import show_resampling

        show_resampling(data.points, kept, title=os.path.basename(args.input),
                        path=os.path.join(args.output, "compare.png"))
    except ImportError as err:
        print(f"no picture written: {err}", file=sys.stderr)
    print(f"wrote compare.md, compare.csv{', compare.png' * os.path.exists(os.path.join(args.output, 'compare.png'))}"
          f" to {args.output}", file=sys.stderr)


def cmd_demo(args) -> None:
    import hgjax

    cloud = hgjax.eval.box_union_cloud(seed=args.seed, n_points=args.n_points)
    points = cloud.points.astype(args.dtype)
    edge = np.asarray(cloud.edge_mask)
    print(f"demo cloud: {points.shape[0]} points on a union of boxes, {int(edge.sum())} labelled edge points,"
          f" keeping {args.ratio:g}")
    print(f"{'method':<8} {'points':>7} {'kept':>6} {'seconds':>8} {'edge precision':>15}")
    for method in sorted(hgjax.METHODS):
        params = {"progress": args.progress} if _accepts(_score_function(method), "progress") else {}
        idx, seconds = _run_method(points, args.ratio, method, params, _key(args))
        precision = float(edge[idx].mean())
        print(f"{method:<8} {points.shape[0]:>7} {idx.size:>6} {seconds:>8.2f} {precision:>15.3f}")
    print(f"(a random subset keeps edge points with precision {edge.mean():.3f} on average)")


COMMANDS = {"resample": cmd_resample, "score": cmd_score, "compare": cmd_compare, "demo": cmd_demo}


def main(argv=None) -> int:
    """Run the ``hgjax`` command line.

    Args:
      argv: the arguments without the program name (default: ``sys.argv[1:]``).

    Returns:
      The exit code: 0 success, 1 failure while computing or writing, 2 invalid arguments
      or input.

    Examples:
      >>> main(["demo", "--n-points", "0"])
      2
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad arguments, 0 after --help/--version
        return int(exc.code or 0)
    if args.dtype == "float64":
        import jax

        jax.config.update("jax_enable_x64", True)
    try:
        COMMANDS[args.command](args)
    except UsageError as err:
        print(f"hgjax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (ValueError, TypeError) as err:  # hgjax's validation of points and parameters
        print(f"hgjax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError, MemoryError) as err:
        print(f"hgjax {args.command}: failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    return 0
