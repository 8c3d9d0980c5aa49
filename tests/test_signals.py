"""Signals at any moment of an ``hgjax`` run, in every mode (one process, tiles, a survey of files,
``--workers``): SIGINT ends it with exit code 130 and SIGTERM with 143, with one line, no partial or
temporary file and no process left behind, start-up's imports included. Subprocesses of
the installed console script; the schedule of signals is seeded, the moments they land are not."""

import concurrent.futures
import contextlib
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import sysconfig
import time

import numpy as np
import psutil
import pytest

import hgjax
from hgjax import cli, io
from hgjax.cli import _signals as cli_signals

pytestmark = [pytest.mark.full, pytest.mark.usefixtures("cli_cache"),
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/status")]

SCRIPT = os.path.join(sysconfig.get_path("scripts"), "hgjax")
"""The console script itself (a version manager's shim in front of it would be a shell that dies
of the signal before Python starts)."""
LAUNCH = "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); os.execv(sys.argv[1], sys.argv[1:])"
"""Runs the script with SIGINT at its default, as from a terminal: a test runner started in the
background passes SIGINT on as ignored, and a process started that way rightly keeps ignoring it."""
MESSAGES = {signal.SIGINT: (130, "hgjax: interrupted"), signal.SIGTERM: (143, "hgjax: terminated")}
MODES = {  # mode: (arguments, interrupts; 100 in all)
    "one process": (["resample", "c.npy", "-o", "{out}/kept.ply", "--method", "hkc"], 32),
    "tiles": (["resample", "c.npy", "-o", "{out}", "--tile", "2", "--method", "hkc"], 30),
    "survey": (["resample", "survey", "-o", "{out}", "--tile", "2", "--method", "voxel"], 30),  # a whole-cloud copy
    "workers": (["resample", "c.npy", "-o", "{out}", "--workers", "2", "--tile", "2", "--method", "hkc"], 8),
}
SAME_RUN = {"workers": ("tiles", 3.0)}
"""Modes not run to the end first: the outputs of another mode (the same tiles, here on 2 Dask
workers), and that mode's seconds times a factor (the workers' start-up)."""
OWN_LINE = re.compile(r"(hgjax [a-z]+|[a-z_]+): ")
"""The start of the lines a run prints (its progress and report; the signal's line is ``hgjax: ...``)."""
ALARM = re.compile(r"traceback|error|warn|exception|killed|leaked", re.IGNORECASE)


def _handles_sigterm(pid: int) -> bool:
    """Whether the process catches SIGTERM: the CLI's handlers are installed (Python installs none
    for SIGTERM itself, and the launcher's SIGINT handler is reset by exec)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            caught = next(int(line.split()[1], 16) for line in fh if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(caught >> (signal.SIGTERM - 1) & 1)


def _run(folder, mode: str, name: str, sig=None, delay: float = 0.0) -> dict:
    """One run of ``mode`` into ``folder/name``; with ``sig``, sent ``delay`` seconds after the CLI's
    handlers exist. Returns its outcome: exit code, stderr lines, seconds from the handlers to the
    end, whether the signal was sent before the run ended (a run that exits 0 having printed nothing
    after the signal, its closing report included, met it inside its exit), the processes it started."""
    out = folder / name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir()
    args = [a.format(out=out) for a in MODES[mode][0]]
    with open(folder / f"{name}.err", "w+") as err:
        proc = subprocess.Popen([sys.executable, "-S", "-c", LAUNCH, SCRIPT, *args], cwd=folder,
                                stdout=subprocess.DEVNULL, stderr=err)
        children = []
        try:
            while proc.poll() is None and not _handles_sigterm(proc.pid):
                time.sleep(0.002)
            start = time.perf_counter()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=delay)  # returns early where the run ends first
            sent = sig is not None and proc.poll() is None
            if sent:
                with contextlib.suppress(psutil.NoSuchProcess):
                    children = psutil.Process(proc.pid).children(recursive=True)
                printed = os.fstat(err.fileno()).st_size
                proc.send_signal(sig)
            code = proc.wait(timeout=300)
            if sent and code == 0 and os.fstat(err.fileno()).st_size == printed:
                sent = False  # its report, the last line it prints, came first: the signal met its exit
            seconds = time.perf_counter() - start
            left = [c for c in children if _alive(c, within=30.0)]
        finally:
            if proc.poll() is None:
                proc.kill()
            for child in children:
                with contextlib.suppress(psutil.NoSuchProcess):
                    child.kill()
        err.seek(0)
        lines = err.read().replace(str(out), "OUT").splitlines()
    return {"code": code, "lines": lines, "seconds": seconds, "sent": sent, "left": left, "out": out}


def _alive(process, within: float) -> bool:
    """Whether ``process`` still runs after ``within`` seconds (a Dask worker whose parent ended exits)."""
    try:
        process.wait(timeout=within)
    except psutil.TimeoutExpired:
        return True
    except psutil.NoSuchProcess:
        pass
    return False


def _outputs(out) -> dict[str, int]:
    """{file name: points} of the outputs in ``out``; -1 for any other file, -2 for one that cannot be read."""
    found = {}
    for root, dirs, files in os.walk(out):
        for name in dirs + files:
            path = os.path.join(root, name)
            relative = os.path.relpath(path, out)
            if name.endswith((".ply", ".npy")) and os.path.isfile(path):
                try:
                    found[relative] = len(io.read_points(path))
                except (OSError, ValueError):
                    found[relative] = -2
            elif name == "hgjax-manifest.json":
                try:
                    with open(path) as fh:
                        json.load(fh)
                except ValueError:
                    found[relative] = -2
            else:
                found[relative] = -1
    return found


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A 2,000-point cloud as one file, and split into a survey of three."""
    folder = tmp_path_factory.mktemp("signals")
    points = np.asarray(hgjax.eval.box_union_cloud(seed=0, n_points=2000).points)
    np.save(folder / "c.npy", points)
    (folder / "survey").mkdir()
    for i, part in enumerate(np.array_split(np.argsort(points[:, 0]), 3)):
        np.save(folder / "survey" / f"s{i}.npy", points[part])
    return folder


def test_100_signals_at_random_moments_in_every_mode(folder):
    """Each mode runs once to the end (its seconds and outputs; :data:`SAME_RUN`), then is stopped at
    moments drawn uniformly over such a run (start-up's imports take most of a small one), SIGINT and
    SIGTERM in turn; besides the signal's line, a stopped run prints only its own progress. A run that ends before its signal is sent is drawn again; one that the signal
    reaches and that exits 0, printing more after it, swallowed it. Outputs a stopped run leaves are complete."""
    if not os.path.exists(SCRIPT):
        pytest.skip(f"no console script at {SCRIPT}")
    full = {}
    for mode in MODES:
        if mode not in SAME_RUN:
            outcome = _run(folder, mode, f"{mode}-full")
            assert outcome["code"] == 0, (mode, outcome["lines"])
            full[mode] = {"seconds": outcome["seconds"], "outputs": _outputs(outcome["out"])}
            assert full[mode]["outputs"] and min(full[mode]["outputs"].values()) > 0, (mode, full[mode]["outputs"])
    for mode, (other, factor) in SAME_RUN.items():
        full[mode] = {"seconds": full[other]["seconds"] * factor, "outputs": full[other]["outputs"]}
    rng = random.Random(47)
    tasks = [(mode, i) for mode, (_, count) in MODES.items() for i in range(count)]
    rng.shuffle(tasks)

    def interrupt(task):
        mode, i = task
        sig = (signal.SIGINT, signal.SIGTERM)[i % 2]
        span = full[mode]["seconds"]
        for attempt in range(5):
            delay = rng.uniform(0.0, span)
            outcome = _run(folder, mode, f"{mode}-{i}", sig, delay)
            if outcome["sent"]:
                break
            span = min(span, outcome["seconds"], 0.9 * full[mode]["seconds"])  # draw within a run's length
        else:
            return [f"{mode} {i}: the run always ended before its signal"]
        code, message = MESSAGES[sig]
        where = f"{mode} {i} {sig.name} after {delay:.2f} s"
        problems = []
        if outcome["code"] != code:
            problems.append(f"{where}: exit code {outcome['code']}, not {code}")
        lines = outcome["lines"]
        if not lines or lines[-1] != message or lines.count(message) != 1:
            problems.append(f"{where}: stderr does not end with the one line {message!r}")
        others = [line for line in lines[:-1] if not OWN_LINE.match(line) or ALARM.search(line)]
        if others:
            problems.append(f"{where}: other lines: {others[:20]}")
        for name, points in _outputs(outcome["out"]).items():
            if full[mode]["outputs"].get(name) != points:
                problems.append(f"{where}: left {name} ({points} points; a full run writes"
                                f" {full[mode]['outputs'].get(name)})")
        if outcome["left"]:
            problems.append(f"{where}: processes left running: {[p.pid for p in outcome['left']]}")
        return problems

    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        problems = [p for found in pool.map(interrupt, tasks) for p in found]
    assert not problems, "\n".join(problems)


def _with_default_handlers(test):
    """Run ``test`` with SIGINT and SIGTERM at Python's defaults (a test runner may ignore them)."""
    saved = {s: signal.signal(s, d) for s, d in ((signal.SIGINT, signal.default_int_handler),
                                                  (signal.SIGTERM, signal.SIG_DFL))}
    try:
        test()
    finally:
        for s, previous in saved.items():
            signal.signal(s, previous)


@pytest.mark.parametrize("sig, raised", [(signal.SIGINT, KeyboardInterrupt), (signal.SIGTERM, cli_signals.Terminated)])
def test_a_signal_during_start_up_imports_waits_for_them(sig, raised):
    """In this process, a signal that comes while the start-up's modules are imported is recorded and
    raised when the imports return, so it never becomes an extension module's ImportError."""
    received, reached = [], []

    def test():
        with pytest.raises(raised), cli_signals._signals(received) as held:
            with held():
                os.kill(os.getpid(), sig)
                time.sleep(0.2)  # the handler runs here, between two bytecodes of the "import"
                reached.append(True)
            reached.append(False)  # not reached: raised when the block ends

    _with_default_handlers(test)
    assert received == [sig.name] and reached == [True]


def test_an_interrupt_that_a_command_swallows_still_exits_130(capsys, monkeypatch):
    """An optional import that catches the ImportError of an interrupted extension module swallows
    the signal; the run still ends as interrupted."""

    def swallowing(args):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
        except KeyboardInterrupt:
            pass

    monkeypatch.setitem(cli.COMMANDS, "demo", swallowing)
    codes = []
    _with_default_handlers(lambda: codes.append(cli.main(["demo"])))
    assert codes == [130] and capsys.readouterr().err == "hgjax: interrupted\n"


def test_the_command_line_installs_its_handlers_before_numpy_and_jax():
    """``hgjax.cli`` (and so ``hgjax``) imports neither NumPy nor JAX: ``main`` installs its handlers
    first, and start-up's imports come after."""
    code = "import sys, hgjax.cli._main; print(sorted({'numpy', 'jax', 'jaxlib', 'scipy'} & set(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr


IMPORT_INTERRUPTED = """
import builtins, os, signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)
signal.signal(signal.SIGTERM, signal.SIG_DFL)
importing, sig = builtins.__import__, getattr(signal, sys.argv[1])

def interrupted(name, *args, **kwargs):
    if name == "argparse" and name not in sys.modules:  # hgjax.cli._main's first standard-library import
        os.kill(os.getpid(), sig)
        time.sleep(0.5)
    return importing(name, *args, **kwargs)

builtins.__import__ = interrupted
sys.argv = ["hgjax", "--help"]
from hgjax.__main__ import console
console()
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_the_console_script_imports_the_command_line_ends_it_cleanly(sig):
    proc = subprocess.run([sys.executable, "-c", IMPORT_INTERRUPTED, sig.name], capture_output=True, text=True,
                          timeout=120)
    code, message = MESSAGES[sig]
    assert (proc.returncode, proc.stderr, proc.stdout) == (code, message + "\n", ""), proc.stderr


NOISY_WORKERS = """
import multiprocessing, os, threading, time
from hgjax.cli import _signals as cli_signals

def noisy():
    for _ in range(300):
        os.write(2, b"distributed.comm.core.CommClosedError: Stream is closed\\n")
        time.sleep(0.005)

worker = multiprocessing.get_context("fork").Process(target=noisy)
worker.start()
threading.Thread(target=noisy, daemon=True).start()
time.sleep(0.2)
cli_signals._exit_at_once("SIGINT")
"""


def test_nothing_is_printed_after_the_interrupted_line_by_workers_or_threads():
    """A local Dask cluster's worker processes and its thread in this process print that their
    connections closed; the signal's line is the last one all the same."""
    proc = subprocess.run([sys.executable, "-c", NOISY_WORKERS], capture_output=True, text=True, timeout=120)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 130 and lines[-1] == "hgjax: interrupted" and "CommClosedError" in proc.stderr, lines[-5:]
    assert lines.count("hgjax: interrupted") == 1
