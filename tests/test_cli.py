"""The ``hgjax`` command line, driven as a subprocess (``python -m hgjax``)."""

import pathlib
import subprocess
import sys

import numpy as np
import pytest

import hgjax
from hgjax import io
from hgjax.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
MESH = DATA / "meshes" / "fandisk.obj"
SCAN = DATA / "scans" / "scan_table_mug.ply"


def run(*args):
    proc = subprocess.run([sys.executable, "-m", "hgjax", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def run_here(capsys, *args):
    """The CLI in this process (no interpreter start-up): (exit code, stdout, stderr)."""
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, out, err


def test_resample_mesh_to_ply_with_score(tmp_path):
    out = tmp_path / "kept.ply"
    proc = run("resample", MESH, "-o", out, "--samples", 3000, "--ratio", 0.1, "--method", "hkc", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "kept 300 of 3000" in proc.stderr
    kept = io.read_points(out)
    assert len(kept) == 300 and kept.attributes["normals"].shape == (300, 3)
    score = kept.attributes["score"]
    assert np.all(score[:-1] <= score[1:])  # HKC keeps the smallest beta, best first


def test_resample_scan_carries_colour_and_writes_indices(tmp_path, capsys):
    out = tmp_path / "kept.ply"
    proc = run("resample", SCAN, "-o", out, "--samples", 4000, "--method", "fps", "--ratio", 0.05)
    assert proc.returncode == 0, proc.stderr
    src = io.read_points(SCAN, samples=4000)
    kept = io.read_points(out)
    assert len(kept) == 200
    rows = {tuple(p): c for p, c in zip(src.points, src.attributes["colors"].tolist())}
    assert all(rows[tuple(p)] == c for p, c in zip(kept.points, kept.attributes["colors"].tolist()))
    code, _, err = run_here(capsys, "resample", SCAN, "-o", tmp_path / "i.npy", "--samples", 4000, "--method",
                            "uniform", "--ratio", 0.05, "--key", 3)
    assert code == 0, err
    idx = np.load(tmp_path / "i.npy")
    assert idx.shape == (200,) and len(np.unique(idx)) == 200


def test_score(tmp_path, capsys):
    scan = DATA / "scans" / "scan_lamppost.ply"
    expected = hgjax.scores.hkf(io.read_points(scan).points)
    proc = run("score", scan, "-o", tmp_path / "s.ply", "--method", "hkf", "--dtype", "float64")
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(io.read_points(tmp_path / "s.ply").attributes["score"], expected, rtol=1e-12)
    for ext in ("npy", "csv"):
        code, _, err = run_here(capsys, "score", scan, "-o", tmp_path / f"s.{ext}", "--method", "hkf",
                                "--dtype", "float64", "--quiet")
        assert code == 0, err
    np.testing.assert_allclose(np.load(tmp_path / "s.npy"), expected, rtol=1e-12)
    np.testing.assert_allclose(np.loadtxt(tmp_path / "s.csv", delimiter=",", skiprows=1)[:, 3], expected,
                               rtol=1e-12)


def test_compare_writes_table_and_picture(tmp_path):
    proc = run("compare", MESH, "-o", tmp_path, "--samples", 2000, "--methods", "hkc,fps,uniform")
    assert proc.returncode == 0, proc.stderr
    assert "| hkc | 400 | 2000 |" in proc.stdout
    assert (tmp_path / "compare.csv").read_text().count("\n") == 4
    assert (tmp_path / "compare.png").read_bytes()[:4] == b"\x89PNG"


def test_demo_runs_every_method():
    proc = run("demo", "--n-points", 2000, "--quiet")
    assert proc.returncode == 0, proc.stderr
    for method in hgjax.METHODS:
        assert f"\n{method} " in proc.stdout
    assert " 2000    400 " in proc.stdout


def test_version_and_help(capsys):
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.startswith("hgjax ")
    code, out, _ = run_here(capsys, "--help")
    assert code == 0 and "examples:" in out and "Exit codes" in out


def test_errors_in_a_subprocess_exit_2_without_traceback():
    proc = run("resample", "missing.ply", "-o", "x.ply")
    assert proc.returncode == 2 and "missing.ply: no such file" in proc.stderr and proc.stdout == ""


@pytest.mark.parametrize("args, message", [
    (["resample", "missing.ply", "-o", "x.ply"], "missing.ply: no such file"),
    (["resample", MESH, "-o", "x.ply", "--ratio", "1.5"], "ratio must be in (0, 1]"),
    (["resample", MESH, "-o", "x.ply", "--ratio", "abc"], "not a number: 'abc'"),
    (["resample", MESH, "-o", "x.ply", "--method", "nope"], "invalid choice: 'nope'"),
    (["resample", MESH, "-o", "x.obj"], "expected .ply, .xyz, .txt or .npy"),
    (["resample", MESH, "-o", "x.ply", "--samples", "500", "--variant", "nope"], "unknown variant 'nope'"),
    (["resample", MESH, "-o", "x.ply", "--samples", "0"], "must be >= 1"),
    (["compare", MESH, "--methods", "hkc,nope"], "unknown method(s) ['nope']"),
    (["score", DATA / "README.md", "-o", "x.npy"], "README.md"),
    (["score", MESH, "-o", "x.npy", "--method", "fps"], "invalid choice: 'fps'"),
    (["frobnicate"], "invalid choice"),
])
def test_usage_errors_exit_2(capsys, args, message):
    code, out, err = run_here(capsys, *args)
    assert code == 2
    assert message in err and out == ""


def test_write_failure_exits_1(tmp_path, capsys):
    code, _, err = run_here(capsys, "resample", MESH, "-o", tmp_path / "no" / "dir" / "x.ply", "--samples", 500)
    assert code == 1
    assert "failed: FileNotFoundError" in err


def test_show_resampling_panels_equal_axes_and_errors(monkeypatch):
    from hgjax.plot import show_resampling

    pts = np.random.default_rng(0).random((50, 3)) * np.array([1.0, 2.0, 4.0])
    fig = show_resampling(pts, {"a": np.arange(5), "b": np.arange(10)}, scores=pts[:, 0], view=(10, 20))
    assert [ax.get_title() for ax in fig.axes] == ["original (50 points)", "a (5 points)", "b (10 points)"]
    for ax in fig.axes:
        spans = [np.ptp(getattr(ax, f"get_{c}lim")()) for c in "xyz"]
        np.testing.assert_allclose(spans, spans[0])  # equal axes
        assert (ax.elev, ax.azim) == (10, 20)
    with pytest.raises(ValueError, match="outside"):
        show_resampling(pts, np.array([50]))
    with pytest.raises(ValueError, match="scores must have shape"):
        show_resampling(pts, np.arange(3), scores=np.ones(3))
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(ImportError, match=r"hgjax\[plot\]"):
        show_resampling(pts, np.arange(3))


@pytest.mark.parametrize("method", sorted(hgjax.METHODS))
def test_every_method_resamples_to_ply_with_its_score(tmp_path, capsys, method):
    out = tmp_path / "k.ply"
    code, _, err = run_here(capsys, "resample", DATA / "scans" / "scan_lamppost.ply", "-o", out, "--samples", 600,
                            "--method", method, "--ratio", 0.1, "--quiet")
    assert code == 0, err
    kept = io.read_points(out)
    assert len(kept) == 60
    has_score = any(name.startswith("score") for name in kept.attributes)
    assert has_score == (method in hgjax.scores.__all__)
