"""A run's progress on stderr: labelled stages, the points done of the total, the rate and the time left.

The command line installs one :class:`Progress` for its run (:func:`installed`). The library reports
to the one installed (:func:`current`): a pass over tiles or files as each task ends
(:class:`hgjax.engine._runners.Ticker`) and the rows of a kernel stream as they are computed
(:mod:`hgjax._stream`). The command line begins its own stages (read, write) and the first of the
engine's (:meth:`Progress.begin`); each stage's end (the engine's ``on_stage``, :meth:`Progress.ended`)
begins the next one.

Where stderr is not a terminal, plain lines: nothing in a run's first :data:`DELAY` seconds nor for a
stage shorter than :data:`STAGE_DELAY`, then one line every :data:`PERIOD` seconds of a stage
(``hgjax resample: big.ply: neighbours/score 410k/1M points (41%), 52.3k points/s, ETA 11 s``) and
one as it ends (``hgjax resample: big.ply: neighbours/score 1M points in 21 s (47.6k points/s)``). On a terminal
the same text, with a bar, is one status line redrawn in place, and each stage it showed is left
as its line when the stage ends. The time left is given once :data:`MIN_SHARE` of a stage is done
(after the first count: a first tile of a few points, or the compilation of a kernel, says
nothing of the rest).

Nothing here imports NumPy or JAX (the command line's parser imports this module).
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import threading
import time

DELAY = 2.0  # seconds of a run before any progress is shown
STAGE_DELAY = 1.0  # seconds of a stage before it is shown
PERIOD = 5.0  # seconds between two plain lines of one stage
REDRAW = 0.2  # seconds between two draws of a terminal's status line
TICK = 0.5  # seconds between two looks at whether a plain line is due
MIN_SHARE = 0.05  # the share of a stage's total counted after its first count before a time left is given
MIN_SECONDS = 1.0  # and the seconds since its first count
BAR = 30  # the most characters of a terminal's bar
MIN_BAR = 10  # the fewest: none where the terminal has less room
LABELS = {"tiles": "neighbours/score", "tile scores": "neighbours/score", "neighbourhoods": "neighbours",
          "tile stats": "plan", "census": "plan", "check": "read"}
"""The label of an engine stage or a pass, where the name it reports is not the one a user reads."""
NEXT = {"plan": "tiles", "tiles": "keep", "neighbourhoods": "score", "score": "keep"}
"""The engine stage that begins as another ends (:data:`hgjax.engine.STAGES`)."""

SAYING = threading.Lock()
_current = None


def current() -> Progress | None:
    """The progress the command line installed for its run, or None."""
    return _current


@contextlib.contextmanager
def installed(progress: Progress):
    """Install ``progress`` for the run inside the block (:func:`current`), and close it afterwards."""
    global _current
    _current = progress
    progress.open()
    try:
        yield progress
    finally:
        _current = None
        progress.close()


def say(line: str) -> None:
    """``line`` on stderr in one write, one line at a time across threads, below the run's status line."""
    progress = _current
    if progress is not None:
        progress.say(line)
        return
    with SAYING:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()


def si(value: float) -> str:
    """``value`` in at most 3 significant digits with an SI prefix: 950, 3.2k, 12M."""
    for prefix, scale in (("T", 1e12), ("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if value >= scale:
            return f"{value / scale:.3g}{prefix}"
    return f"{value:.3g}"


def duration(seconds: float) -> str:
    """``seconds`` as a person reads them: 0.4 s, 8.5 s, 12 s, 4 min 05 s, 2 h 03 min."""
    if seconds < 10:
        return f"{max(seconds, 0.0):.1f} s"
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds // 60 % 60:02d} min"


class Rate:
    """The rate of a count and the time left, measured from its first count on (the wait before it,
    a kernel's compilation or a first small task, says nothing of the rest).

    Args:
      start: when the count began (the rate of a count updated once is taken from it).
    """

    def __init__(self, start: float):
        self.start, self.first = start, None

    def __call__(self, done: float, now: float) -> float:
        """Units a second: since the first count, or since the start while there is only one."""
        if self.first is None:
            self.first = (now, done)
        t0, d0 = self.first
        if now > t0 and done > d0:
            return (done - d0) / (now - t0)
        return done / max(now - self.start, 1e-9)

    def left(self, done: float, total: float, now: float) -> str | None:
        """The time left at the rate since the first count, or None while less than :data:`MIN_SHARE` of
        ``total`` was counted after it, or less than :data:`MIN_SECONDS` passed (tasks that end together)."""
        if done >= total:
            return "0 s"
        if self.first is None or done - self.first[1] < MIN_SHARE * total or now - self.first[0] < MIN_SECONDS:
            return None
        return duration((total - done) * (now - self.first[0]) / (done - self.first[1]))


class _Stage:
    """One stage of a run: its label, what it counts and since when, and the engine stage that began while its
    tasks still ran (``then``)."""

    def __init__(self, label: str, total: float | None, unit: str, now: float):
        self.label, self.total, self.unit, self.start = label, total, unit, now
        self.detail, self.tasks, self.task, self.pass_, self.then = None, None, None, 0, None
        self.done = self.partial = self.finished = 0
        self.rate, self.said = Rate(now), None

    def count(self) -> float:
        return self.done + self.partial


class _Rows:
    """The rows of one kernel stream, counted into the current task of the stage they began in."""

    def __init__(self, progress: Progress, stage: _Stage):
        self.progress, self.stage = progress, stage

    def update(self, rows: int) -> None:
        self.progress.rows_sent(self.stage, rows)

    def close(self) -> None:
        """The stream sent its last rows (the stage's count stays until its task or stage ends)."""


class Progress:
    """The progress of one run of the command line on stderr (see the module).

    Args:
      prefix: the start of every line (``hgjax resample``).
      show: show the progress (else only :meth:`say`'s lines and ``verbose``'s seconds).
      terminal: stderr is a terminal: a status line redrawn in place, instead of plain lines.
      verbose: print each stage's seconds as it ends (``  plan: 3.021 s``).
    """

    def __init__(self, prefix: str, *, show: bool, terminal: bool, verbose: bool = False):
        self.prefix, self.show, self.terminal, self.verbose = prefix, show, terminal, verbose
        self.lock = threading.RLock()
        self.begun = time.perf_counter()
        self.where, self.points, self.stage, self.drawn = "", None, None, False
        self.stop, self.thread = threading.Event(), None

    def open(self) -> None:
        if self.show:
            self.thread = threading.Thread(target=self._loop, name="hgjax-progress", daemon=True)
            self.thread.start()

    def close(self) -> None:
        self.stop.set()
        if self.thread is not None:
            self.thread.join()
        with self.lock:
            self.stage = None
            self._clear()

    def file(self, where: str | None = None, points: int | None = None) -> None:
        """The input the stages to come work on (``3/10 big.ply``) and its number of points, each kept where
        not given."""
        with self.lock:
            self.where = self.where if where is None else where
            self.points = self.points if points is None else points

    def begin(self, name: str, total: float | None = None, unit: str = "points") -> None:
        """Begin stage ``name`` (its label: :data:`LABELS`), ``total`` units to do or None (unknown)."""
        with self.lock:
            self._end(time.perf_counter())
            self.stage = _Stage(LABELS.get(name, name), total, unit, time.perf_counter())

    def ended(self, name: str, seconds: float) -> None:
        """Stage ``name`` ended after ``seconds`` (an ``on_stage`` hook): its seconds with ``verbose``, and the
        stage after it (:data:`NEXT`) begins."""
        with self.lock:
            stage = self.stage
            running = stage is not None and stage.tasks and stage.finished < stage.tasks
            if not running:
                self._end(time.perf_counter())
                self.stage = None
            if self.verbose:
                self._line(f"  {name}: {seconds:.3f} s")
            if name in NEXT and running:  # its tasks still run (on Dask workers): the next stage begins after them
                stage.then = NEXT[name]
            elif name in NEXT:
                self.begin(NEXT[name], self.points)

    def count(self, what: str, total: float, tasks: int, task: str, unit: str) -> object:
        """A pass of ``tasks`` tasks of ``total`` units in all (:class:`hgjax.engine._runners.Ticker`) begins: it is the
        count of the current stage, or begins the stage it names. Returns the pass, for :meth:`task_done`."""
        with self.lock:
            label = LABELS.get(what, what)
            if self.stage is None:
                self.begin(what, total, unit)
            stage = self.stage
            stage.detail = None if label == stage.label else what
            stage.total, stage.unit, stage.tasks, stage.task = total, unit, tasks, task
            stage.done = stage.partial = stage.finished = 0
            stage.rate, stage.pass_ = Rate(time.perf_counter()), stage.pass_ + 1
            return stage, stage.pass_

    def task_done(self, counted: object, amount: float) -> None:
        """A task of the pass ``counted`` (:meth:`count`) ended, of ``amount`` units; from any thread."""
        stage, pass_ = counted
        with self.lock:
            if stage is self.stage and stage.pass_ == pass_:
                stage.done += amount
                stage.finished += 1
                stage.partial = 0
                stage.rate(stage.count(), time.perf_counter())
                if stage.then is not None and stage.finished == stage.tasks:
                    self.begin(stage.then, self.points)

    def rows(self, total: int) -> _Rows:
        """The counter of a kernel stream of ``total`` rows: the current task's progress within a pass, else
        the stage's own count, the streams of a stage one after another (a method's second kernel on a few
        rows adds them to the total)."""
        with self.lock:
            stage = self.stage
            if stage is None:
                self.begin("score", total)
                stage = self.stage
            if stage.tasks is None:
                stage.done += stage.partial
                stage.total = max(stage.total or 0, stage.done + total)
            stage.partial = 0
            return _Rows(self, stage)

    def rows_sent(self, stage: _Stage, rows: int) -> None:
        with self.lock:
            if stage is self.stage:
                stage.partial += rows
                stage.rate(stage.count(), time.perf_counter())

    def say(self, line: str) -> None:
        """``line`` on stderr, whole, below the status line (which is drawn again)."""
        with self.lock:
            self._line(line)

    def _line(self, line: str) -> None:
        with SAYING:
            if self.drawn:
                sys.stderr.write("\r\x1b[K")
                self.drawn = False
            sys.stderr.write(line + "\n")
            sys.stderr.flush()

    def _clear(self) -> None:
        if self.drawn:
            with SAYING:
                sys.stderr.write("\r\x1b[K")
                sys.stderr.flush()
            self.drawn = False

    def _loop(self) -> None:
        while not self.stop.wait(REDRAW if self.terminal else TICK):
            with self.lock:
                self._show(time.perf_counter())

    def _show(self, now: float) -> None:
        stage = self.stage
        if stage is None or now - self.begun < DELAY or now - stage.start < STAGE_DELAY:
            return
        if self.terminal:
            with SAYING:
                sys.stderr.write("\r" + self.text(stage, now, width=shutil.get_terminal_size().columns - 1) + "\x1b[K")
                sys.stderr.flush()
            self.drawn = True
            stage.said = now
        elif stage.said is None or now - stage.said >= PERIOD:
            self._line(self.text(stage, now))
            stage.said = now

    def _end(self, now: float) -> None:
        """End the current stage: a last line where it was shown."""
        stage = self.stage
        if stage is None or not self.show or stage.said is None:
            return
        seconds = now - stage.start
        if stage.total:
            amount = f" {si(stage.total)} {stage.unit}" + (f", {stage.tasks} {stage.task}s" if stage.tasks else "")
            self._line(f"{self.head(stage)}{amount} in {duration(seconds)} ({si(stage.total / max(seconds, 1e-9))}"
                       f" {stage.unit}/s)")
        else:
            self._line(f"{self.head(stage)} done in {duration(seconds)}")

    def head(self, stage: _Stage) -> str:
        where = f"{self.where}: " if self.where else ""
        detail = f" ({stage.detail})" if stage.detail else ""
        return f"{self.prefix}: {where}{stage.label}{detail}"

    def text(self, stage: _Stage, now: float, width: int | None = None) -> str:
        """The line of ``stage`` at ``now``: what is done of its total, the rate and the time left; within
        ``width`` characters with a bar where given (a terminal's)."""
        head = self.head(stage)
        done = min(stage.count(), stage.total or 0)
        if not done:
            total = f" ({si(stage.total)} {stage.unit})" if stage.total else ""
            line = f"{head}{total}: {duration(now - stage.start)} so far"
            return line if width is None else line[:width]
        share = done / stage.total
        parts = [f"{si(done)}/{si(stage.total)} {stage.unit} ({share:.0%})"]
        if stage.tasks:
            parts.append(f"{stage.finished}/{stage.tasks} {stage.task}s")
        rate, left = stage.rate(done, now), stage.rate.left(done, stage.total, now)
        if left is None:  # too little done since the first count to tell a rate
            parts.append(f"{duration(now - stage.start)} so far")
        else:
            parts += [f"{si(rate)} {stage.unit}/s", f"ETA {left}"]
        line = f"{head} " + ", ".join(parts)
        if width is None:
            return line
        room = min(BAR, width - len(line) - 3)
        if room >= MIN_BAR:
            filled = int(share * room)
            line += f" [{'#' * filled}{'-' * (room - filled)}]"
        return line[:width]
