"""``hgjax resample`` with ``--tile``, ``--workers`` or ``--scheduler``: every input one cloud.

The inputs are one survey resampled in tiles by :func:`hgjax.survey.resample_files`, here or on
a Dask cluster: a local one of ``--workers`` single-threaded processes, closed at the end of the
run with time for its workers to stop (:func:`_dask_client`), or an existing one at
``--scheduler``. Options that a survey cannot honour (``--count``, ``--format``, ``--samples``,
``--voxel-size``, ``--order priority``), and a method that needs the whole cloud at once, are refused
before anything is read.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time

from hgjax.cli._common import (
    DEFAULT_RATIO,
    BatchFailure,
    UsageError,
    _expand,
    _key,
    _progress,
    _refuse_stdout,
    _say,
    _seconds,
    _stage,
    _tell,
)


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
    if _progress(args):
        _say(f"hgjax resample: starting a local Dask cluster of {args.workers} worker processes")
    with contextlib.ExitStack() as stack:
        with _interrupts_held():
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0", host="127.0.0.1"))
        with distributed.Client(cluster) as client:
            yield client

        async def close_workers():
            import asyncio

            workers = list(cluster.workers.values())
            await asyncio.gather(*(worker.close(timeout=WORKER_CLOSE_SECONDS) for worker in workers))

        cluster.sync(close_workers)


@contextlib.contextmanager
def _interrupts_held():
    """SIGINT blocked while the local cluster starts: its worker processes inherit the mask, so a Ctrl-C
    reaches this process alone (which closes the cluster), never a worker mid-start; a Ctrl-C meanwhile
    is delivered here once the cluster has started."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _resample_survey(args, params: dict) -> None:
    """``resample`` with --tile, --workers or --scheduler: every input one cloud (:func:`hgjax.survey.resample_files`).

    Unless ``--quiet`` or ``--no-progress``, a first line at once, then the survey's progress (its files and
    tiles counted into the run's stages, :mod:`hgjax._progress`); ``--verbose`` prints each stage's seconds and
    the total."""
    from hgjax import io, survey

    if args.workers is not None and args.scheduler is not None:
        raise UsageError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    refused = {"--count": args.count, "--format": args.format, "--samples": args.samples,
               "--voxel-size": args.voxel_size, "--order priority": args.order == "priority" or None}
    given = [name for name, value in refused.items() if value is not None]
    if given:
        raise UsageError(f"{', '.join(given)} cannot be used with --tile/--workers/--scheduler (a survey keeps"
                         " --ratio of all its points, in each input's format and order)")
    from hgjax import METHODS

    refused = METHODS[args.method].refused(params)
    if refused is not None:
        options = [name for name, value in (("--tile", args.tile), ("--workers", args.workers),
                                            ("--scheduler", args.scheduler)) if value is not None]
        raise UsageError(f"--method {args.method}{refused[0]} cannot run in tiles: {refused[1]}; leave out"
                         f" {' and '.join(options)} to run it on the whole cloud at once")
    _refuse_stdout(args.output)
    if os.path.splitext(args.output)[1] and not os.path.isdir(args.output):
        raise UsageError(f"-o {args.output}: with --tile/--workers/--scheduler, -o is a directory")
    start = time.perf_counter()
    inputs = _expand(args.inputs)
    ratio = DEFAULT_RATIO if args.ratio is None else args.ratio
    if _progress(args):  # within a second of the start; the progress follows
        _say(f"hgjax resample: {args.method} keeps {ratio:g} of a survey of {len(inputs)} files as one cloud"
             f"{'' if args.tile is None else f' in tiles of {args.tile:g}'} -> {args.output}")
    if os.path.isdir(args.output):
        for temp in io.remove_stale_temporaries(args.output):
            print(f"hgjax: removed {temp}, left by a killed run", file=sys.stderr)
    with contextlib.ExitStack() as stack:
        client = None if args.workers is None and args.scheduler is None else stack.enter_context(_dask_client(args))
        result = survey.resample_files(inputs, args.output, ratio, method=args.method, tile=args.tile, client=client,
                                       key=_key(args), keep_going=args.keep_going, skip_existing=args.skip_existing,
                                       progress=_progress(args),
                                       on_stage=lambda name, seconds: _seconds(args, name, seconds),
                                       on_resume=_say, **params)
    _stage(args, "total", start)
    for message in result.failures.values():
        _say(f"hgjax resample: failed: {message}")
    kept = f" ({len(result.skipped)} up to date, kept)" if result.skipped else ""
    _tell(args, f"{args.method}: wrote {len(result.written)} of {len(inputs)} outputs{kept} to {args.output}"
          f" ({result.manifest})")
    if result.failures:
        raise BatchFailure(f"{len(result.failures)} of {len(inputs)} inputs failed{kept}: {', '.join(result.failures)}")
