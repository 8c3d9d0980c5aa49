"""The ``hgjax`` console script as scan users run it: no data loss, input order, batches
that lose no work, and signals at every stage (subprocesses through the installed entry point)."""

import os
import pathlib
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

import hgjax
from hgjax import io

HGJAX = shutil.which("hgjax")
PACKAGE_ROOT = str(pathlib.Path(hgjax.__file__).resolve().parents[1])
N = 2000

pytestmark = pytest.mark.usefixtures("cli_cache")

HOOK = '''
"""Test hook: at one stage of an hgjax run, send a signal to this process or pause."""
import os, signal, sys, threading, time

import numpy as np
import scipy.spatial

stage, action = os.environ["HGJAX_TEST_HOOK"].split(":")


def fire():
    if action == "pause":
        print("hook: paused", file=sys.stderr, flush=True)
        time.sleep(600)
    else:
        os.kill(os.getpid(), getattr(signal, action))


def fire_soon():
    threading.Timer(0.2, fire).start()


class Tree(scipy.spatial.cKDTree):
    def query(self, x, *args, **kwargs):
        """A threaded search long enough for the signal to land inside and for its threads to
        outlive the interpreter's shutdown (every point within the radius of every query)."""
        big = np.repeat(np.asarray(x, float), max(1, 400_000 // len(x)), axis=0)
        fire_soon()
        while True:
            super().query_ball_point(big, 1e30, return_length=True, workers=-1)


if stage == "neighbours":
    scipy.spatial.cKDTree = Tree

import hgjax
import hgjax.io

if stage == "read":
    read_npy = hgjax.io._npy._read_npy

    def _read_npy(path):
        columns = read_npy(path)
        fire()
        return columns

    hgjax.io._npy._read_npy = _read_npy
elif stage == "score":
    collect = hgjax._stream.NarrowStream.collect  # the stream of HKC's per-row kernel in every tile

    def looping_collect(self):
        fire_soon()
        while True:
            collect(self)

    hgjax._stream.NarrowStream.collect = looping_collect
elif stage == "write":
    atomic_write = hgjax.io._atomic_write

    class Signalling:
        """Fires once the file holds more than its header (point data: written by lazrs for LAZ)."""

        def __init__(self, fh):
            self.fh, self.fired = fh, False

        def write(self, data):
            written = self.fh.write(data)
            if not self.fired and self.fh.tell() > 2048:
                self.fired = True
                self.fh.flush()
                fire()
            return written

        def __getattr__(self, name):
            return getattr(self.fh, name)

    hgjax.io._atomic_write = lambda target, write: atomic_write(target, lambda fh: write(Signalling(fh)))
'''


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """One small cloud, as .npy and as a LAS scan with increasing GPS time."""
    pytest.importorskip("laspy")
    folder = tmp_path_factory.mktemp("scan")
    points = hgjax.eval.box_union_cloud(seed=0, n_points=N).points
    np.save(folder / "c.npy", points)
    io.write_points(folder / "scan.las", points, attributes={"gps_time": np.linspace(0.0, 1.0, N)})
    return folder


def env(tmp_path, hook=None):
    """The environment of a subprocess: this package first on the path, the session's compilation
    cache (``cli_cache``), and with ``hook`` ("STAGE:ACTION"), the test hook above."""
    paths = [PACKAGE_ROOT]
    if hook is not None:
        (tmp_path / "hook").mkdir(exist_ok=True)
        (tmp_path / "hook" / "sitecustomize.py").write_text(HOOK)
        paths.insert(0, str(tmp_path / "hook"))
    result = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
    if hook is not None:
        result["HGJAX_TEST_HOOK"] = hook
    return result


def hgjax_cli(tmp_path, *args, hook=None, timeout=300):
    proc = subprocess.run([HGJAX, *map(str, args)], cwd=tmp_path, env=env(tmp_path, hook), capture_output=True,
                          text=True, timeout=timeout)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def test_the_console_script_runs_this_package(tmp_path):
    proc = subprocess.run([HGJAX, "--version"], env=env(tmp_path), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == f"hgjax {hgjax.__version__}"


def test_npy_output_onto_its_input_holds_the_kept_points(tmp_path, scan):
    path = tmp_path / "c.npy"
    shutil.copy(scan / "c.npy", path)
    source = np.load(path)
    proc = hgjax_cli(tmp_path, "resample", path, "-o", path, "--method", "fps", "--ratio", 0.3)
    assert proc.returncode == 0, proc.stderr
    kept = io.read_points(path)
    assert len(kept) == 600
    assert set(map(tuple, kept.points)) <= set(map(tuple, source))  # points, not indices


def test_truncated_las_is_an_error_naming_the_file(tmp_path, scan):
    import laspy

    header = laspy.read(scan / "scan.las").header
    cut = tmp_path / "cut.las"
    cut.write_bytes((scan / "scan.las").read_bytes()[:header.offset_to_point_data + 1000 * header.point_format.size])
    proc = hgjax_cli(tmp_path, "resample", cut, "-o", tmp_path / "out.las", "--method", "fps")
    assert proc.returncode == 2
    assert "cut.las" in proc.stderr and "1000 points" in proc.stderr and f"announces {N}" in proc.stderr
    assert not (tmp_path / "out.las").exists()


def test_dash_is_refused_and_never_made_a_file(tmp_path, scan, capsys, monkeypatch):
    from hgjax import cli

    monkeypatch.chdir(tmp_path)
    for args, message in [(["resample", scan / "c.npy", "-o", "-"], "standard output"),
                          (["resample", "-", "-o", "kept.ply"], "standard input"),
                          (["compare", scan / "c.npy", "-o", "-", "--methods", "fps"], "standard output")]:
        assert cli.main([str(a) for a in args]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
    assert os.listdir(tmp_path) == []


@pytest.mark.full
def test_kept_points_keep_the_scan_order(tmp_path, scan):
    proc = hgjax_cli(tmp_path, "resample", scan / "scan.las", "-o", tmp_path / "in.las", "--method", "hkc")
    assert proc.returncode == 0, proc.stderr
    gps = io.read_points(tmp_path / "in.las").attributes["gps_time"]
    assert len(gps) == 400 and np.all(np.diff(gps) > 0)
    proc = hgjax_cli(tmp_path, "resample", scan / "scan.las", "-o", tmp_path / "best.las", "--method", "hkc",
                     "--order", "priority")
    assert proc.returncode == 0, proc.stderr
    best = io.read_points(tmp_path / "best.las").attributes
    assert np.all(np.diff(best["score"]) >= 0) and not np.all(np.diff(best["gps_time"]) > 0)
    np.testing.assert_array_equal(np.sort(best["gps_time"]), gps)


@pytest.mark.full
@pytest.mark.parametrize("stage, action", [("read", "SIGINT"), ("neighbours", "SIGINT"), ("score", "SIGINT"),
                                           ("write", "SIGINT"), ("neighbours", "SIGTERM"), ("write", "SIGTERM")])
def test_signals_at_every_stage_exit_cleanly(tmp_path, scan, stage, action):
    out = tmp_path / "out"
    out.mkdir()
    proc = hgjax_cli(tmp_path, "resample", scan / "c.npy", "-o", out / "kept.ply", "--method", "hkc",
                     hook=f"{stage}:{action}")
    code, message = {"SIGINT": (130, "hgjax: interrupted"), "SIGTERM": (143, "hgjax: terminated")}[action]
    assert proc.returncode == code, proc.stderr
    assert proc.stderr.splitlines()[-1] == message and proc.stdout == ""
    assert os.listdir(out) == []  # neither the output nor a temporary file


@pytest.mark.full
def test_ctrl_c_during_a_laz_write_exits_130(tmp_path, scan):
    proc = hgjax_cli(tmp_path, "resample", scan / "scan.las", "-o", tmp_path / "kept.laz", "--method", "fps",
                     hook="write:SIGINT")
    assert proc.returncode == 130 and "LazrsError" not in proc.stderr, proc.stderr
    assert os.listdir(tmp_path) == ["hook"]


@pytest.mark.full
def test_kill_9_during_a_write_is_cleaned_up_by_the_next_run(tmp_path, scan):
    out = tmp_path / "out"
    out.mkdir()
    with subprocess.Popen([HGJAX, "resample", scan / "c.npy", "-o", out / "kept.ply", "--method", "fps"],
                          env=env(tmp_path, "write:pause"), stderr=subprocess.PIPE, text=True) as proc:
        try:
            for line in proc.stderr:
                if line.startswith("hook: paused"):
                    break
        finally:
            proc.kill()
    (temp,) = os.listdir(out)
    assert temp.startswith(".kept.ply.") and temp.endswith(".tmp")
    neighbour = out / ".kept.ply.otherhost.1.0123456789ab.tmp"  # another machine's writer: left alone
    neighbour.write_bytes(b"")
    proc = hgjax_cli(tmp_path, "resample", scan / "c.npy", "-o", out / "kept.ply", "--method", "fps")
    assert proc.returncode == 0, proc.stderr
    assert f"removed {out / temp}" in proc.stderr
    assert sorted(os.listdir(out)) == sorted([neighbour.name, "kept.ply"])


def test_attributes_the_output_format_cannot_hold_are_refused_before_computing(tmp_path, scan):
    points = np.load(scan / "c.npy")
    io.write_points(tmp_path / "a.ply", points)
    io.write_points(tmp_path / "b.ply", points, attributes={"intensity": np.linspace(0, 1, N, dtype=np.float32)})
    start = time.perf_counter()
    proc = hgjax_cli(tmp_path, "resample", tmp_path / "a.ply", tmp_path / "b.ply", "-o", tmp_path / "out",
                     "--format", "las", "--method", "lhf")
    assert proc.returncode == 2 and "b.ply" in proc.stderr and "'intensity'" in proc.stderr, proc.stderr
    assert "nothing was written" in proc.stderr and os.listdir(tmp_path / "out") == []
    assert " kept " not in proc.stderr and time.perf_counter() - start < 30


def test_a_bad_file_in_a_batch(tmp_path, scan):
    src = tmp_path / "tiles"
    src.mkdir()
    for name in "acd":
        shutil.copy(scan / "c.npy", src / f"{name}.npy")
    (src / "b.npy").write_bytes(b"\x93NUMPY not really")
    proc = hgjax_cli(tmp_path, "resample", src, "-o", tmp_path / "out", "--method", "fps")
    assert proc.returncode == 2 and "b.npy" in proc.stderr and "nothing was written" in proc.stderr
    assert os.listdir(tmp_path / "out") == []
    proc = hgjax_cli(tmp_path, "resample", src, "-o", tmp_path / "out", "--method", "fps", "--keep-going")
    assert proc.returncode == 1 and "1 of 4 inputs failed" in proc.stderr and "b.npy" in proc.stderr
    assert f"hgjax resample: failed: cannot read {src / 'b.npy'}" in proc.stderr and "skipped:" not in proc.stderr
    assert sorted(os.listdir(tmp_path / "out")) == ["a.ply", "c.ply", "d.ply", "hgjax-manifest.json"]
    proc = hgjax_cli(tmp_path, "resample", src, "-o", tmp_path / "out", "--method", "fps", "--keep-going",
                     "--skip-existing")  # the three written are up to date: still one of the four inputs failed
    assert proc.returncode == 1 and "1 of 4 inputs failed (3 up to date, kept)" in proc.stderr, proc.stderr
    os.remove(tmp_path / "out" / "c.ply")
    before = {name: os.stat(tmp_path / "out" / name).st_mtime_ns for name in ("a.ply", "d.ply")}
    os.remove(src / "b.npy")
    proc = hgjax_cli(tmp_path, "resample", src, "-o", tmp_path / "out", "--method", "fps", "--skip-existing")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("(--skip-existing)") == 2 and proc.stderr.count(" kept ") == 1
    assert sorted(os.listdir(tmp_path / "out")) == ["a.ply", "c.ply", "d.ply", "hgjax-manifest.json"]
    assert before == {name: os.stat(tmp_path / "out" / name).st_mtime_ns for name in ("a.ply", "d.ply")}


@pytest.mark.full
def test_verbose_prints_the_seconds_of_each_stage(tmp_path, scan):
    """The stages of the composition hgjax.resample runs: in tiles (PCA-AC as one), or on the whole cloud."""
    for method, stages in ((["hkc"], ["plan", "tiles", "keep"]), (["pca_ac"], ["plan", "tiles", "keep"]),
                           (["gfr", "--variant", "reference"], ["neighbourhoods", "score", "keep"])):
        proc = hgjax_cli(tmp_path, "resample", scan / "c.npy", "-o", tmp_path / "k.ply", "--method", *method, "-v")
        assert proc.returncode == 0, proc.stderr
        lines = [line.split(":") for line in proc.stderr.splitlines() if line.startswith("  ")]
        assert [name.split()[0] for name, _ in lines] == ["read", *stages, "write"]
        assert all(seconds.strip().endswith(" s") and float(seconds.split()[0]) >= 0 for _, seconds in lines)


@pytest.mark.full
def test_score_writes_finite_values(tmp_path):
    line = np.c_[np.linspace(0.0, 1.0, 500), np.zeros(500), np.zeros(500)]  # HKC: +inf where no low band
    io.write_points(tmp_path / "line.ply", line)
    scores = np.asarray(hgjax.score(hgjax.neighbourhoods(line, "hkc"), "hkc"))
    assert np.isinf(scores).any() and np.isfinite(scores).any()
    proc = hgjax_cli(tmp_path, "score", tmp_path / "line.ply", "-o", tmp_path / "s.ply", "--method", "hkc")
    assert proc.returncode == 0, proc.stderr
    written = io.read_points(tmp_path / "s.ply").attributes["score"]
    assert np.isfinite(written).all()
    finite = np.isfinite(scores)
    np.testing.assert_allclose(written[finite], scores[finite], rtol=1e-6)
    np.testing.assert_allclose(written[~finite], scores[finite].max(), rtol=1e-6)


def test_samples_memory_uses_the_method_cost_and_the_cgroup_limit(tmp_path, monkeypatch):
    from hgjax.cli import _common as cli_common

    mesh = str(pathlib.Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes" / "fandisk.obj")
    monkeypatch.setattr(cli_common, "_available_memory", lambda: 3 * 10**9)  # where _check_samples reads it
    cli_common._check_samples(10**6, [mesh], ["hkc"])
    with pytest.raises(cli_common.UsageError, match="with gfr, more than the 3.0 GB available"):
        cli_common._check_samples(10**6, [mesh], ["hkc", "gfr"])
    monkeypatch.undo()
    unlimited = cli_common._available_memory(str(tmp_path / "none"))
    (tmp_path / "v2").mkdir()
    (tmp_path / "v2" / "memory.max").write_text(f"{2**30}\n")
    (tmp_path / "v2" / "memory.current").write_text(f"{2**28}\n")
    assert cli_common._available_memory(str(tmp_path / "v2")) == min(unlimited, 2**30 - 2**28)
    (tmp_path / "v2" / "memory.max").write_text("max\n")
    assert cli_common._available_memory(str(tmp_path / "v2")) == pytest.approx(unlimited, rel=0.2)
    (tmp_path / "v1" / "memory").mkdir(parents=True)
    (tmp_path / "v1" / "memory" / "memory.limit_in_bytes").write_text(f"{2**29}\n")
    (tmp_path / "v1" / "memory" / "memory.usage_in_bytes").write_text(f"{2**28}\n")
    assert cli_common._available_memory(str(tmp_path / "v1")) == min(unlimited, 2**28)


@pytest.mark.full
def test_compare_on_an_all_equal_cloud(tmp_path):
    io.write_points(tmp_path / "same.xyz", np.ones((100, 3)))
    proc = hgjax_cli(tmp_path, "compare", tmp_path / "same.xyz", "--methods", "fps,hkc")
    assert proc.returncode == 0, proc.stderr
    assert "| mean gap (units) |" in proc.stdout and "| fps | 20 | 100 |" in proc.stdout


def test_compare_picture_view_zoom_and_feature_share(tmp_path, scan):
    import matplotlib.image

    proc = hgjax_cli(tmp_path, "compare", scan / "c.npy", "-o", tmp_path / "out", "--methods", "fps,ea",
                     "--view", "10,-30", "--zoom", 2)
    assert proc.returncode == 0, proc.stderr
    rows = {line.split("|")[1].strip(): line.split("|")[7].strip() for line in proc.stdout.splitlines()
            if line.startswith("| fps") or line.startswith("| ea")}
    assert float(rows["ea"]) > 1.5 > 1.2 > float(rows["fps"])  # EA keeps sharp features; FPS covers evenly
    assert matplotlib.image.imread(tmp_path / "out" / "compare.png").shape[1] > 500
    proc = hgjax_cli(tmp_path, "compare", scan / "c.npy", "--view", "ten")
    assert proc.returncode == 2 and "expected ELEV,AZIM" in proc.stderr


def test_kept_points_are_drawn_over_the_grey_cloud():
    pytest.importorskip("matplotlib")
    from hgjax.plot import show_resampling

    points = np.random.default_rng(0).random((300, 3))
    colours = np.zeros((300, 3), np.uint8)  # a scan's own colours: black
    fig = show_resampling(points, {"a": np.arange(10)}, colors=colours, context=True, zoom=2, view=(10, 20))
    grey, red = fig.axes[1].collections
    assert len(grey.get_offsets()) == 300 and np.allclose(grey.get_facecolor()[0][:3], 0.85)
    assert len(red.get_offsets()) == 10 and red.get_facecolor()[0][0] > 0.8
    low, high = fig.axes[1].get_xlim()
    assert high - low == pytest.approx((points[:, 0].max() - points[:, 0].min()) / 2, rel=0.3)
    assert (fig.axes[1].elev, fig.axes[1].azim) == (10, 20)


def test_help_parameter_example_runs_in_bash(tmp_path, scan):
    proc = hgjax_cli(tmp_path, "resample", "--help")
    example = proc.stdout.split("e.g. -p ")[1].split()[0]
    command = f"{HGJAX} score {scan / 'c.npy'} -o s.ply --method lhf -p {example}"
    proc = subprocess.run(["bash", "-c", command], cwd=tmp_path, env=env(tmp_path), capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert len(io.read_points(tmp_path / "s.ply")) == N


def test_the_all_extra_installs_every_optional_feature_and_hints_name_it(monkeypatch):
    tomllib = pytest.importorskip("tomllib")

    project = tomllib.loads((pathlib.Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    named = {name for name in extras if name not in ("all", "test")}
    assert extras["all"] == [f"hgjax[{','.join(sorted(named, key=list(extras).index))}]"]
    monkeypatch.setitem(sys.modules, "laspy", None)
    with pytest.raises(ImportError, match=r'pip install "\.\[las\]" in the hgjax source folder \("\.\[all\]"'):
        io.write_points("kept.las", np.eye(3))
