"""The progress of a command-line run: plain lines to a file, a status line on a terminal, -q and -v."""

import os
import pty
import re
import subprocess
import sys

import numpy as np
import pytest

from hgjax import _progress, io
from hgjax.engine import _runners
from hgjax.cli import main

RUN_NOW = ("import sys; from hgjax import _progress; _progress.DELAY = _progress.STAGE_DELAY = _progress.PERIOD = 0.0;"
           " _progress.TICK = _progress.REDRAW = 0.01;"
           " from hgjax.cli import main; sys.exit(main(sys.argv[1:]))")
"""The command line with its progress shown from the start and at every redraw (a test's run is short)."""
LABELS = ("read", "plan", "neighbours/score", "keep", "write")


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    path = tmp_path_factory.mktemp("progress") / "c.npy"
    u = np.random.default_rng(0).random((60_000, 2))
    io.write_points(path, np.c_[u * 20, np.sin(3 * u[:, 0])])
    return path


def _run(args, stderr):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(os.path.dirname(_progress.__file__)),
                                                         os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-c", RUN_NOW, *map(str, args)], stdin=subprocess.DEVNULL,
                          stdout=subprocess.DEVNULL, stderr=stderr, env=env, timeout=600, check=False)


def test_plain_lines_to_a_file_name_each_stage_with_its_counts(tmp_path, cloud):
    with open(tmp_path / "err.txt", "w") as err:
        proc = _run(["resample", cloud, "-o", tmp_path / "k.ply", "--method", "hkc"], err)
    text = (tmp_path / "err.txt").read_text()
    assert proc.returncode == 0, text
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[-1].startswith("hkc: kept 12000 of 60000 points of ")
    progress = lines[:-1]
    assert progress and all(re.match(rf"hgjax resample: c\.npy: ({'|'.join(LABELS)})[ :]", line)
                            for line in progress), progress
    done = [line for line in progress if line.startswith("hgjax resample: c.npy: neighbours/score 60k points in ")]
    assert len(done) == 1 and re.search(r" in [\d.]+ s \([\d.]+k? points/s\)$", done[0]), progress
    counts = [re.search(r" (\S+)/60k points \((\d+)%\)", line) for line in progress]
    assert all(int(c[2]) <= 100 for c in counts if c), progress


def test_a_terminal_gets_a_labelled_status_line_with_a_bar(tmp_path, cloud):
    master, slave = pty.openpty()
    try:
        proc = subprocess.Popen([sys.executable, "-c", RUN_NOW, "resample", str(cloud), "-o", str(tmp_path / "k.ply"),
                                 "--method", "hkc"], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave)
        os.close(slave)
        out = b""
        while True:
            try:
                chunk = os.read(master, 1 << 16)
            except OSError:  # the run closed its end
                break
            if not chunk:
                break
            out += chunk
        assert proc.wait(timeout=600) == 0, out
    finally:
        os.close(master)
    text = out.decode()
    drawn = [part for part in re.split(r"[\r\n]+", text) if part.startswith("hgjax resample: c.npy: neighbours/score ")]
    assert any(re.search(r"/60k points \(\d+%\)", part) and "[" in part for part in drawn), drawn
    assert "\x1b[K" in text
    lines = [line for line in text.replace("\r\x1b[K", "\n").split("\n") if line.strip("\r")]
    assert lines[-1].startswith("hkc: kept 12000 of 60000 points of ")


@pytest.fixture
def now(monkeypatch):
    """Progress shown from the start of a run and at every redraw."""
    for name in ("DELAY", "STAGE_DELAY", "PERIOD"):
        monkeypatch.setattr(_progress, name, 0.0)
    monkeypatch.setattr(_progress, "TICK", 0.001)


def test_quiet_prints_nothing_and_verbose_the_seconds_of_each_stage(tmp_path, capsys, cloud, now):
    out = tmp_path / "k.ply"
    assert main(["resample", str(cloud), "-o", str(out), "--method", "ea", "-q"]) == 0
    assert capsys.readouterr().err == "" and len(io.read_points(out)) == 12000
    assert main(["score", str(cloud), "-o", str(out), "--method", "ea", "--quiet", "-v"]) == 0
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(":")[0].strip() for line in lines] == [f"read {cloud}", "plan", "tiles", "keep", "write"]
    assert all(re.fullmatch(r"  [^:]+: \d+\.\d{3} s", line) for line in lines), lines


def test_no_progress_keeps_the_summary(tmp_path, capsys, cloud, now):
    assert main(["resample", str(cloud), "-o", str(tmp_path / "k.ply"), "--method", "ea", "--no-progress"]) == 0
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("ea: kept 12000 of 60000 points"), lines


def test_a_folder_numbers_its_files_and_a_survey_counts_its_tiles(tmp_path, capsys, now):
    rng = np.random.default_rng(1)
    for i in range(2):
        io.write_points(tmp_path / f"t{i}.ply", rng.random((3000, 3)) + [i, 0, 0])
    code = main(["resample", str(tmp_path / "t0.ply"), str(tmp_path / "t1.ply"), "-o", str(tmp_path / "out"),
                 "--method", "ea"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert all(re.match(r"(hgjax resample: [12]/2 t[01]\.ply: |ea: kept )", line) for line in err.splitlines()), err
    code = main(["resample", str(tmp_path / "t0.ply"), str(tmp_path / "t1.ply"), "-o", str(tmp_path / "tiles"),
                 "--method", "ea", "--tile", "0.5"])
    err = capsys.readouterr().err
    assert code == 0, err
    shown = [line for line in err.splitlines() if line.startswith("hgjax resample: ") and " keeps " not in line]
    assert all(re.match(rf"hgjax resample: ({'|'.join(LABELS)})[ :(]", line) for line in shown), shown
    assert any(re.search(r"^hgjax resample: neighbours/score 6k points, \d+ tiles in ", line) for line in shown), shown


def test_no_time_left_from_a_first_tile_of_a_few_points():
    """A first tile of 2 points, done after a kernel's compilation, says nothing of the 418k to come."""
    run = _progress.Progress("hgjax resample", show=True, terminal=False)
    counted = run.count("tile scores", 418_000, 2, "tile", "points")
    start = run.stage.start
    run.task_done(counted, 2)
    line = run.text(run.stage, start + 5.8)
    assert "ETA" not in line and "points/s" not in line, line
    assert line.startswith("hgjax resample: neighbours/score 2/418k points (0%), 1/2 tiles, "), line
    rate = _progress.Rate(0.0)
    rate(2, 5.8)
    assert rate.left(2, 418_000, 6.0) is None
    assert rate.left(100_002, 418_000, 6.1) is None  # tiles that end together tell no rate
    assert rate.left(100_002, 418_000, 7.8) == "6.4 s"  # 100k points in the 2 s since the first count


def test_a_survey_ticker_gives_no_time_left_from_a_tiny_first_tile(capsys, monkeypatch):
    monkeypatch.setattr(_runners.Ticker, "PERIOD", 0.0)
    tick = _runners.Ticker("tile scores", {"a": 2, "b": 418_000})
    tick("a")
    assert "ETA" not in capsys.readouterr().err.splitlines()[-1]
    tick("b")
    assert capsys.readouterr().err.splitlines()[-1].endswith(", ETA 0 s")


def test_durations_read_as_a_person_reads_them():
    assert [_progress.duration(s) for s in (0.04, 8.46, 42, 245, 7380)] == ["0.0 s", "8.5 s", "42 s", "4 min 05 s",
                                                                             "2 h 03 min"]


def test_tiles_still_running_on_workers_keep_their_stage_until_they_end():
    """On Dask the engine's tiles stage ends as the tasks are sent; the user reads their count until they end."""
    run = _progress.Progress("hgjax resample", show=True, terminal=False)
    run.begin("plan", 3000)
    run.ended("plan", 0.1)
    counted = run.count("tile scores", 3000, 2, "tile", "points")
    run.ended("tiles", 0.0)
    run.task_done(counted, 1000)
    assert run.stage.label == "neighbours/score" and run.stage.finished == 1
    run.task_done(counted, 2000)
    assert run.stage.label == "keep"


def test_the_kernel_streams_of_one_stage_count_one_after_another():
    run = _progress.Progress("hgjax resample", show=True, terminal=False)
    run.begin("tiles", 1000)
    run.rows(1000).update(1000)
    run.rows(50).update(10)  # a method's second kernel, on a few rows
    assert (run.stage.count(), run.stage.total) == (1010, 1050)
