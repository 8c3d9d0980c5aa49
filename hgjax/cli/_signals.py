"""How an ``hgjax`` run ends on SIGINT or SIGTERM, and how the console script exits.

:func:`_signals` turns the first SIGINT into KeyboardInterrupt and the first SIGTERM into
:class:`Terminated` (exit codes 130 and 143, :data:`SIGNAL_EXITS`), ignoring later ones so that
the clean-up of partial files runs to its end, and holds a signal that comes inside an import
until the import ends. The console script ends the process at once instead
(:func:`_exit_at_once`, :func:`_exit`): unwinding could free arrays that library threads still
read. The console script (:func:`hgjax.__main__.console`) calls :func:`exit_on_signals` first,
before the parser (:mod:`hgjax.cli._main`) is imported. This module imports nothing heavy: :func:`hgjax.cli.main`
installs the handlers before JAX is imported.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys


class Terminated(KeyboardInterrupt):
    """SIGTERM received: handled as Ctrl-C is (exit code 143)."""


SIGNAL_EXITS = {"SIGINT": (130, "interrupted"), "SIGTERM": (143, "terminated")}
"""Exit code and message of a run stopped by a signal."""


def _exit_at_once(name: str) -> None:
    """End the process for the signal ``name`` without unwinding: remove the partial files
    (:data:`hgjax.io.OPEN_TEMPORARIES`; before hgjax.io is loaded there are none, and it is never
    imported here, as the signal may have come in the middle of that import), end the worker
    processes this process started (a local Dask cluster's), print one line, exit; nothing this
    process's other threads print after that line reaches stderr.

    Unwinding would free arrays that library threads (SciPy's k-d tree workers, XLA's) may still
    read, and would turn a signal inside an import into that import's ImportError. A worker process
    left running, or the thread of a local Dask cluster, would print that its connection closed
    (``CommClosedError``) after the line."""
    io = sys.modules.get("hgjax.io")
    for temp in list(getattr(io, "OPEN_TEMPORARIES", ())):
        with contextlib.suppress(OSError):
            os.unlink(temp)
    multiprocessing = sys.modules.get("multiprocessing")  # never imported here, as hgjax.io is not
    for child in getattr(multiprocessing, "active_children", list)():
        with contextlib.suppress(OSError, ValueError, AttributeError):
            child.kill()
    code, message = SIGNAL_EXITS[name]
    clear = "\r\x1b[K" if os.isatty(2) else ""  # a terminal's progress status line, if one is drawn
    os.write(2, f"{clear}hgjax: {message}\n".encode())
    with contextlib.suppress(OSError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
    os._exit(code)


_DEFAULT_HANDLERS = ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL))
"""Each handled signal with the handler it has unless the parent process set it to be ignored."""


def _at_once(signum, frame) -> None:
    """The handler of :func:`exit_on_signals` until :func:`hgjax.cli.main` installs its own."""
    _exit_at_once(signal.Signals(signum).name)


def exit_on_signals() -> None:
    """From now on, SIGINT and SIGTERM end the process at once (:func:`_exit_at_once`), until
    :func:`hgjax.cli.main` installs its own handlers in their place (:func:`_signals`). The console
    script calls this first, so that a signal while :mod:`hgjax.cli._main` and the standard library's
    modules it needs are imported prints the run's one line, never a traceback from an import.
    Signals the parent set to be ignored stay ignored."""
    for signum, default in _DEFAULT_HANDLERS:
        if signal.getsignal(signum) is default:
            signal.signal(signum, _at_once)


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
    for signum, default in _DEFAULT_HANDLERS:
        if signal.getsignal(signum) in (default, _at_once):
            saved[signum] = signal.signal(signum, handler)
    try:
        yield held
    finally:
        for signum, previous in saved.items():
            signal.signal(signum, previous)


def _exit(code: int) -> None:
    """End the console script: flush what it printed and exit without the interpreter's shutdown,
    which library threads still running (SciPy's k-d tree workers, XLA's) can crash."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe (hgjax demo | head)
            stream.flush()
    os._exit(code)
