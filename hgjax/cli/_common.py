"""What every ``hgjax`` command shares: its errors, its inputs and outputs, one method on one cloud.

The exceptions that set the exit code (:class:`UsageError` 2, :class:`BatchFailure` 1); the
inputs expanded from files, directories and quoted glob patterns and read as the commands see
them (:func:`_load`), the outputs named and checked writable (:func:`_targets`); ``--samples``
checked against the memory before a mesh is sampled (:func:`_check_samples`, the cgroup limit
included); ``-p``/``--variant`` checked against the method's parameters; and one method run on
one cloud in its float64 local frame with ``--verbose``'s stage seconds (:func:`_compute`).
Nothing here imports NumPy or JAX at module level (:mod:`hgjax.cli` loads it before its signal
handlers are installed).
"""

from __future__ import annotations

import os
import sys
import time


DEFAULT_RATIO = 0.2
FALLBACK_MEMORY = 8 * 2**30
"""Memory assumed where neither /proc/meminfo nor ``os.sysconf`` tells."""
MESH_EXTENSIONS = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")
INPUT_EXTENSIONS = (".ply", ".pcd", ".las", ".laz", ".xyz", ".txt", ".npy") + MESH_EXTENSIONS[1:]
CLI_PARAMS = {"ratio": "--ratio or --count", "voxel_size": "--voxel-size", "progress": "--no-progress",
              "key": "--key", "search": "--search"}
"""Method parameters set by options of their own, not by ``-p``."""


class UsageError(Exception):
    """An invalid argument or input detected by the CLI (exit code 2)."""


class BatchFailure(Exception):
    """Some inputs of a ``--keep-going`` run failed; the others were written (exit code 1)."""


def _expand(paths: list[str]) -> list[str]:
    """Input files in the order given: each path, the supported files of a directory (sorted), or the
    matches of a glob pattern the shell left alone (quoted, ``'survey/*.laz'``; sorted, a matched
    directory standing for its supported files); each file once, a path, symbolic or hard link
    reaching a file given before left out (:func:`hgjax.io.file_identity`)."""
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
    from hgjax import io

    unique = {}
    for path in files:
        first = unique.setdefault(io.file_identity(path), path)
        if first != path:
            print(f"hgjax: {path} is {first} again; it is read once", file=sys.stderr)
    return list(unique.values())


def _refuse_stdout(output: str) -> None:
    if output == "-":
        raise UsageError("writing to standard output (-o -) is not supported; give a file or directory")


def _targets(inputs: list[str], output: str, fmt: str | None) -> list[str]:
    """The output path of each input, checked writable (the directory of -o FILE, or -o DIR, is created
    when missing)."""
    from hgjax import io

    _refuse_stdout(output)
    ext = os.path.splitext(output)[1].lower()
    is_file = len(inputs) == 1 and ext and not os.path.isdir(output) and not output.endswith(("/", os.sep))
    if is_file:
        if fmt is not None and f".{fmt}" != ext:
            raise UsageError(f"--format {fmt} disagrees with the extension of -o {output}")
        if ext in io.WRITE_EXTENSIONS:  # else check_writable names the extension, and nothing is created
            try:
                os.makedirs(os.path.dirname(output) or os.curdir, exist_ok=True)
            except OSError as err:
                raise UsageError(f"cannot create the directory of -o {output}: {err.strerror}") from None
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
    _begin("read", os.path.getsize(path), "bytes")
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
    """``-p``, ``--variant`` and ``--search`` parameters, checked against the registry entry's
    parameters of the stages the CLI runs (build, score, select: not the soft score's ``tau``),
    before any input is read. Without ``--search`` the engine picks the backend's default
    (:func:`hgjax.engine.searched`)."""
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
    if args.search is not None:
        if "search" not in accepted:
            raise UsageError(f"method {entry.name!r} does not take --search: it builds no neighbourhoods")
        params["search"] = args.search
    return params


def _key(args):
    import jax

    return jax.random.key(args.seed if getattr(args, "key", None) is None else args.key)


def _progress(args) -> bool:
    """Whether the run shows its progress (:mod:`hgjax._progress`)."""
    return args.progress and not args.quiet


def _file(where: str | None = None, points: int | None = None) -> None:
    """The input that the stages to come work on, or its number of points, for the progress
    (:meth:`hgjax._progress.Progress.file`)."""
    from hgjax import _progress

    if _progress.current() is not None:
        _progress.current().file(where, points)


def _begin(name: str, total: int | None = None, unit: str = "points") -> None:
    """Stage ``name`` of ``total`` ``unit`` begins, for the progress (:meth:`hgjax._progress.Progress.begin`)."""
    from hgjax import _progress

    if _progress.current() is not None:
        _progress.current().begin(name, total, unit)


def _stage(args, name: str, start: float) -> None:
    """Stage ``name``, begun at ``start``, ended (:func:`_seconds`)."""
    _seconds(args, name, time.perf_counter() - start)


def _seconds(args, name: str, seconds: float) -> None:
    """Stage ``name`` ended after ``seconds``: the run's progress goes on to the next one and, with ``--verbose``,
    prints the seconds (:meth:`hgjax._progress.Progress.ended`)."""
    from hgjax import _progress

    if _progress.current() is not None:
        _progress.current().ended(name, seconds)
    elif args.verbose:
        _say(f"  {name}: {seconds:.3f} s")


def _say(line: str) -> None:
    """``line`` on stderr, written whole between the progress lines (:func:`hgjax._progress.say`)."""
    from hgjax import _progress

    _progress.say(line)


def _tell(args, line: str) -> None:
    """A line that says what a run did (an output written), unless ``--quiet``."""
    if not args.quiet:
        _say(line)


def _compute(entry, points, ratio, params, key, progress: bool, args, voxel_size=None):
    """(kept indices in keep-priority order, scores of every point or None for samplers, seconds).

    :func:`hgjax.tiles.resample` in one tile, which is :func:`hgjax.resample` (the engine's run),
    reporting each stage's seconds with ``--verbose`` (its ``on_stage``); a ``search`` in
    ``params`` (``--search``) is the engine's neighbour search, as the backend's default is
    (:func:`hgjax.engine.searched`). The points are moved to their local frame in float64 first, so that no
    method, the samplers included, ever casts georeferenced coordinates to float32.
    """
    import numpy as np

    import hgjax
    from hgjax import engine

    start = time.perf_counter()
    points = hgjax.local_frame(points)[0]
    extra = {} if voxel_size is None else {"voxel_size": voxel_size}
    if progress and "progress" in entry.resample_params:
        extra["progress"] = True
    _file(points=len(points))
    _begin(engine.first_stage(entry, params), len(points))
    idx, scores = hgjax.tiles.resample(points, ratio, method=entry.name, key=key, return_scores=True,
                                       on_stage=lambda name, seconds: _seconds(args, name, seconds), **params,
                                       **extra)
    return np.asarray(idx), scores, time.perf_counter() - start


def count_ratio(count: int, n: int) -> float:
    """count / n: hgjax rounds ratio * n to 1e-9 relative before its ceiling, so exactly
    ``count`` of ``n`` points are kept (tested up to 1e10 points)."""
    return count / n
