"""The ``hgjax`` command line: resample, score, compare and demo.

Every method comes from the registry :data:`hgjax.METHODS`: its neighbourhood kind, which
end of the score is kept, whether it draws random numbers and which ``-p NAME=VALUE``
parameters it takes. A scoring method is run as ``neighbourhoods -> score -> keep``, so
the score is computed once and written next to the kept points.

Points are read in float64 and moved to their local frame (:func:`hgjax.local_frame`) in
float64 before the library sees them, so georeferenced scans (UTM coordinates of 1e6 m)
keep their millimetres with every method; outputs keep the original coordinates.
``--dtype float32`` (default) then computes in float32, and the library's
:class:`hgjax.PrecisionWarning` about that is silenced because it is the requested
behaviour; ``--dtype float64`` turns on JAX's x64 mode for the run.

JAX's persistent compilation cache is on, in ``$HGJAX_CACHE_DIR`` (empty: off), else
``$XDG_CACHE_HOME/hgjax/jax``, else ``~/.cache/hgjax/jax``, so a second run skips the
compilation of the first. Within one run, files of different sizes share the compiled
kernels (the library streams fixed-size chunks).

Exit codes: 0 success; 1 failure while computing or writing; 2 invalid arguments or
input, detected before any computation where possible (bad option, ratio, count, seed or
parameter, unreadable input, unwritable output, too many samples for the memory); 130
interrupted (Ctrl-C). Messages go to stderr, tables to stdout; user errors never print a
Python traceback.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import csv
import os
import sys
import time
import warnings

import numpy as np

EPILOG = """\
examples:
  hgjax demo                                       all methods on a built-in box-union cloud
  hgjax resample scan.ply -o kept.ply --method hkc --ratio 0.2
  hgjax resample scan.laz -o kept.laz --count 100000 --method lhf
  hgjax resample scans/ -o kept/ --format pcd      every point file of scans/, one output each
  hgjax resample part.stl -o kept.npy --samples 50000 --method lhf   (.npy: kept indices)
  hgjax resample scan.ply -o grid.ply --method voxel --voxel-size 0.05
  hgjax score scan.pcd -o scored.ply --method hkf
  hgjax compare bunny.ply -o out/ --methods hkc,hkf,lhf,fps

Inputs: PLY, PCD, LAS/LAZ, XYZ/TXT, NPY point clouds, and meshes (OBJ, STL, OFF, GLB/GLTF,
PLY with faces) sampled to --samples points; a directory stands for its point and mesh
files, sorted. Outputs: PLY, PCD, LAS/LAZ, XYZ/TXT with the input's attributes and a
`score` attribute for scoring methods; .npy: the kept indices (resample) or a table with a
`score` field (score). With several inputs, a directory or -o DIR, each output is named
after its input's stem with the --format extension.

Computation is in float32 after moving the points to a local frame in float64 (UTM
coordinates are safe); --dtype float64 turns on JAX's x64 mode. Compiled kernels are
cached in $HGJAX_CACHE_DIR (empty: no cache), else $XDG_CACHE_HOME/hgjax/jax or
~/.cache/hgjax/jax.

exit codes:
  0    success
  1    failure while computing or writing
  2    invalid arguments or input (found before computing where possible)
  130  interrupted (Ctrl-C)
"""

DEFAULT_RATIO = 0.2
SEED_LIMIT = 2**32
BYTES_PER_SAMPLE = 2048
"""Peak memory per point sampled on a mesh and resampled (measured: ~190 bytes to sample
fandisk.obj, ~1700 more for HKC; rounded up). ``--samples`` is refused above the available
memory divided by this."""
FALLBACK_MEMORY = 8 * 2**30
"""Memory assumed where neither /proc/meminfo nor ``os.sysconf`` tells."""
MESH_EXTENSIONS = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")
INPUT_EXTENSIONS = (".ply", ".pcd", ".las", ".laz", ".xyz", ".txt", ".npy") + MESH_EXTENSIONS[1:]
CLI_PARAMS = {"ratio": "--ratio or --count", "voxel_size": "--voxel-size", "progress": "--quiet",
              "key": "--key"}
"""Method parameters set by options of their own, not by ``-p``."""


class UsageError(Exception):
    """An invalid argument or input detected by the CLI (exit code 2)."""


def _ratio(text: str) -> float:
    from hgjax import _validate

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    try:
        return _validate.check_ratio(value)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _positive(cast):
    """An argparse type: ``cast(text)``, finite and > 0."""

    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {'an integer' if cast is int else 'a number'}: {text!r}") from None
        if not (value > 0 and np.isfinite(value)):
            raise argparse.ArgumentTypeError(f"must be {'>= 1' if cast is int else 'a finite number > 0'}; got {text}")
        return value

    return parse


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 0 <= value < SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"must be in [0, 2**32); got {value}")
    return value


def _param(text: str) -> tuple[str, object]:
    name, sep, value = text.partition("=")
    if not sep or not name.isidentifier():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE; got {text!r}")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``hgjax`` command (exposed for documentation tools)."""
    from hgjax import METHODS, __version__, io

    methods = sorted(METHODS)
    scoring = [m for m in methods if METHODS[m].kind is not None]
    formats = [ext[1:] for ext in io.WRITE_EXTENSIONS]
    parser = argparse.ArgumentParser(prog="hgjax", description="Point-cloud resampling with hypergraph signal"
                                     " processing (HKC, HKF, LHF) and baselines, in JAX.",
                                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"hgjax {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--seed", type=_seed, default=0, help="seed of mesh sampling, subsets and random"
                        " methods, in [0, 2**32) (default 0)")
    common.add_argument("--dtype", choices=["float32", "float64"], default="float32",
                        help="computation dtype (default float32, after a float64 local frame; float64"
                        " enables JAX x64)")
    common.add_argument("--quiet", "--no-progress", dest="progress", action="store_false",
                        help="no progress bar (shown only when stderr is a terminal)")

    def with_inputs(p, several):
        if several:
            p.add_argument("inputs", nargs="+", metavar="IN", help="point cloud or mesh files, or directories")
            p.add_argument("-o", "--output", required=True, metavar="OUT",
                           help="output file (one input) or directory (created when missing)")
            p.add_argument("--format", choices=formats, default=None,
                           help="output format in a directory (default ply)")
        else:
            p.add_argument("inputs", nargs=1, metavar="IN", help="point cloud or mesh file")
        p.add_argument("--samples", type=_positive(int), default=None,
                       help="points sampled on a mesh (default 20000), or a seeded subset of a cloud")

    def with_method(p, names):
        p.add_argument("--method", choices=names, default="hkc", help=f"one of {', '.join(names)} (default hkc)")
        p.add_argument("--variant", default=None, help="score variant, e.g. invariant or reference")
        p.add_argument("-p", "--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help="method parameter, e.g. -p lengths=(10,30) (repeatable; see hgjax.METHODS)")

    p = sub.add_parser("resample", parents=[common], help="keep a fraction of the points",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Keep ceil(ratio N) points, or exactly --count. The output keeps the"
                       " input's attributes plus the method's `score`; .npy writes the kept indices.")
    with_inputs(p, several=True)
    with_method(p, methods)
    size = p.add_mutually_exclusive_group()
    size.add_argument("--ratio", type=_ratio, default=None, help=f"fraction kept, in (0, 1] (default"
                      f" {DEFAULT_RATIO})")
    size.add_argument("--count", type=_positive(int), default=None, metavar="M",
                      help="number of points kept, in [1, N]")
    p.add_argument("--voxel-size", type=_positive(float), default=None, metavar="S",
                   help="voxel method: one point per voxel of edge S (with --ratio/--count: that many)")
    p.add_argument("--key", type=_seed, default=None, help="seed of jax.random.key for random methods"
                   " (default: --seed)")

    p = sub.add_parser("score", parents=[common], help="write per-point scores",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Write every point with the method's per-point `score` attribute.")
    with_inputs(p, several=True)
    with_method(p, scoring)
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help="ratio for scores that need one (LHF)")

    p = sub.add_parser("compare", parents=[common], help="run several methods and tabulate them",
                       description="Run several methods on one input; print a markdown table and, with"
                       " -o DIR, write compare.md, compare.csv and compare.png (needs matplotlib).")
    with_inputs(p, several=False)
    p.add_argument("-o", "--output", default=None, metavar="DIR", help="output folder")
    p.add_argument("--methods", default=",".join(methods), help="comma-separated methods (default: all)")
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help=f"fraction kept (default {DEFAULT_RATIO})")

    p = sub.add_parser("demo", parents=[common], help="all methods on a built-in edge-labelled cloud",
                       description="Sample a union of boxes with known sharp edges, run every method and"
                       " print the point counts, the time and the precision of kept edge points.")
    p.add_argument("--n-points", type=_positive(int), default=20000, help="cloud size (default 20000)")
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help=f"fraction kept (default {DEFAULT_RATIO})")
    return parser


def cache_dir() -> str | None:
    """The persistent compilation cache directory: ``$HGJAX_CACHE_DIR`` (empty: None, no
    cache), else ``$XDG_CACHE_HOME/hgjax/jax``, else ``~/.cache/hgjax/jax``."""
    if "HGJAX_CACHE_DIR" in os.environ:
        return os.environ["HGJAX_CACHE_DIR"] or None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "hgjax", "jax")


def _print_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"hgjax: warning: {message}", file=sys.stderr)


@contextlib.contextmanager
def _session(dtype: str):
    """JAX and warning settings for one run, restored afterwards: x64 for float64, the
    persistent compilation cache, one-line warnings, no PrecisionWarning for float32."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    import hgjax

    settings = {"jax_enable_x64": dtype == "float64"}
    directory = cache_dir()
    if directory is not None:
        try:
            os.makedirs(directory, exist_ok=True)
        except OSError as err:
            print(f"hgjax: warning: no compilation cache: cannot create {directory}: {err.strerror}",
                  file=sys.stderr)
        else:
            settings.update(jax_compilation_cache_dir=directory, jax_persistent_cache_min_compile_time_secs=0.0,
                            jax_persistent_cache_min_entry_size_bytes=-1)
    saved = {name: getattr(jax.config, name) for name in settings}
    try:
        for name, value in settings.items():
            jax.config.update(name, value)
        compilation_cache.reset_cache()
        with warnings.catch_warnings():
            warnings.showwarning = _print_warning
            if dtype == "float32":
                warnings.filterwarnings("ignore", category=hgjax.PrecisionWarning)
            yield
    finally:
        for name, value in saved.items():
            jax.config.update(name, value)
        compilation_cache.reset_cache()


def _expand(paths: list[str]) -> list[str]:
    """Input files: each path, or the supported files of a directory (sorted)."""
    files = []
    for path in paths:
        if os.path.isdir(path):
            found = sorted(entry.path for entry in os.scandir(path)
                           if entry.is_file() and os.path.splitext(entry.name)[1].lower() in INPUT_EXTENSIONS)
            if not found:
                raise UsageError(f"{path}: no point cloud or mesh files (expected {', '.join(INPUT_EXTENSIONS)})")
            files += found
        elif not os.path.exists(path):
            raise UsageError(f"cannot read {path}: no such file")
        else:
            files.append(path)
    return files


def _targets(inputs: list[str], output: str, fmt: str | None) -> list[str]:
    """The output path of each input, checked writable (directories are created)."""
    from hgjax import io

    ext = os.path.splitext(output)[1].lower()
    is_file = len(inputs) == 1 and ext and not os.path.isdir(output) and not output.endswith(("/", os.sep))
    if is_file:
        if fmt is not None and f".{fmt}" != ext:
            raise UsageError(f"--format {fmt} disagrees with the extension of -o {output}")
        targets = [output]
    else:
        try:
            os.makedirs(output, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot create the output directory {output}: {err.strerror}") from None
        stems = [os.path.splitext(os.path.basename(path))[0] for path in inputs]
        targets = [os.path.join(output, f"{stem}.{fmt or 'ply'}") for stem in stems]
        clashes = sorted({t for t in targets if targets.count(t) > 1})
        if clashes:
            raise UsageError(f"several inputs would be written to {', '.join(clashes)}; give inputs with"
                             " distinct names")
    for target in targets:
        io.check_writable(target)
    return targets


def _available_memory() -> int:
    """Bytes of memory available: MemAvailable of /proc/meminfo, else the physical memory."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_MEMORY


def _is_mesh(path: str) -> bool:
    """Whether ``path`` is a mesh (sampled to ``--samples`` points): by extension, and for
    PLY by a face element in its header."""
    ext = os.path.splitext(path)[1].lower()
    if ext != ".ply":
        return ext in MESH_EXTENSIONS
    try:
        with open(path, "rb") as fh:
            for line in iter(fh.readline, b""):
                words = line.split()
                if words[:1] == [b"end_header"]:
                    break
                if words[:2] == [b"element", b"face"] and len(words) > 2 and words[2] != b"0":
                    return True
    except OSError:
        pass
    return False


def _check_samples(samples: int | None, inputs: list[str]) -> None:
    """Refuse ``--samples`` on a mesh beyond what the memory holds, before sampling."""
    meshes = [path for path in inputs if _is_mesh(path)]
    if samples is None or not meshes:
        return
    available = _available_memory()
    if samples * BYTES_PER_SAMPLE > available:
        raise UsageError(f"--samples {samples} needs about {samples * BYTES_PER_SAMPLE / 1e9:.1f} GB to sample"
                         f" {meshes[0]} and resample it, more than the {available / 1e9:.1f} GB available; use"
                         f" --samples {available // BYTES_PER_SAMPLE} or fewer")


def _load(path: str, args):
    from hgjax import io

    return io.read_points(path, samples=args.samples, seed=args.seed)


def _method_params(args, entry) -> dict:
    """``-p`` and ``--variant`` parameters, checked against the registry entry's parameters of
    the stages the CLI runs (build, score, select: not the soft score's ``tau``)."""
    params = {}
    for name, value in args.param:
        if name in CLI_PARAMS:
            raise UsageError(f"-p {name}: set it with {CLI_PARAMS[name]}")
        if name in params:
            raise UsageError(f"-p {name} is given twice")
        params[name] = value
    if args.variant is not None:
        if "variant" in params:
            raise UsageError("give the variant once: --variant or -p variant=...")
        params["variant"] = args.variant
    accepted = entry.params["build"] | entry.params["score"] | entry.params["select"]
    unknown = sorted(set(params) - accepted)
    if unknown:
        takes = ", ".join(sorted(accepted - set(CLI_PARAMS))) or "no parameters"
        raise UsageError(f"method {entry.name!r} does not take {', '.join(unknown)} (from -p/--variant);"
                         f" it takes: {takes}")
    return params


def _key(args):
    import jax

    return jax.random.key(args.seed if getattr(args, "key", None) is None else args.key)


def _progress(args) -> bool:
    return args.progress and sys.stderr.isatty()


def _score(entry, points, ratio, params, progress: bool) -> np.ndarray:
    """Per-point scores of a scoring method: neighbourhoods, then the JAX score."""
    import hgjax

    nb = hgjax.neighbourhoods(points, entry.name, **params)
    extra = {"ratio": ratio} if "ratio" in entry.params["score"] else {}
    if progress and "progress" in entry.params["score"]:
        extra["progress"] = True
    return np.asarray(hgjax.score(nb, entry.name, **params, **extra))


def _compute(entry, points, ratio, params, key, progress: bool, voxel_size=None):
    """(kept indices, scores of every point or None for samplers, seconds).

    The points are moved to their local frame in float64 first, so that no method, the
    samplers included, ever casts georeferenced coordinates to float32.
    """
    import hgjax

    start = time.perf_counter()
    points = hgjax.local_frame(points)[0]
    if entry.kind is None:
        extra = {"key": key} if entry.needs_key else {}
        if voxel_size is not None:
            extra["voxel_size"] = voxel_size
        idx, scores = np.asarray(entry.select(points, ratio, **extra, **params)), None
    else:
        scores = _score(entry, points, ratio, params, progress)
        idx = np.asarray(hgjax.keep(scores, ratio, method=entry.name, key=key, **params))
    return idx, scores, time.perf_counter() - start


def count_ratio(count: int, n: int) -> float:
    """count / n: hgjax rounds ratio * n to 1e-9 relative before its ceiling, so exactly
    ``count`` of ``n`` points are kept (tested up to 1e10 points)."""
    return count / n


def _prepare(args) -> tuple[list[str], list[str]]:
    """Inputs and their checked outputs, before anything is read or computed."""
    inputs = _expand(args.inputs)
    _check_samples(args.samples, inputs)
    return inputs, _targets(inputs, args.output, args.format)


def cmd_resample(args) -> None:
    from hgjax import METHODS, io

    entry = METHODS[args.method]
    params = _method_params(args, entry)
    if args.voxel_size is not None and args.method != "voxel":
        raise UsageError(f"--voxel-size is for --method voxel; got --method {args.method}")
    inputs, targets = _prepare(args)
    key, progress = _key(args), _progress(args)
    for path, target in zip(inputs, targets):
        data = _load(path, args)
        n = len(data)
        if args.count is not None and args.count > n:
            raise UsageError(f"--count {args.count} is more than the {n} points of {path}")
        ratio = count_ratio(args.count, n) if args.count is not None else args.ratio
        if ratio is None and args.voxel_size is None:
            ratio = DEFAULT_RATIO
        idx, scores, seconds = _compute(entry, data.points, ratio, params, key, progress, args.voxel_size)
        if target.lower().endswith(".npy"):
            io.write_indices(target, idx)
        else:
            kept = data.subset(idx)
            attributes = dict(kept.attributes)
            if scores is not None:
                attributes["score"] = scores[idx]
            io.write_points(target, kept.points, attributes=attributes, header=data.header)
        print(f"{args.method}: kept {idx.size} of {n} points of {path} in {seconds:.2f} s -> {target}",
              file=sys.stderr)


def cmd_score(args) -> None:
    from hgjax import METHODS, io

    entry = METHODS[args.method]
    params = _method_params(args, entry)
    inputs, targets = _prepare(args)
    progress = _progress(args)
    for path, target in zip(inputs, targets):
        data = _load(path, args)
        start = time.perf_counter()
        scores = _score(entry, data.points, args.ratio, params, progress)
        seconds = time.perf_counter() - start
        io.write_points(target, data.points, attributes={**data.attributes, "score": scores}, header=data.header)
        print(f"{args.method}: scored {len(data)} points of {path} in {seconds:.2f} s -> {target}",
              file=sys.stderr)


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
    inputs = _expand(args.inputs)
    if len(inputs) != 1:
        raise UsageError(f"compare takes one file; {args.inputs[0]} holds {len(inputs)}")
    (path,) = inputs
    _check_samples(args.samples, inputs)
    if args.output is not None:
        try:
            os.makedirs(args.output, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot create the output directory {args.output}: {err.strerror}") from None
        if not os.access(args.output, os.W_OK | os.X_OK):
            raise UsageError(f"cannot write to {args.output}: the directory is not writable")
    data = _load(path, args)
    res = hgjax.intrinsic_resolution(data.points)
    rows, kept = [], {}
    key, progress = _key(args), _progress(args)
    for method in methods:
        idx, _, seconds = _compute(hgjax.METHODS[method], data.points, args.ratio, {}, key, progress)
        mean, worst = _coverage(data.points, idx)
        kept[method] = idx
        rows.append([method, idx.size, len(data), f"{seconds:.3f}", f"{mean / res:.3f}", f"{worst / res:.3f}"])
    header = ["method", "kept", "points", "seconds", "mean gap (res)", "max gap (res)"]
    table = "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                      + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows])
    print(f"{path}: ratio {args.ratio}, resolution {res:.4g} (gap = distance from a point to the"
          f" nearest kept point)\n\n{table}")
    if args.output is None:
        return
    with open(os.path.join(args.output, "compare.md"), "w") as fh:
        fh.write(table + "\n")
    with open(os.path.join(args.output, "compare.csv"), "w", newline="") as fh:
        csv.writer(fh).writerows([header] + rows)
    written = "compare.md, compare.csv"
    try:
        from hgjax.plot import show_resampling

        show_resampling(data.points, kept, colors=data.attributes.get("colors"), title=os.path.basename(path),
                        path=os.path.join(args.output, "compare.png"))
        written += ", compare.png"
    except ImportError as err:
        print(f"no picture written: {err}", file=sys.stderr)
    print(f"wrote {written} to {args.output}", file=sys.stderr)


def cmd_demo(args) -> None:
    import hgjax

    cloud = hgjax.eval.box_union_cloud(seed=args.seed, n_points=args.n_points)
    edge = np.asarray(cloud.edge_mask)
    print(f"demo cloud: {len(edge)} points on a union of boxes, {int(edge.sum())} labelled edge points,"
          f" keeping {args.ratio:g}")
    print(f"{'method':<8} {'points':>7} {'kept':>6} {'seconds':>8} {'edge precision':>15}")
    key, progress = _key(args), _progress(args)
    for method in sorted(hgjax.METHODS):
        idx, _, seconds = _compute(hgjax.METHODS[method], cloud.points, args.ratio, {}, key, progress)
        print(f"{method:<8} {len(edge):>7} {idx.size:>6} {seconds:>8.2f} {float(edge[idx].mean()):>15.3f}")
    print(f"(a random subset keeps edge points with precision {edge.mean():.3f} on average)")


COMMANDS = {"resample": cmd_resample, "score": cmd_score, "compare": cmd_compare, "demo": cmd_demo}


def main(argv=None) -> int:
    """Run the ``hgjax`` command line.

    Args:
      argv: the arguments without the program name (default: ``sys.argv[1:]``).

    Returns:
      The exit code: 0 success, 1 failure while computing or writing, 2 invalid arguments
      or input, 130 interrupted.

    Examples:
      >>> main(["demo", "--n-points", "0"])
      2
    """
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # argparse exits 2 on bad arguments, 0 after --help/--version
            return int(exc.code or 0)
        try:
            with _session(args.dtype):
                COMMANDS[args.command](args)
        except (UsageError, ValueError, TypeError, ImportError) as err:  # includes hgjax's validation
            print(f"hgjax {args.command}: error: {err}", file=sys.stderr)
            return 2
        except (OSError, RuntimeError, MemoryError) as err:
            print(f"hgjax {args.command}: failed: {type(err).__name__}: {err}", file=sys.stderr)
            return 1
    except KeyboardInterrupt:
        print("hgjax: interrupted", file=sys.stderr)
        return 130
    return 0
