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

Exit codes: 0 success; 1 failure while computing or writing (with ``--keep-going``: some
inputs failed, the others were written); 2 invalid arguments or input, detected before any
computation (bad option, ratio, count, seed or parameter, unreadable input, an attribute
the output format cannot hold, unwritable output, too many samples for the memory); 130
interrupted (Ctrl-C), 143 terminated (SIGTERM), with no partial file left. Messages go to
stderr, tables to stdout; user errors never print a Python traceback.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import csv
import math
import os
import sys
import time
import warnings
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

EPILOG = """\
examples:
  hgjax demo                                       all methods on a built-in box-union cloud
  hgjax resample scan.ply -o kept.ply --method hkc --ratio 0.2
  hgjax resample scan.laz -o kept.laz --count 100000 --method lhf
  hgjax resample scans/ -o kept/ --format pcd      every point file of scans/, one output each
  hgjax resample part.stl -o kept.npy --samples 50000 --method lhf
  hgjax resample tiles/ -o kept/ --format laz --keep-going --skip-existing   resume a batch
  hgjax resample survey/*.laz -o kept/ --tile 500 --workers 2   one survey in tiles, on 2 Dask workers
  hgjax resample scan.ply -o grid.ply --method voxel --voxel-size 0.05
  hgjax score scan.pcd -o scored.ply --method lhf -p lengths=10,30
  hgjax compare bunny.ply -o out/ --methods hkc,hkf,lhf,fps

Inputs: PLY, PCD, LAS/LAZ, XYZ/TXT, NPY point clouds, and meshes (OBJ, STL, OFF, GLB/GLTF,
PLY with faces) sampled to --samples points; a directory stands for its point and mesh
files, sorted. Outputs: PLY, PCD, LAS/LAZ, XYZ/TXT, NPY with the input's attributes and a
`score` attribute for scoring methods; NPY as the input was: a table with fields x, y, z, ...
(score included) from a table or another format, a plain (N, 3 + C) array from a plain array
(without the score: `hgjax score` refuses it; write another format to keep it). Kept points are
written in input order (--order priority: best first). `hgjax score` writes finite scores
(+inf, an HKC point without a low band, becomes the largest finite score). With several
inputs, a directory or -o DIR, each output is named after its input's stem with the
--format extension. Every input is read and checked against its output format before
anything is computed; -o may be the input. `-` (standard input or output) is refused.

Computation is in float32 after moving the points to a local frame in float64 (UTM
coordinates are safe); --dtype float64 turns on JAX's x64 mode. Compiled kernels are
cached in $HGJAX_CACHE_DIR (empty: no cache), else $XDG_CACHE_HOME/hgjax/jax or
~/.cache/hgjax/jax.

exit codes:
  0    success
  1    failure while computing or writing
  1    also: some inputs failed with --keep-going (the others were written)
  2    invalid arguments or input (found before computing where possible)
  130  interrupted (Ctrl-C); 143 terminated (SIGTERM); no partial file is left
"""

DEFAULT_RATIO = 0.2
DEMO_PICTURE = "hgjax-demo.png"
SEED_LIMIT = 2**32
FALLBACK_MEMORY = 8 * 2**30
"""Memory assumed where neither /proc/meminfo nor ``os.sysconf`` tells."""
MESH_EXTENSIONS = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")
INPUT_EXTENSIONS = (".ply", ".pcd", ".las", ".laz", ".xyz", ".txt", ".npy") + MESH_EXTENSIONS[1:]
CLI_PARAMS = {"ratio": "--ratio or --count", "voxel_size": "--voxel-size", "progress": "--quiet",
              "key": "--key"}
"""Method parameters set by options of their own, not by ``-p``."""


class UsageError(Exception):
    """An invalid argument or input detected by the CLI (exit code 2)."""


class BatchFailure(Exception):
    """Some inputs of a ``--keep-going`` run failed; the others were written (exit code 1)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM received: handled as Ctrl-C is (exit code 143)."""


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
        if not (value > 0 and math.isfinite(value)):
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


def _view(text: str) -> tuple[float, float]:
    try:
        elev, azim = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ELEV,AZIM in degrees, e.g. 25,-60; got {text!r}") from None
    if not (math.isfinite(elev) and math.isfinite(azim)):
        raise argparse.ArgumentTypeError(f"must be finite; got {text!r}")
    return elev, azim


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
    from hgjax import METHODS, Method, __version__, io
    from hgjax._registry import DEFAULT

    methods = sorted(METHODS)
    scoring = [m for m in methods if isinstance(METHODS[m], Method)]
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
    common.add_argument("-v", "--verbose", action="store_true",
                        help="print the seconds of each stage: per file read, the engine's stages (plan, tiles:"
                        " every tile's neighbourhoods and scores, keep; a method on the whole cloud at once:"
                        " neighbourhoods, score, keep; a sampler: sample), write; a survey (--tile, --workers,"
                        " --scheduler): check, copy (a whole-cloud method), the engine's stages, write, total")

    def with_inputs(p, several):
        if several:
            p.add_argument("inputs", nargs="+", metavar="IN", help="point cloud or mesh files, or directories")
            p.add_argument("-o", "--output", required=True, metavar="OUT",
                           help="output file (one input) or directory (created when missing)")
            p.add_argument("--format", choices=formats, default=None,
                           help="output format in a directory (default ply)")
            p.add_argument("--keep-going", action="store_true",
                           help="write every input that can be processed, list the others, exit 1 (default:"
                           " any unreadable input stops the run before anything is computed, exit 2)")
            p.add_argument("--skip-existing", action="store_true",
                           help="resume: keep an output only where hgjax-manifest.json in its directory records"
                           " it as it is, written with the same method, ratio or count, parameters, key (random"
                           " methods), options and hgjax version from the same inputs (path, size, modification"
                           " time); one line per output says it was skipped or why it is recomputed. The manifest"
                           " is written beside the outputs of -o DIR, of a survey, and of any run with"
                           " --skip-existing")
        else:
            p.add_argument("inputs", nargs=1, metavar="IN", help="point cloud or mesh file")
        p.add_argument("--samples", type=_positive(int), default=None,
                       help="points sampled on a mesh (default 20000), or a seeded subset of a cloud")

    def with_picture(p):
        p.add_argument("--view", type=_view, default=(25.0, -60.0), metavar="ELEV,AZIM",
                       help="camera elevation and azimuth of the picture in degrees (default 25,-60)")
        p.add_argument("--zoom", type=_positive(float), default=1.0, help="picture magnification about the"
                       " cloud's centre (default 1: the whole cloud)")

    def with_method(p, names):
        p.add_argument("--method", choices=names, default=DEFAULT,
                       help=f"one of {', '.join(names)} (default {DEFAULT})")
        p.add_argument("--variant", default=None, help="score variant, e.g. invariant or reference")
        p.add_argument("-p", "--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help="method parameter, e.g. -p lengths=10,30 (repeatable; see hgjax.METHODS)")

    p = sub.add_parser("resample", parents=[common], help="keep a fraction of the points",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Keep ceil(ratio N) points, or exactly --count, in input order (--order)."
                       " The output keeps the input's attributes plus the method's `score`.")
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
    p.add_argument("--order", choices=["input", "priority"], default="input",
                   help="order of the kept points: as in the input (default; keeps a scan's GPS-time or"
                   " scan-line order) or from the highest keep priority down")
    survey = p.add_argument_group("survey", "with any of these, the inputs are one cloud resampled in tiles"
                                  " (hgjax.survey.resample_files): -o is a directory with one output per"
                                  " input in its format and hgjax-manifest.json")
    survey.add_argument("--tile", type=_positive(float), default=None, metavar="T",
                        help="tile edge in the points' units (default: one tile)")
    survey.add_argument("--workers", type=_positive(int), default=None, metavar="W",
                        help="run the tiles on a local Dask cluster of W single-threaded processes")
    survey.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="run the tiles on the Dask cluster of this scheduler (its workers must see"
                        " the inputs and -o)")

    p = sub.add_parser("score", parents=[common], help="write per-point scores",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Write every point with the method's per-point `score` attribute.")
    with_inputs(p, several=True)
    with_method(p, scoring)
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help="ratio of the ranking that the scores"
                   " written are (LHF: its two lengths combined at the kept count, Eqs. (15)-(16))")

    p = sub.add_parser("compare", parents=[common], help="run several methods and tabulate them",
                       description="Run several methods on one input; print a markdown table (coverage"
                       " gaps and the share of sharp features kept) and, with -o DIR, write compare.md,"
                       " compare.csv and compare.png (kept points in red over the grey cloud; needs"
                       " matplotlib).")
    with_inputs(p, several=False)
    p.add_argument("-o", "--output", default=None, metavar="DIR", help="output folder")
    p.add_argument("--methods", default=",".join(methods), help="comma-separated methods (default: all)")
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help=f"fraction kept (default {DEFAULT_RATIO})")
    with_picture(p)

    p = sub.add_parser("demo", parents=[common], help="all methods on a built-in edge-labelled cloud",
                       description="Sample a union of boxes with known sharp edges, run every method,"
                       " print the point counts, the time and the precision of kept edge points, and"
                       " draw the kept points.")
    p.add_argument("--n-points", type=_positive(int), default=20000, help="cloud size (default 20000)")
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help=f"fraction kept (default {DEFAULT_RATIO})")
    p.add_argument("-o", "--output", default=DEMO_PICTURE, metavar="PNG",
                   help=f"picture of the kept points (default {DEMO_PICTURE} in the current folder; needs"
                   " matplotlib)")
    with_picture(p)
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
    """Input files, each once (by its real path), in the order given: each path, the supported
    files of a directory (sorted), or the matches of a glob pattern the shell left alone (quoted,
    ``'survey/*.laz'``; sorted, a matched directory standing for its supported files)."""
    import glob

    def supported(directory: str) -> list[str]:
        return sorted(entry.path for entry in os.scandir(directory)
                      if entry.is_file() and os.path.splitext(entry.name)[1].lower() in INPUT_EXTENSIONS)

    files = []
    for path in paths:
        if path == "-":
            raise UsageError("reading standard input (-) is not supported; give a file or directory")
        if os.path.isdir(path):
            found = supported(path)
            if not found:
                raise UsageError(f"{path}: no point cloud or mesh files (expected {', '.join(INPUT_EXTENSIONS)})")
            files += found
        elif os.path.exists(path):
            files.append(path)
        elif glob.has_magic(path):
            found = [f for match in sorted(glob.glob(path)) for f in (supported(match) if os.path.isdir(match)
                                                                      else [match])]
            if not found:
                raise UsageError(f"{path}: the pattern matches no point cloud or mesh file")
            files += found
        else:
            raise UsageError(f"cannot read {path}: no such file")
    unique = {}
    for path in files:
        first = unique.setdefault(os.path.realpath(path), path)
        if first != path:
            print(f"hgjax: {path} is {first} again; it is read once", file=sys.stderr)
    return list(unique.values())


def _refuse_stdout(output: str) -> None:
    if output == "-":
        raise UsageError("writing to standard output (-o -) is not supported; give a file or directory")


def _targets(inputs: list[str], output: str, fmt: str | None) -> list[str]:
    """The output path of each input, checked writable (directories are created)."""
    from hgjax import io

    _refuse_stdout(output)
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
    for directory in sorted({os.path.dirname(io.check_writable(target)) for target in targets}):
        for temp in io.remove_stale_temporaries(directory):
            print(f"hgjax: removed {temp}, left by a killed run", file=sys.stderr)
    return targets


def _cgroup_free(root: str) -> int | None:
    """Bytes the cgroup memory limit under ``root`` still allows (v2 ``memory.max`` less
    ``memory.current``, v1 ``memory.limit_in_bytes`` less ``memory.usage_in_bytes``); None
    where no limit is set."""
    for limit_name, usage_name in (("memory.max", "memory.current"),
                                   (os.path.join("memory", "memory.limit_in_bytes"),
                                    os.path.join("memory", "memory.usage_in_bytes"))):
        try:
            with open(os.path.join(root, limit_name)) as fh:
                limit = int(fh.read().strip())  # "max" (no limit) is a ValueError
            with open(os.path.join(root, usage_name)) as fh:
                usage = int(fh.read().strip())
        except (OSError, ValueError):
            continue
        if limit < 2**60:  # cgroup v1 writes "no limit" as a huge number
            return max(limit - usage, 0)
    return None


def _available_memory(cgroup_root: str = "/sys/fs/cgroup") -> int:
    """Bytes of memory available: MemAvailable of /proc/meminfo (else the physical memory),
    and no more than the cgroup memory limit leaves, where one is set (containers, batch
    schedulers)."""
    available = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    if available is None:
        try:
            available = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            available = FALLBACK_MEMORY
    limited = _cgroup_free(cgroup_root)
    return available if limited is None else min(available, limited)


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


def _check_samples(samples: int | None, inputs: list[str], methods: list[str]) -> None:
    """Refuse ``--samples`` on a mesh beyond what the memory holds for the costliest of
    ``methods`` (each method's ``bytes_per_sample``), before sampling."""
    import hgjax

    meshes = [path for path in inputs if _is_mesh(path)]
    if samples is None or not meshes:
        return
    method = max(methods, key=lambda m: hgjax.METHODS[m].bytes_per_sample)
    cost, available = hgjax.METHODS[method].bytes_per_sample, _available_memory()
    if samples * cost > available:
        raise UsageError(f"--samples {samples} needs about {samples * cost / 1e9:.1f} GB to sample {meshes[0]}"
                         f" and resample it with {method}, more than the {available / 1e9:.1f} GB available;"
                         f" use --samples {available // cost} or fewer")


def _load(path: str, args):
    """Read one input as ``resample``, ``score`` or ``compare`` see it.

    A ``score`` attribute read back from an earlier hgjax output is replaced by the new score
    when the command writes one (a scoring method; one line on stderr says so, once per run);
    a sampler's output carries it on as it is. A plain (N, 3 + C) ``.npy`` input gives a plain
    ``.npy`` output of the kept rows, which has no score column (:func:`hgjax.io.holds_scores`;
    said once per run by ``resample``, refused by ``score``).
    """
    import dataclasses

    from hgjax import METHODS, Method, io

    start = time.perf_counter()
    data = io.read_points(path, samples=args.samples, seed=args.seed)
    _stage(args, f"read {path}", start)
    if args.command not in ("resample", "score") or not isinstance(METHODS[args.method], Method):
        return data
    if "score" in data.attributes:
        data = dataclasses.replace(data, attributes={k: v for k, v in data.attributes.items() if k != "score"})
        if not getattr(args, "said_score_replaced", False):
            args.said_score_replaced = True
            print(f"hgjax {args.command}: the `score` attribute of {path} (and of any other input that has one) is"
                  f" replaced by the new {args.method} score", file=sys.stderr)
    out = f"out.{args.format}" if args.format else args.output
    if args.command == "resample" and not io.holds_scores(out, header=data.header) and not getattr(
            args, "said_no_score", False):
        args.said_no_score = True
        print(f"hgjax resample: {path} is a plain array, so its .npy output is one too (np.load gives the kept"
              f" points) without the score; write another format to keep the score", file=sys.stderr)
    return data


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
    accepted = entry.resample_params
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


def _stage(args, name: str, start: float) -> None:
    """With ``--verbose``, print the seconds since ``start`` spent in stage ``name``."""
    _seconds(args, name, time.perf_counter() - start)


def _seconds(args, name: str, seconds: float) -> None:
    """With ``--verbose``, print the ``seconds`` spent in stage ``name``."""
    if args.verbose:
        print(f"  {name}: {seconds:.3f} s", file=sys.stderr)


def _compute(entry, points, ratio, params, key, progress: bool, args, voxel_size=None):
    """(kept indices in keep-priority order, scores of every point or None for samplers, seconds).

    :func:`hgjax.resample`, reporting each stage's seconds with ``--verbose`` (its
    ``on_stage``). The points are moved to their local frame in float64 first, so that no
    method, the samplers included, ever casts georeferenced coordinates to float32.
    """
    import numpy as np

    import hgjax

    start = time.perf_counter()
    points = hgjax.local_frame(points)[0]
    extra = {} if voxel_size is None else {"voxel_size": voxel_size}
    if progress and "progress" in entry.resample_params:
        extra["progress"] = True
    idx, scores = hgjax.resample(points, ratio, method=entry.name, key=key, return_scores=True,
                                 on_stage=lambda name, seconds: _seconds(args, name, seconds), **params, **extra)
    return np.asarray(idx), scores, time.perf_counter() - start


def count_ratio(count: int, n: int) -> float:
    """count / n: hgjax rounds ratio * n to 1e-9 relative before its ceiling, so exactly
    ``count`` of ``n`` points are kept (tested up to 1e10 points)."""
    return count / n


def _prepare(args) -> list[tuple[str, str, dict | None]]:
    """(input, output, run record or None) triples, outputs checked, before anything is read or computed.

    The outputs of ``-o DIR``, and every output with ``--skip-existing``, are recorded in the
    manifest of their directory (:data:`hgjax.survey.MANIFEST`) as each is written, with their
    run record (:func:`_record`). With ``--skip-existing``, an output is left out where
    :func:`hgjax.survey.reusable` says its manifest records it as this run would write it, the
    rule of a survey too; one line per output says it was skipped or why it is recomputed.

    Raises:
      hgjax.survey.ManifestError: with ``--skip-existing``, a manifest that is not one.
    """
    from hgjax import METHODS, survey

    inputs = _expand(args.inputs)
    _check_samples(args.samples, inputs, [args.method])
    targets = _targets(inputs, args.output, args.format)
    if not (args.skip_existing or os.path.isdir(args.output)):
        return [(path, target, None) for path, target in zip(inputs, targets)]
    params, key, manifests, jobs = _method_params(args, METHODS[args.method]), _key(args), {}, []
    for path, target in zip(inputs, targets):
        record = _record(args, path, params, key)
        if args.skip_existing:
            where = _manifest_of(target)
            if where not in manifests:
                manifests[where] = survey.read_manifest(where)
            reuse, line = survey.reusable(manifests[where], target, record)
            print(line, file=sys.stderr)
            if reuse:
                continue
        jobs.append((path, target, record))
    return jobs


def _manifest_of(target: str) -> str:
    """The manifest that records ``target``: :data:`hgjax.survey.MANIFEST` in its directory."""
    from hgjax import survey

    return os.path.join(os.path.dirname(os.path.abspath(target)), survey.MANIFEST)


def _record(args, path: str, params: dict, key) -> dict:
    """The run record (:func:`hgjax.survey.run_record`) of the output of ``path``: the command, method, ratio
    or count, parameters, key, and every option that changes the output (dtype, samples, the seed of a
    sampled input; ``resample``'s voxel size and order)."""
    from hgjax import survey

    sampled = args.samples is not None or _is_mesh(path)
    options = {"command": args.command, "dtype": args.dtype, "samples": args.samples,
               "seed": args.seed if sampled else None}
    ratio = args.ratio
    if args.command == "resample":
        options.update(count=args.count, voxel_size=args.voxel_size, order=args.order)
        if ratio is None and args.count is None and args.voxel_size is None:
            ratio = DEFAULT_RATIO
    return survey.run_record([path], method=args.method, ratio=ratio, key=key, params=params, **options)


def _check_inputs(args, jobs, check) -> tuple[list[tuple[str, str, dict | None]], dict[str, str], object]:
    """Read every input of ``jobs`` (:func:`_prepare`) and run ``check(path, target, data)`` on it before any
    computation.

    Returns:
      The jobs that passed, the message of each input that failed, and the data of the
      only input when there is one job (so a single file is read once).

    Raises:
      UsageError: an input failed and ``--keep-going`` is not set (all failures listed).
    """
    good, failed, data = [], {}, None
    for path, target, record in jobs:
        try:
            data = _load(path, args)
            check(path, target, data)
        except (UsageError, ValueError, TypeError, OSError) as err:
            failed[path] = str(err) if path in str(err) else f"{path}: {err}"
        else:
            good.append((path, target, record))
    if failed and not args.keep_going:
        raise UsageError(f"{len(failed)} of {len(jobs)} inputs cannot be processed, nothing was written"
                         " (--keep-going writes the others):\n  " + "\n  ".join(failed.values()))
    for message in failed.values():
        print(f"hgjax {args.command}: skipped: {message}", file=sys.stderr)
    return good, failed, data if len(jobs) == 1 and good else None


def _run_batch(args, jobs, check, process) -> None:
    """Check every input, then ``process(path, target, data)`` each good one, and record its output in its
    manifest (where :func:`_prepare` gave it a run record) as soon as it is written.

    With ``--keep-going`` an input that fails (when checked or computed) is listed and
    skipped, the others are written, and the run ends with exit code 1."""
    from hgjax import survey

    good, failed, data = _check_inputs(args, jobs, check)
    for path, target, record in good:
        try:
            process(path, target, data if data is not None else _load(path, args))
            if record is not None:
                survey.write_manifest(_manifest_of(target), [{"output": target, "input": os.path.abspath(path),
                                                              "run": record}])
        except (ValueError, TypeError, OSError, RuntimeError, MemoryError) as err:
            if not args.keep_going:
                raise
            failed[path] = f"{path}: {type(err).__name__}: {err}"
            print(f"hgjax {args.command}: failed: {failed[path]}", file=sys.stderr)
    if failed:
        raise BatchFailure(f"{len(failed)} of {len(jobs)} inputs failed: {', '.join(failed)}")


def _ratio_of(args, path: str, n: int) -> float | None:
    if args.count is not None and args.count > n:
        raise UsageError(f"--count {args.count} is more than the {n} points of {path}")
    if args.count is not None:
        return count_ratio(args.count, n)
    return DEFAULT_RATIO if args.ratio is None and args.voxel_size is None else args.ratio


def _score_placeholder(entry, args, n: int) -> np.ndarray | None:
    """A stand-in for the score column, of the dtype the method writes, to check the output
    format before computing."""
    import numpy as np

    from hgjax import Method

    return np.zeros(n, np.dtype(args.dtype)) if isinstance(entry, Method) else None


def cmd_resample(args) -> None:
    import numpy as np

    from hgjax import METHODS, io

    entry = METHODS[args.method]
    params = _method_params(args, entry)
    if args.voxel_size is not None and "voxel_size" not in entry.accepted:
        takes = sorted(m for m, e in METHODS.items() if "voxel_size" in e.accepted)
        raise UsageError(f"--voxel-size is for --method {' or '.join(takes)}; got --method {args.method}")
    if (args.tile, args.workers, args.scheduler) != (None, None, None):
        _resample_survey(args, params)
        return
    jobs = _prepare(args)
    key, progress = _key(args), _progress(args)

    def check(path, target, data):
        _ratio_of(args, path, len(data))
        io.check_format(target, data.points, attributes=data.attributes, header=data.header,
                        scores=_score_placeholder(entry, args, len(data)))

    def process(path, target, data):
        n = len(data)
        idx, scores, seconds = _compute(entry, data.points, _ratio_of(args, path, n), params, key, progress,
                                        args, args.voxel_size)
        if args.order == "input":
            idx = np.sort(idx)
        kept = data.subset(idx)
        start = time.perf_counter()
        io.write_points(target, kept.points, attributes=kept.attributes,
                        scores=None if scores is None else scores[idx], header=data.header)
        _stage(args, "write", start)
        print(f"{args.method}: kept {idx.size} of {n} points of {path} in {seconds:.2f} s -> {target}",
              file=sys.stderr)

    _run_batch(args, jobs, check, process)


WORKER_CLOSE_SECONDS = 60.0
"""How long a ``--workers`` process may take to close at the end of a run before it is killed (Dask's own
default, 4 s, is shorter than a loaded machine takes to stop a worker that ran JAX: it kills it and warns)."""


@contextlib.contextmanager
def _dask_client(args):
    """The Dask client of ``--workers`` (a local cluster, closed at the end) or ``--scheduler``.

    After a run that ends normally the local cluster's worker processes are asked to close and
    given :data:`WORKER_CLOSE_SECONDS` to do so, so none is killed and Dask prints no warning;
    after an error or an interruption the cluster is closed as Dask closes it, at once."""
    try:
        import distributed
    except ImportError:
        raise ImportError("--workers and --scheduler need dask.distributed: pip install 'hgjax[distributed]'")\
            from None
    if args.scheduler is not None:
        with distributed.Client(args.scheduler) as client:
            yield client
        return
    if args.progress:
        print(f"hgjax resample: starting a local Dask cluster of {args.workers} worker processes", file=sys.stderr,
              flush=True)
    with distributed.LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                                  dashboard_address=":0", host="127.0.0.1") as cluster:
        with distributed.Client(cluster) as client:
            yield client

        async def close_workers():
            import asyncio

            workers = list(cluster.workers.values())
            await asyncio.gather(*(worker.close(timeout=WORKER_CLOSE_SECONDS) for worker in workers))

        cluster.sync(close_workers)


def _resample_survey(args, params: dict) -> None:
    """``resample`` with --tile, --workers or --scheduler: every input one cloud (:func:`hgjax.survey.resample_files`).

    Unless ``--quiet``, a first line at once, then the survey's progress (a tqdm bar per stage where stderr is
    a terminal, plain lines otherwise); ``--verbose`` prints each stage's seconds and the total."""
    from hgjax import io, survey

    if args.workers is not None and args.scheduler is not None:
        raise UsageError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    refused = {"--count": args.count, "--format": args.format, "--samples": args.samples,
               "--voxel-size": args.voxel_size, "--order priority": args.order == "priority" or None}
    given = [name for name, value in refused.items() if value is not None]
    if given:
        raise UsageError(f"{', '.join(given)} cannot be used with --tile/--workers/--scheduler (a survey keeps"
                         " --ratio of all its points, in each input's format and order)")
    _refuse_stdout(args.output)
    if os.path.splitext(args.output)[1] and not os.path.isdir(args.output):
        raise UsageError(f"-o {args.output}: with --tile/--workers/--scheduler, -o is a directory")
    start = time.perf_counter()
    inputs = _expand(args.inputs)
    ratio = DEFAULT_RATIO if args.ratio is None else args.ratio
    if args.progress:  # within a second of the start; progress lines follow (a tqdm bar per stage on a terminal)
        print(f"hgjax resample: {args.method} keeps {ratio:g} of a survey of {len(inputs)} files as one cloud"
              f"{'' if args.tile is None else f' in tiles of {args.tile:g}'} -> {args.output}", file=sys.stderr,
              flush=True)
    if os.path.isdir(args.output):
        for temp in io.remove_stale_temporaries(args.output):
            print(f"hgjax: removed {temp}, left by a killed run", file=sys.stderr)
    with contextlib.ExitStack() as stack:
        client = None if args.workers is None and args.scheduler is None else stack.enter_context(_dask_client(args))
        result = survey.resample_files(inputs, args.output, ratio, method=args.method, tile=args.tile, client=client,
                                       key=_key(args), keep_going=args.keep_going, skip_existing=args.skip_existing,
                                       progress=args.progress,
                                       on_stage=lambda name, seconds: _seconds(args, name, seconds),
                                       on_resume=lambda line: print(line, file=sys.stderr, flush=True), **params)
    _stage(args, "total", start)
    for message in result.failures.values():
        print(f"hgjax resample: failed: {message}", file=sys.stderr)
    print(f"{args.method}: wrote {len(result.written)} of {len(inputs)} outputs to {args.output}"
          f" ({result.manifest})", file=sys.stderr)
    if result.failures:
        raise BatchFailure(f"{len(result.failures)} of {len(inputs)} inputs failed: {', '.join(result.failures)}")


def _finite_scores(scores: np.ndarray) -> np.ndarray:
    """Scores as written by ``hgjax score``: +inf (an HKC point whose low band vanishes) becomes the
    largest finite score and -inf the smallest, so colour ramps (CloudCompare, PDAL) accept the
    column; with no finite score at all, 0."""
    import numpy as np

    finite = scores[np.isfinite(scores)]
    if finite.size == 0:
        return np.zeros_like(scores)
    return np.nan_to_num(scores, nan=0.0, posinf=finite.max(), neginf=finite.min())


def cmd_score(args) -> None:
    """``hgjax score``: every point with the method's ``score`` attribute (replacing one read from the
    input); an output that has no column for it (a plain ``.npy`` array's) is refused before computing."""
    from hgjax import METHODS, io

    entry = METHODS[args.method]
    params = _method_params(args, entry)
    jobs = _prepare(args)
    key, progress = _key(args), _progress(args)

    def check(path, target, data):
        if not io.holds_scores(target, header=data.header):
            raise UsageError(f"{path} is a plain array, so a .npy output of it is one too and has no column for the"
                             f" score; write another format (-o {os.path.splitext(target)[0]}.ply, or --format)")
        io.check_format(target, data.points, attributes=data.attributes, header=data.header,
                        scores=_score_placeholder(entry, args, len(data)))

    def process(path, target, data):
        _, scores, seconds = _compute(entry, data.points, args.ratio, params, key, progress, args)
        scores = _finite_scores(scores)
        start = time.perf_counter()
        io.write_points(target, data.points, attributes=data.attributes, scores=scores, header=data.header)
        _stage(args, "write", start)
        print(f"{args.method}: scored {len(data)} points of {path} in {seconds:.2f} s -> {target}",
              file=sys.stderr)

    _run_batch(args, jobs, check, process)


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
    _check_samples(args.samples, inputs, methods)
    if args.output is not None:
        _refuse_stdout(args.output)
        try:
            os.makedirs(args.output, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot create the output directory {args.output}: {err.strerror}") from None
        if not os.access(args.output, os.W_OK | os.X_OK):
            raise UsageError(f"cannot write to {args.output}: the directory is not writable")
    data = _load(path, args)
    res = hgjax.intrinsic_resolution(data.points)
    unit, unit_name = _gap_unit(data.points, res)
    variation = hgjax.eval.feature_variation(data.points)
    rows, kept = [], {}
    key, progress = _key(args), _progress(args)
    for method in methods:
        idx, _, seconds = _compute(hgjax.METHODS[method], data.points, args.ratio, {}, key, progress, args)
        mean, worst = _coverage(data.points, idx)
        kept[method] = idx
        share = f"{variation[idx].mean() / variation.mean():.2f}" if variation.mean() > 0 else "-"
        rows.append([method, idx.size, len(data), f"{seconds:.3f}", f"{mean / unit:.3f}", f"{worst / unit:.3f}",
                     share])
    header = ["method", "kept", "points", "seconds", f"mean gap ({unit_name})", f"max gap ({unit_name})",
              "feature share"]
    table = "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                      + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows])
    print(f"{path}: ratio {args.ratio}, resolution {res:.4g}. Gap: distance from a point to the nearest kept"
          " point (small: even coverage). Feature share: mean surface variation of the kept points over"
          " that of all points (above 1: sharp edges and corners kept preferentially; EA maximises it by"
          f" definition).\n\n{table}")
    if args.output is None:
        return
    with open(os.path.join(args.output, "compare.md"), "w") as fh:
        fh.write(table + "\n")
    with open(os.path.join(args.output, "compare.csv"), "w", newline="") as fh:
        csv.writer(fh).writerows([header] + rows)
    picture = _picture(data.points, kept, os.path.join(args.output, "compare.png"), args,
                       colors=data.attributes.get("colors"), title=os.path.basename(path))
    print(f"wrote compare.md, compare.csv{', compare.png' * bool(picture)} to {args.output}", file=sys.stderr)


def _gap_unit(points: np.ndarray, res: float) -> tuple[float, str]:
    """The unit of coverage gaps: the intrinsic resolution, else (a cloud whose points mostly
    coincide) the bounding-box diagonal, else 1."""
    import numpy as np

    if res > 0:
        return res, "res"
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    return (diagonal, "diagonal") if diagonal > 0 else (1.0, "units")


def _picture(points, kept: dict, path: str, args, **style) -> bool:
    """Draw the kept points of each method over the grey cloud to ``path``; False, with a note,
    where matplotlib is missing."""
    from hgjax.plot import show_resampling

    try:
        show_resampling(points, kept, view=args.view, zoom=args.zoom, context=True, path=path, **style)
    except ImportError as err:
        print(f"no picture written: {err}", file=sys.stderr)
        return False
    return True


def cmd_demo(args) -> None:
    import numpy as np

    import hgjax

    folder = os.path.dirname(os.path.abspath(args.output))
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"cannot write the picture {args.output}: {folder} is not a writable folder")
    cloud = hgjax.eval.box_union_cloud(seed=args.seed, n_points=args.n_points)
    edge = np.asarray(cloud.edge_mask)
    print(f"demo cloud: {len(edge)} points on a union of boxes, {int(edge.sum())} labelled edge points,"
          f" keeping {args.ratio:g}")
    print(f"{'method':<8} {'points':>7} {'kept':>6} {'seconds':>8} {'edge precision':>15}")
    key, progress = _key(args), _progress(args)
    kept, same = {}, {}
    for method in sorted(hgjax.METHODS):
        idx, _, seconds = _compute(hgjax.METHODS[method], cloud.points, args.ratio, {}, key, progress, args)
        same[method] = next((m for m, other in kept.items() if np.array_equal(np.sort(other), np.sort(idx))), None)
        kept[method] = idx
        note = "" if same[method] is None else f"  same points as {same[method]}"
        print(f"{method:<8} {len(edge):>7} {idx.size:>6} {seconds:>8.2f} {float(edge[idx].mean()):>15.3f}{note}")
    size = next(iter(kept.values())).size
    print(f"edge precision: the share of kept points that are labelled edge points; at most"
          f" {min(int(edge.sum()), size)} / {size} = {min(int(edge.sum()), size) / size:.3f} (every edge point"
          f" kept), {edge.mean():.3f} for a random subset on average.")
    for method, first in same.items():
        alike = getattr(hgjax.METHODS[method], "ranks_as", None)
        if alike is not None and alike[0] == first:
            print(f"{method} keeps the points of {first}: {alike[1]}.")
    if _picture(np.asarray(cloud.points), kept, args.output, args,
                title="hgjax demo: kept points (red) over the cloud"):
        print(f"wrote the picture to {os.path.abspath(args.output)}")
    print("next: hgjax resample YOUR_SCAN.ply -o kept.ply --method hkc --ratio 0.2   (or hgjax compare"
          " YOUR_SCAN.ply -o out/ to pick a method)")


COMMANDS = {"resample": cmd_resample, "score": cmd_score, "compare": cmd_compare, "demo": cmd_demo}


SIGNAL_EXITS = {"SIGINT": (130, "interrupted"), "SIGTERM": (143, "terminated")}
"""Exit code and message of a run stopped by a signal."""


def _exit_at_once(name: str) -> None:
    """End the process for the signal ``name`` without unwinding: remove the partial files
    (:data:`hgjax.io.OPEN_TEMPORARIES`; before hgjax.io is loaded there are none, and it is never
    imported here, as the signal may have come in the middle of that import), print one line, exit.

    Unwinding would free arrays that library threads (SciPy's k-d tree workers, XLA's) may still
    read, and would turn a signal inside an import into that import's ImportError."""
    io = sys.modules.get("hgjax.io")
    for temp in list(getattr(io, "OPEN_TEMPORARIES", ())):
        with contextlib.suppress(OSError):
            os.unlink(temp)
    code, message = SIGNAL_EXITS[name]
    os.write(2, f"hgjax: {message}\n".encode())
    os._exit(code)


@contextlib.contextmanager
def _signals(received: list, exit_now: bool = False):
    """SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated`, once: the name of the
    first is appended to ``received`` and later ones are ignored, so the clean-up of partial
    files runs to its end. With ``exit_now`` (the console script) the handler ends the process
    itself (:func:`_exit_at_once`) whenever the signal comes, start-up included. Signals the
    parent set to be ignored stay ignored.

    Yields ``held``: a context manager for imports; a signal that comes inside is only recorded,
    and raised when the block ends (with ``exit_now``, the process still ends at once), so that
    it never becomes the ImportError of an extension module stopped while it initialises, nor is
    swallowed by an optional import that catches ImportError."""
    import signal
    import threading

    holding = []

    @contextlib.contextmanager
    def held():
        holding.append(True)
        try:
            yield
        finally:
            holding.pop()
        if received:
            raise Terminated() if received[0] == "SIGTERM" else KeyboardInterrupt()

    if threading.current_thread() is not threading.main_thread():
        yield contextlib.nullcontext
        return

    def handler(signum, frame):
        if received:
            return
        received.append(signal.Signals(signum).name)
        if exit_now:
            _exit_at_once(received[0])
        if not holding:
            raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    saved = {}
    for signum, default in ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL)):
        if signal.getsignal(signum) is default:
            saved[signum] = signal.signal(signum, handler)
    try:
        yield held
    finally:
        for signum, previous in saved.items():
            signal.signal(signum, previous)


def _import_engine() -> None:
    """Import what every command needs: JAX (its compilation cache) and the method registry, with
    its kernels and I/O: most of a run's start-up."""
    import jax.experimental.compilation_cache  # noqa: F401

    from hgjax import METHODS, io  # noqa: F401


def _run(argv, received: list) -> int:
    """Parse ``argv`` and run the command; the exit code of its outcome. A failure after a
    signal was received is re-raised: the signal, not the failure it caused (a LAZ writer
    stopped midway), decides the exit code."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad arguments, 0 after --help/--version
        return int(exc.code or 0)
    try:
        with _session(args.dtype):
            COMMANDS[args.command](args)
    except (UsageError, ValueError, TypeError, ImportError) as err:  # includes hgjax's validation
        if received:
            raise
        print(f"hgjax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except BatchFailure as err:
        print(f"hgjax {args.command}: {err}", file=sys.stderr)
        return 1
    except (OSError, RuntimeError, MemoryError) as err:
        if received:
            raise
        print(f"hgjax {args.command}: failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    return 0


def main(argv=None) -> int:
    """Run the ``hgjax`` command line.

    SIGINT (Ctrl-C) and SIGTERM stop the run at once, with one line on stderr: partial output
    files are removed and the exit code is 130 or 143. The handlers are installed before
    anything heavy is imported (``import hgjax.cli`` loads neither NumPy nor JAX), so this holds
    during start-up too. Called as the console script (``argv`` None), the process then ends
    with :func:`os._exit`, so that library threads still running (SciPy's k-d tree workers)
    cannot crash the interpreter's shutdown, and a signal inside an import cannot become an
    ImportError.

    Args:
      argv: the arguments without the program name (default: ``sys.argv[1:]``).

    Returns:
      The exit code: 0 success, 1 failure while computing or writing, 2 invalid arguments
      or input, 130 interrupted, 143 terminated.

    Examples:
      >>> main(["demo", "--n-points", "0"])
      2
    """
    received: list[str] = []
    code = None
    try:
        with _signals(received, exit_now=argv is None) as held:  # before JAX is imported
            if argv is None:
                # The resource tracker that multiprocessing starts (a local Dask cluster) removes the
                # semaphores of a process that ended at once, with a warning not meant for the user:
                # its command line takes this process's -W options.
                sys.warnoptions.append("ignore::UserWarning:multiprocessing.resource_tracker")
            with held():
                _import_engine()
            code = _run(argv, received)
            if argv is None and not received:
                _exit(code)  # the handlers still in place: a signal up to the end is reported as one
    except BaseException as err:
        if not (received or isinstance(err, KeyboardInterrupt)):
            raise
    if received or code is None:  # a signal, or a KeyboardInterrupt raised by another part of the process
        code, message = SIGNAL_EXITS[received[0] if received else "SIGINT"]
        print(f"hgjax: {message}", file=sys.stderr)
    if argv is None:
        _exit(code)
    return code


def _exit(code: int) -> None:
    """End the console script: flush what it printed and exit without the interpreter's shutdown,
    which library threads still running (SciPy's k-d tree workers, XLA's) can crash."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe (hgjax demo | head)
            stream.flush()
    os._exit(code)
