"""The command line's parser, the run's JAX settings and the dispatch: :func:`main` (:mod:`hgjax.cli`)."""

from __future__ import annotations

import argparse
import ast
import contextlib
import math
import os
import sys
import warnings

from hgjax import _names, _progress
from hgjax.cli._batch import cmd_resample, cmd_score
from hgjax.cli._common import DEFAULT_RATIO, BatchFailure, UsageError
from hgjax.cli._compare import cmd_compare, cmd_demo
from hgjax.cli._signals import SIGNAL_EXITS, _exit, _signals

EPILOG = """\
examples:
  hgjax demo                                       every method on a built-in CAD part, ranked
  hgjax resample scan.ply -o kept.ply --method hkc --ratio 0.2
  hgjax score scan.pcd -o scored.ply --method lhf -p lengths=10,30
  hgjax compare bunny.ply -o out/ --methods hkc,hkf,lhf,fps
  hgjax COMMAND --help                             each command's options and examples

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

MORE = "\nFormats, the compilation cache and exit codes: hgjax --help."
EXAMPLES = {
    "resample": """\
examples:
  hgjax resample scan.ply -o kept.ply --method hkc --ratio 0.2
  hgjax resample scan.laz -o kept.laz --count 100000 --method lhf
  hgjax resample scans/ -o kept/ --format pcd      every point file of scans/, one output each
  hgjax resample part.stl -o kept.npy --samples 50000 --method lhf
  hgjax resample tiles/ -o kept/ --format laz --keep-going --skip-existing   resume a batch
  hgjax resample survey/*.laz -o kept/ --tile 500 --workers 2   one survey in tiles, on 2 Dask workers
  hgjax resample scan.ply -o grid.ply --method voxel --voxel-size 0.05
  hgjax resample scans/ -o kept/ -v 2> run.log   progress lines and each stage's seconds in run.log
  hgjax resample scans/ -o kept/ -q              only warnings and errors
""" + MORE,
    "score": """\
examples:
  hgjax score scan.pcd -o scored.ply --method lhf -p lengths=10,30
  hgjax score scans/ -o scored/ --format laz --method hkc      one scored file per input
  hgjax score part.stl -o scored.ply --samples 50000 --method ea
""" + MORE,
    "compare": """\
examples:
  hgjax compare bunny.ply -o out/ --methods hkc,hkf,lhf,fps
  hgjax compare part.stl --samples 20000 --ratio 0.1     the table only, on 20000 surface samples
""" + MORE,
    "demo": """\
examples:
  hgjax demo
  hgjax demo --n-points 50000 -o demo.png --view 30,-45
  hgjax demo --ratio 0.2         edge recall when a fifth of the points is kept
""" + MORE,
}
"""Each command's ``--help`` examples."""

OUTPUT_FORMATS = ("ply", "xyz", "txt", "npy", "pcd", "las", "laz")
"""The formats :func:`hgjax.io.write_points` writes (:data:`hgjax.io.WRITE_EXTENSIONS` without the dots)."""

DEMO_PICTURE = "hgjax-demo.png"
SEED_LIMIT = 2**32


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
    if value.lower() in ("true", "false"):
        return name, value.lower() == "true"
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


class _Formatter(argparse.HelpFormatter):
    """Help text as written where it has line breaks (the examples), wrapped to the terminal otherwise."""

    def _fill_text(self, text, width, indent):
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


class _Version(argparse.Action):
    """``--version``: the installed version, looked up only when asked for (importlib.metadata is slow to import)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from hgjax import __version__

        print(f"hgjax {__version__}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``hgjax`` command (exposed for documentation tools).

    It imports neither NumPy nor JAX, so ``--help`` answers at once."""
    methods, scoring = list(_names.METHODS), list(_names.SCORING)
    parser = argparse.ArgumentParser(prog="hgjax", description="Point-cloud resampling with hypergraph signal"
                                     " processing (HKC, HKF, LHF) and baselines, in JAX.",
                                     epilog=EPILOG, formatter_class=_Formatter)
    parser.add_argument("--version", action=_Version, help="show the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--seed", type=_seed, default=0, help="seed of mesh sampling, subsets and random"
                        " methods, in [0, 2**32) (default 0)")
    common.add_argument("--dtype", choices=["float32", "float64"], default="float32",
                        help="computation dtype (default float32, after a float64 local frame; float64"
                        " enables JAX x64)")
    common.add_argument("-q", "--quiet", action="store_true",
                        help="print only warnings and errors: no progress, no summary line per output")
    common.add_argument("--no-progress", dest="progress", action="store_false",
                        help="hide the progress; by default each stage that lasts over a second, once the run"
                        " has taken 2 s, is shown with its points done, rate and time left: a status line on a"
                        " terminal, else a plain line every 5 s")
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
            p.add_argument("--format", choices=OUTPUT_FORMATS, default=None,
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
        p.add_argument("--method", choices=names, default=_names.DEFAULT,
                       help=f"one of {', '.join(names)} (default {_names.DEFAULT})")
        p.add_argument("--variant", default=None, help="score variant, e.g. invariant or reference")
        p.add_argument("-p", "--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help="method parameter, e.g. -p lengths=10,30 (repeatable; see hgjax.METHODS)")
        p.add_argument("--search", choices=["host", "jax"], default=None,
                       help="neighbour search: host (SciPy's k-d tree, the CPU default) or jax (the traced search,"
                       " the GPU/TPU default; same neighbours)")

    p = sub.add_parser("resample", parents=[common], help="keep a fraction of the points",
                       epilog=EXAMPLES["resample"], formatter_class=_Formatter,
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
                       epilog=EXAMPLES["score"], formatter_class=_Formatter,
                       description="Write every point with the method's per-point `score` attribute.")
    with_inputs(p, several=True)
    with_method(p, scoring)
    p.add_argument("--ratio", type=_ratio, default=DEFAULT_RATIO, help="ratio of the ranking that the scores"
                   " written are (LHF: its two lengths combined at the kept count, Eqs. (15)-(16))")

    p = sub.add_parser("compare", parents=[common], help="run several methods and tabulate them",
                       epilog=EXAMPLES["compare"], formatter_class=_Formatter,
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
                       epilog=EXAMPLES["demo"], formatter_class=_Formatter,
                       description="Sample a CAD part (an L-bracket) with known sharp edges, have every"
                       " method keep as many points as lie on an edge, print the share of edge points each"
                       " keeps (edge recall), best first, and draw the kept points.")
    p.add_argument("--n-points", type=_positive(int), default=20000, help="cloud size (default 20000)")
    p.add_argument("--ratio", type=_ratio, default=None, help="fraction kept (default: the share of points on"
                   " an edge)")
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


def _warning_printer():
    """A ``warnings.showwarning`` for one run: each message on one line, once (an input read when
    checked and again when computed warns once)."""
    said = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        if str(message) not in said:
            said.add(str(message))
            _progress.say(f"hgjax: warning: {message}")

    return show


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
            warnings.showwarning = _warning_printer()
            if dtype == "float32":
                warnings.filterwarnings("ignore", category=hgjax.PrecisionWarning)
            yield
    finally:
        for name, value in saved.items():
            jax.config.update(name, value)
        compilation_cache.reset_cache()


COMMANDS = {"resample": cmd_resample, "score": cmd_score, "compare": cmd_compare, "demo": cmd_demo}


def _import_engine() -> None:
    """Import what every command needs: JAX (its compilation cache) and the method registry, with
    its kernels and I/O: most of a run's start-up."""
    import jax.experimental.compilation_cache  # noqa: F401

    from hgjax import METHODS, io  # noqa: F401


def _run(argv, received: list, held) -> int:
    """Parse ``argv`` (nothing heavy imported: ``--help`` answers at once), import the engine
    inside ``held`` (a signal during the import waits for it) and run the command; the exit code
    of its outcome. A failure after a signal was received is re-raised: the signal, not the
    failure it caused (a LAZ writer stopped midway), decides the exit code."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad arguments, 0 after --help/--version
        return int(exc.code or 0)
    with held():
        _import_engine()
    progress = _progress.Progress(f"hgjax {args.command}", show=args.progress and not args.quiet,
                                  terminal=sys.stderr.isatty(), verbose=args.verbose)
    try:
        with _session(args.dtype), _progress.installed(progress):
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
            code = _run(argv, received, held)
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
