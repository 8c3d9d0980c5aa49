"""``hgjax resample`` and ``hgjax score`` file by file: a batch of (input, output) jobs.

Every input is read and checked against its output format before anything is computed
(:func:`_check_inputs`); each is then computed and written in turn, its output recorded in the
manifest of its directory as soon as it is written (:func:`_run_batch`), so ``--skip-existing``
resumes a batch where it stopped (:func:`_prepare`) and ``--keep-going`` writes every input that
can be. ``resample`` with ``--tile``, ``--workers`` or ``--scheduler`` is a survey instead
(:mod:`hgjax.cli._survey`). ``hgjax score`` writes finite scores (:func:`_finite_scores`).
"""

from __future__ import annotations

import os
import sys
import time
from typing import TYPE_CHECKING

from hgjax.cli._common import (
    DEFAULT_RATIO,
    BatchFailure,
    UsageError,
    _begin,
    _check_samples,
    _compute,
    _expand,
    _file,
    _is_mesh,
    _key,
    _load,
    _method_params,
    _progress,
    _say,
    _stage,
    _targets,
    _tell,
    count_ratio,
)
from hgjax.cli._survey import _resample_survey

if TYPE_CHECKING:
    import numpy as np


def _prepare(args) -> tuple[list[tuple[str, str, dict | None]], int]:
    """(input, output, run record or None) triples, outputs checked, before anything is read or computed,
    and the number of inputs (those whose outputs are kept included).

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
        return [(path, target, None) for path, target in zip(inputs, targets)], len(inputs)
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
    return jobs, len(inputs)


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


def _check_inputs(args, jobs, total: int, check) -> tuple[list[tuple[str, str, dict | None]], dict[str, str], object]:
    """Read every input of ``jobs`` (:func:`_prepare`; ``total`` inputs in all) and run ``check(path, target,
    data)`` on it before any computation.

    Returns:
      The jobs that passed, the message of each input that failed, and the data of the
      only input when there is one job (so a single file is read once).

    Raises:
      UsageError: an input failed and ``--keep-going`` is not set (all failures listed).
    """
    good, failed, data = [], {}, None
    for i, (path, target, record) in enumerate(jobs):
        _file(_numbered(i, len(jobs), path))
        try:
            data = _load(path, args)
            check(path, target, data)
        except (UsageError, ValueError, TypeError, OSError) as err:
            failed[path] = str(err) if path in str(err) else f"{path}: {err}"
        else:
            good.append((path, target, record))
    if failed and not args.keep_going and total == 1:
        raise UsageError(next(iter(failed.values())))
    if failed and not args.keep_going:
        raise UsageError(f"{len(failed)} of {total} inputs cannot be processed, nothing was written"
                         " (--keep-going writes the others):\n  " + "\n  ".join(failed.values()))
    for message in failed.values():
        _say(f"hgjax {args.command}: failed: {message}")
    return good, failed, data if len(jobs) == 1 and good else None


def _run_batch(args, jobs, total: int, check, process) -> None:
    """Check every input, then ``process(path, target, data)`` each good one, and record its output in its
    manifest (where :func:`_prepare` gave it a run record) as soon as it is written.

    With ``--keep-going`` an input that fails (when checked or computed) is listed and
    skipped, the others are written, and the run ends with exit code 1."""
    from hgjax import survey

    good, failed, data = _check_inputs(args, jobs, total, check)
    for i, (path, target, record) in enumerate(good):
        _file(_numbered(i, len(good), path))
        try:
            process(path, target, data if data is not None else _load(path, args))
            if record is not None:
                survey.write_manifest(_manifest_of(target), [{"output": target, "input": os.path.abspath(path),
                                                              "run": record}])
        except (ValueError, TypeError, OSError, RuntimeError, MemoryError) as err:
            if not args.keep_going:
                raise
            failed[path] = f"{path}: {type(err).__name__}: {err}"
            _say(f"hgjax {args.command}: failed: {failed[path]}")
    if failed:
        kept = total - len(jobs)
        raise BatchFailure(f"{len(failed)} of {total} inputs failed{f' ({kept} up to date, kept)' if kept else ''}:"
                           f" {', '.join(failed)}")


def _numbered(i: int, count: int, path: str) -> str:
    """How the progress names the ``i``-th of ``count`` inputs: its file name, numbered among several."""
    name = os.path.basename(path)
    return name if count == 1 else f"{i + 1}/{count} {name}"


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
    jobs, total = _prepare(args)
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
        _begin("write", idx.size)
        io.write_points(target, kept.points, attributes=kept.attributes,
                        scores=None if scores is None else scores[idx], header=data.header)
        _stage(args, "write", start)
        _tell(args, f"{args.method}: kept {idx.size} of {n} points of {path} in {seconds:.2f} s -> {target}")

    _run_batch(args, jobs, total, check, process)


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
    jobs, total = _prepare(args)
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
        _begin("write", len(data))
        io.write_points(target, data.points, attributes=data.attributes, scores=scores, header=data.header)
        _stage(args, "write", start)
        _tell(args, f"{args.method}: scored {len(data)} points of {path} in {seconds:.2f} s -> {target}")

    _run_batch(args, jobs, total, check, process)
