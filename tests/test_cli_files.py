"""The ``hgjax`` command line on several files, georeferenced scans and the compilation cache."""

import os
import pathlib
import subprocess
import sys
import warnings

import numpy as np
import pytest

import hgjax
from fixtures import box_union
from hgjax import io, survey
from hgjax.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]
UTM = np.array([512345.0, 4012345.0, 87.0])


pytestmark = pytest.mark.usefixtures("cli_cache")


def run_here(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, out, err


def cloud(n, spacing=None):
    points = box_union(n)
    if spacing is not None:
        points = points * (spacing / hgjax.intrinsic_resolution(points))
    return points


def test_directory_of_scans_to_a_directory(capsys, tmp_path):
    src = tmp_path / "scans"
    src.mkdir()
    sizes = {"b": 3000, "a": 4100, "c": 2500}
    for stem, n in sizes.items():
        io.write_points(src / f"{stem}.{'ply' if stem != 'c' else 'xyz'}", cloud(n))
    (src / "notes.md").write_text("not a scan")
    (src / "sub").mkdir()
    code, _, err = run_here(capsys, "resample", src, "-o", tmp_path / "out", "--format", "pcd", "--count", 500,
                            "--dtype", "float64", "--no-progress")  # the suite runs with x64
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "out")) == ["a.pcd", "b.pcd", "c.pcd", survey.MANIFEST]  # -o DIR: a manifest
    assert [line.split(" of ")[1].split()[0] for line in err.splitlines()] == ["4100", "3000", "2500"]  # sorted
    for stem, n in sizes.items():
        kept = io.read_points(tmp_path / "out" / f"{stem}.pcd")
        idx = np.sort(hgjax.resample(cloud(n), 500 / n, method="hkc"))  # written in input order
        np.testing.assert_allclose(kept.points, cloud(n)[idx], rtol=1e-6)
        assert kept.attributes["score"].shape == (500,)


@pytest.mark.full
def test_several_files_share_the_compiled_kernels(capsys, tmp_path):
    import jax

    paths = []
    for n in (3000, 4700, 3500, 5000):  # the last two need the chunk shapes of the first two (_stream.chunk_rows)
        paths.append(tmp_path / f"c{n}.ply")
        io.write_points(paths[-1], cloud(n))
    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, *args, **kwargs: compiles.append(name) if name.endswith("backend_compile_duration") else None)
    for method in ("hkc", "lhf"):
        for path in paths[:2]:
            code, _, err = run_here(capsys, "resample", path, "-o", tmp_path / "first", "--method", method)
            assert code == 0, err
        compiles.clear()
        for path in paths[2:]:
            code, _, err = run_here(capsys, "resample", path, "-o", tmp_path / "second", "--method", method)
            assert code == 0, err
        assert compiles == [], method


def test_output_names_and_clashes(capsys, tmp_path):
    for name in ("s.ply", "s.xyz", "t.ply"):
        io.write_points(tmp_path / name, cloud(1500))
    code, _, err = run_here(capsys, "resample", tmp_path / "s.ply", tmp_path / "s.xyz", "-o", tmp_path / "out")
    assert code == 2 and "several inputs would be written to" in err and "s.ply" in err
    assert not list((tmp_path / "out").iterdir())
    code, _, err = run_here(capsys, "resample", tmp_path / "t.ply", "-o", tmp_path / "k.ply", "--format", "las")
    assert code == 2 and "--format las disagrees with the extension of -o" in err
    code, _, err = run_here(capsys, "resample", tmp_path / "t.ply", "-o", tmp_path / "single")
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "single")) == [survey.MANIFEST, "t.ply"]
    code, _, err = run_here(capsys, "score", tmp_path / "t.ply", tmp_path / "s.xyz", "-o", tmp_path / "scored",
                            "--format", "npy")
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "scored")) == [survey.MANIFEST, "s.npy", "t.npy"]
    code, _, err = run_here(capsys, "resample", tmp_path / "out", "-o", tmp_path / "x")
    assert code == 2 and "no point cloud or mesh files" in err


def test_las_keeps_its_georeference(capsys, tmp_path):
    pytest.importorskip("laspy")
    io.write_points(tmp_path / "scan.las", cloud(3000, spacing=0.05) + UTM)
    code, _, err = run_here(capsys, "resample", tmp_path / "scan.las", "-o", tmp_path / "kept.laz", "--method",
                            "lhf")
    assert code == 0, err
    source, kept = io.read_points(tmp_path / "scan.las"), io.read_points(tmp_path / "kept.laz")
    np.testing.assert_array_equal(kept.header.offsets, source.header.offsets)
    assert set(map(tuple, kept.points)) <= set(map(tuple, source.points))


@pytest.mark.parametrize("method", ["hkc", "lhf", "ea", "fps"])
def test_georeferenced_scan_keeps_the_same_points(capsys, tmp_path, method):
    local = cloud(4000, spacing=0.05)
    kept = {}
    for name, points in (("local", local), ("utm", local + UTM)):
        io.write_points(tmp_path / f"{name}.ply", points, attributes={"index": np.arange(len(points))})
        code, _, err = run_here(capsys, "resample", tmp_path / f"{name}.ply", "-o", tmp_path / f"{name}.npy",
                                "--method", method)
        assert code == 0, err
        kept[name] = io.read_points(tmp_path / f"{name}.npy").attributes["index"]
    overlap = np.intersect1d(kept["local"], kept["utm"]).size / kept["local"].size
    assert overlap >= 0.99, overlap


def cache_files(directory):
    return [name for _, _, names in os.walk(directory) for name in names]


@pytest.mark.full
def test_persistent_compilation_cache(tmp_path):
    mesh = tmp_path / "c.ply"
    io.write_points(mesh, cloud(1500))
    base = {k: v for k, v in os.environ.items() if k not in ("HGJAX_CACHE_DIR", "XDG_CACHE_HOME")}

    def run(env, out):
        proc = subprocess.run([sys.executable, "-m", "hgjax", "resample", mesh, "-o", tmp_path / out, "--method",
                               "ea"], cwd=ROOT, capture_output=True, text=True, timeout=300, env={**base, **env})
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr

    run({"HGJAX_CACHE_DIR": str(tmp_path / "cache")}, "a.ply")
    assert cache_files(tmp_path / "cache")
    run({"HGJAX_CACHE_DIR": "", "XDG_CACHE_HOME": str(tmp_path / "xdg-off")}, "b.ply")
    assert not (tmp_path / "xdg-off").exists()
    run({"XDG_CACHE_HOME": str(tmp_path / "xdg")}, "c.ply")
    assert cache_files(tmp_path / "xdg" / "hgjax" / "jax")


def test_a_warning_about_an_input_is_printed_once(capsys, tmp_path):
    """Each input is read when checked and again when computed; its warning is printed once."""
    src = tmp_path / "scans"
    src.mkdir()
    for name in "ab":
        points = cloud(600)
        points[5] = np.nan
        np.savetxt(src / f"{name}.xyz", points)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        code, _, err = run_here(capsys, "resample", src, "-o", tmp_path / "out", "--method", "uniform")
    assert code == 0, err
    for name in "ab":
        assert err.count(f"{src / name}.xyz: dropped 1 of 600 points with NaN or inf coordinates") == 1, err


def test_one_input_that_cannot_be_read_is_reported_alone(capsys, tmp_path):
    path = tmp_path / "ragged.xyz"
    path.write_text("1 2 3\n4 5 6\n7 8\n")
    code, _, err = run_here(capsys, "resample", path, "-o", tmp_path / "out.ply")
    assert code == 2
    assert err == f"hgjax resample: error: cannot read {path}: line 3 has 2 values where the lines before it have 3\n"


@pytest.mark.parametrize("text, value", [("true", True), ("False", False), ("TRUE", True)])
def test_a_parameter_of_true_or_false_is_a_boolean(capsys, monkeypatch, tmp_path, text, value):
    from hgjax import engine

    calls, composition = [], engine.run

    def spy(points, ratio, *, method, params, **rest):
        calls.append(dict(params))
        return composition(points, ratio, method=method, params=params, **rest)

    monkeypatch.setattr(engine, "run", spy)
    io.write_points(tmp_path / "c.ply", cloud(600))
    code, _, err = run_here(capsys, "resample", tmp_path / "c.ply", "-o", tmp_path / "out.ply", "--method", "ea",
                            "-p", f"dedupe={text}")
    assert code == 0, err
    assert calls and all(params["dedupe"] is value for params in calls)


def test_a_survey_rerun_counts_the_outputs_kept_up_to_date(capsys, tmp_path):
    src = tmp_path / "survey"
    src.mkdir()
    for i in range(2):
        io.write_points(src / f"t{i}.xyz", cloud(400) + [3.0 * i, 0, 0])
    (src / "bad.xyz").write_text("1 2 3\n4 5\n")
    args = ["resample", src, "-o", tmp_path / "out", "--tile", 2, "--keep-going", "--skip-existing", "--no-progress",
            "--method", "uniform"]
    code, _, err = run_here(capsys, *args)
    assert code == 1 and "wrote 2 of 3 outputs to" in err and "1 of 3 inputs failed: " in err, err
    code, _, err = run_here(capsys, *args)
    assert code == 1, err
    assert "wrote 0 of 3 outputs (2 up to date, kept) to" in err, err
    assert "1 of 3 inputs failed (2 up to date, kept): " in err, err
