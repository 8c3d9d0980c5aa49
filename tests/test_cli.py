"""The ``hgjax`` command line, in this process (``hgjax.cli.main``) and as a subprocess."""

import argparse
import dataclasses
import os
import pathlib
import re
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

import hgjax
from hgjax import _validate, cli, engine, io
from hgjax.cli import _common as cli_common
from hgjax.cli import _main as cli_main
from hgjax.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
MESH = DATA / "meshes" / "fandisk.obj"
SCAN = DATA / "scans" / "scan_table_mug.ply"
LAMPPOST = DATA / "scans" / "scan_lamppost.ply"


pytestmark = pytest.mark.usefixtures("cli_cache")


def run(*args, env=None):
    proc = subprocess.run([sys.executable, "-m", "hgjax", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, env=env)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def run_here(capsys, *args):
    """The CLI in this process (no interpreter start-up): (exit code, stdout, stderr)."""
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, out, err


@pytest.fixture
def runs(monkeypatch):
    """Every run of the resampling engine (hgjax.engine.run) made by the CLI: (method, ratio, params)."""
    calls, composition = [], engine.run

    def spy(points, ratio, *, method, params, **rest):
        calls.append((method, ratio, dict(params)))
        return composition(points, ratio, method=method, params=params, **rest)

    monkeypatch.setattr(engine, "run", spy)
    return calls


def test_resample_mesh_to_ply_with_score(tmp_path):
    out = tmp_path / "kept.ply"
    proc = run("resample", MESH, "-o", out, "--samples", 3000, "--ratio", 0.1, "--method", "hkc", "--no-progress",
               "--order", "priority")
    assert proc.returncode == 0, proc.stderr
    assert "kept 300 of 3000" in proc.stderr
    kept = io.read_points(out)
    assert len(kept) == 300 and kept.attributes["normals"].shape == (300, 3)
    score = kept.attributes["score"]
    assert np.all(score[:-1] <= score[1:])  # HKC keeps the smallest beta, best first


def test_resample_scan_carries_colour(tmp_path, capsys):
    out = tmp_path / "kept.pcd"
    code, _, err = run_here(capsys, "resample", SCAN, "-o", out, "--samples", 4000, "--method", "fps",
                            "--ratio", 0.05)
    assert code == 0, err
    src = io.read_points(SCAN, samples=4000)
    kept = io.read_points(out)
    assert len(kept) == 200
    rows = {tuple(p): c for p, c in zip(src.points.astype(np.float32), src.attributes["colors"].tolist())}
    assert all(rows[tuple(p)] == c for p, c in zip(kept.points.astype(np.float32),
                                                   kept.attributes["colors"].tolist()))
    code, _, err = run_here(capsys, "resample", SCAN, "-o", tmp_path / "k.npy", "--samples", 4000, "--method",
                            "uniform", "--ratio", 0.05, "--key", 3)
    assert code == 0, err
    kept = io.read_points(tmp_path / "k.npy")
    assert len(kept) == 200 and len(np.unique(kept.points, axis=0)) == 200


@pytest.mark.full
def test_score_computed_once_and_written_for_the_kept_points(tmp_path, capsys, runs):
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "k.ply", "--method", "gfr",
                            "-p", "mode=top", "--ratio", 0.1, "--dtype", "float64",  # the suite runs with x64
                            "--no-progress")
    assert code == 0, err
    assert runs == [("gfr", 0.1, {"mode": "top"})]
    points = io.read_points(LAMPPOST).points
    scores = np.asarray(hgjax.score(hgjax.neighbourhoods(points, "gfr"), "gfr"))
    idx = np.sort(hgjax.keep(scores, 0.1, method="gfr", mode="top"))  # written in input order
    kept = io.read_points(tmp_path / "k.ply")
    np.testing.assert_array_equal(kept.points, points[idx])
    np.testing.assert_allclose(kept.attributes["score"], scores[idx], rtol=1e-6)


@pytest.mark.parametrize("command", ["resample", "score"])
def test_lhf_writes_its_two_lengths_combined_at_the_ratio(capsys, tmp_path, runs, command):
    """LHF's score is ratio-free; the value it is ranked by (and written) combines its two
    lengths at the kept count of --ratio (Eqs. (15)-(16))."""
    code, _, err = run_here(capsys, command, LAMPPOST, "-o", tmp_path / "k.ply", "--method", "lhf",
                            "--ratio", 0.3, "--dtype", "float64", "--no-progress")
    assert code == 0, err
    assert runs == [("lhf", 0.3, {})]
    points = io.read_points(LAMPPOST).points
    gamma = np.asarray(hgjax.score(hgjax.neighbourhoods(points, "lhf"), "lhf"))
    combined = hgjax.scores.lhf.combine(gamma, _validate.n_keep(len(points), 0.3))
    idx = np.sort(hgjax.keep(gamma, 0.3, method="lhf")) if command == "resample" else np.arange(len(points))
    written = io.read_points(tmp_path / "k.ply")
    np.testing.assert_array_equal(written.points, points[idx])
    np.testing.assert_allclose(written.attributes["score"], combined[idx], rtol=1e-6)
    assert np.abs(combined - hgjax.scores.lhf.combine(gamma, _validate.n_keep(len(points), 0.05))).max() > 1e-3


def test_the_kernel_rows_are_counted_unless_the_progress_is_off(capsys, tmp_path, monkeypatch, runs):
    args = ["resample", LAMPPOST, "-o", tmp_path / "k.ply", "--method", "ea"]
    assert run_here(capsys, *args)[0] == 0
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert run_here(capsys, *args)[0] == 0
    assert run_here(capsys, *args, "--quiet")[0] == 0
    assert run_here(capsys, *args, "--no-progress")[0] == 0
    assert [params.get("progress") for _, _, params in runs] == [True, True, None, None]


def test_parameters_come_from_the_registry(capsys, tmp_path, monkeypatch):
    out = tmp_path / "k.ply"
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", out, "--method", "lhf", "-p", "lengths=(6,12)")
    assert code == 0, err
    entry = hgjax.METHODS["lhf"]

    def without_lengths(points_or_nb, *, variant="invariant"):
        raise AssertionError("never called: the parameters are refused first")

    narrowed = dataclasses.replace(entry, build=without_lengths, score=without_lengths, soft_score=without_lengths)
    assert "lengths" not in narrowed.accepted
    monkeypatch.setitem(hgjax.METHODS, "lhf", narrowed)
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", out, "--method", "lhf", "-p", "lengths=(6,12)")
    assert code == 2 and "method 'lhf' does not take lengths" in err


@pytest.mark.parametrize("args, message", [
    (["--method", "hkc", "-p", "foo=1"], "method 'hkc' does not take foo (from -p/--variant); it takes:"),
    (["--method", "hkc", "-p", "tau=0.1"], "does not take tau"),
    (["--method", "fps", "--variant", "reference"], "method 'fps' does not take variant"),
    (["--method", "uniform", "-p", "start=1"], "it takes: no parameters"),
    (["--method", "lhf", "-p", "ratio=0.5"], "-p ratio: set it with --ratio or --count"),
    (["--method", "voxel", "-p", "voxel_size=0.5"], "-p voxel_size: set it with --voxel-size"),
    (["-p", "kernel_size=3", "-p", "kernel_size=5"], "-p kernel_size is given twice"),
    (["--variant", "invariant", "-p", "variant=reference"], "give the variant once"),
    (["-p", "nonsense"], "expected NAME=VALUE"),
    (["--method", "hkc", "--voxel-size", "0.1"], "--voxel-size is for --method voxel"),
    (["--ratio", "0.2", "--count", "5"], "not allowed with argument --ratio"),
    (["--count", "100000"], "--count 100000 is more than the 1771 points"),
    (["--count", "0"], "must be >= 1"),
    (["--search", "bogus"], "argument --search: invalid choice: 'bogus'"),
    (["--method", "fps", "--search", "jax"], "method 'fps' does not take --search"),
    (["-p", "search=jax"], "-p search: set it with --search"),
])
def test_parameter_errors_exit_2(capsys, tmp_path, args, message):
    code, out, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "k.ply", *args)
    assert code == 2 and out == ""
    assert message in err, err
    assert not (tmp_path / "k.ply").exists()


@pytest.mark.full
@pytest.mark.parametrize("method", ["ea", "hkc"])
def test_search_is_the_engines_and_keeps_the_same_points(capsys, tmp_path, runs, method):
    """--search names the search of the engine's tiles (the backend's default without it): the
    traced search keeps and writes what the host's k-d tree does."""
    written = {}
    for search in (None, "jax"):
        out = tmp_path / f"{search}.ply"
        code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", out, "--samples", 600, "--method", method,
                                *([] if search is None else ["--search", search]))
        assert code == 0, err
        written[search] = io.read_points(out)
    assert [params.get("search") for _, _, params in runs] == [None, "jax"]
    assert len(written["jax"]) == 120
    np.testing.assert_array_equal(written["jax"].points, written[None].points)
    np.testing.assert_array_equal(written["jax"].attributes["score"], written[None].attributes["score"])


@pytest.mark.full
@pytest.mark.parametrize("method", ["hkc", "gfr", "voxel"])
def test_count_keeps_exactly_m_points(capsys, tmp_path, method):
    for count in (1, 333, 1771):
        code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "k.npy", "--count", count,
                                "--method", method)
        assert code == 0, err
        assert len(io.read_points(tmp_path / "k.npy")) == count


def test_count_ratio_is_exact_for_every_size():
    for n in range(1, 150):
        for m in range(1, n + 1):
            assert _validate.n_keep(n, cli_common.count_ratio(m, n)) == m
    # Every count of every N below 1200 at once: n_keep's rounded ceiling of count_ratio(m, n) x n
    # (its clamp to [1, n] cannot change a value that is m).
    n, m = np.meshgrid(np.arange(1, 1200), np.arange(1, 1200), indexing="ij")
    n, m = n[m <= n], m[m <= n]
    np.testing.assert_array_equal(_validate._ceil_rounded(cli_common.count_ratio(m, n) * n, np), m)
    rng = np.random.default_rng(0)
    for n in [*rng.integers(1, 10**10, 3000).tolist(), 6369616873]:
        for m in (1, 2, int(rng.integers(1, n + 1)), n - 1, n):
            assert _validate.n_keep(n, cli_common.count_ratio(m, n)) == m, (m, n)


def test_voxel_size_is_one_pass_at_that_size(capsys, tmp_path):
    points = io.read_points(LAMPPOST).points
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "i.npy", "--method", "voxel",
                            "--voxel-size", 0.5)
    assert code == 0, err
    expected = hgjax.voxel_sample(points, voxel_size=0.5)
    np.testing.assert_array_equal(io.read_points(tmp_path / "i.npy").points, points[np.sort(expected)])
    assert expected.size < points.shape[0] // 2
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "j.npy", "--method", "voxel",
                            "--voxel-size", 0.5, "--count", 100)
    assert code == 0, err
    expected = hgjax.voxel_sample(points, 100 / len(points), voxel_size=0.5)
    np.testing.assert_array_equal(io.read_points(tmp_path / "j.npy").points, points[np.sort(expected)])


def test_score_command(tmp_path, capsys):
    points = io.read_points(LAMPPOST).points
    expected = np.asarray(hgjax.score(hgjax.neighbourhoods(points, "hkf"), "hkf"))
    for ext in ("ply", "txt", "npy"):
        code, _, err = run_here(capsys, "score", LAMPPOST, "-o", tmp_path / f"s.{ext}", "--method", "hkf",
                                "--dtype", "float64")
        assert code == 0, err
    np.testing.assert_allclose(io.read_points(tmp_path / "s.ply").attributes["score"], expected, rtol=1e-6)
    np.testing.assert_allclose(io.read_points(tmp_path / "s.txt").attributes["score"], expected, rtol=1e-6)
    np.testing.assert_allclose(np.load(tmp_path / "s.npy")["score"], expected, rtol=1e-6)


def test_score_float64(tmp_path, capsys):
    code, _, err = run_here(capsys, "score", LAMPPOST, "-o", tmp_path / "s.ply", "--method", "hkf", "--dtype",
                            "float64")
    assert code == 0, err
    score = io.read_points(tmp_path / "s.ply").attributes["score"]
    assert score.dtype == np.float64


def test_demo_ranks_every_method_by_edge_recall_and_draws_them_in_the_working_folder(tmp_path, monkeypatch,
                                                                                    capsys):
    import matplotlib.image

    monkeypatch.chdir(tmp_path)
    code, out, err = run_here(capsys, "demo", "--n-points", 2000, "--quiet")
    assert code == 0 and err == "", err
    edges = int(re.search(r"^(\d+) of them", out, re.M).group(1))
    rows = [cells for cells in map(str.split, out.splitlines())
            if cells[:1] and cells[0] in hgjax.METHODS and cells[1].isdigit()]
    recall = {row[0]: float(row[3]) for row in rows}
    assert sorted(recall) == sorted(hgjax.METHODS) and all(int(row[1]) == edges for row in rows)
    assert list(recall.values()) == sorted(recall.values(), reverse=True)
    assert min(recall[m] for m in ("ea", "hkc", "lhf", "mss")) > 1.5 * max(recall[m] for m in ("fps", "uniform",
                                                                                                   "voxel"))
    assert f"the share of the {edges} edge points kept; 1.000 at best" in out
    assert next(row for row in rows if row[0] == "hkf")[4:] == ["same", "points", "as", "hkc"]
    assert f"wrote the picture to {tmp_path / cli_main.DEMO_PICTURE}" in out
    assert out.splitlines()[-1].startswith("next: hgjax resample ")
    assert matplotlib.image.imread(tmp_path / cli_main.DEMO_PICTURE).shape[1] > 1000


def test_version_and_help(capsys):
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.startswith("hgjax ")
    code, out, _ = run_here(capsys, "--help")
    assert code == 0 and "examples:" in out
    assert "exit codes:" in out and "130  interrupted" in out and "HGJAX_CACHE_DIR" in out


HELP_MODULES = """
import sys
from hgjax.cli import main
code = main(sys.argv[1:])
print(code, sorted({"numpy", "jax", "jaxlib", "scipy"} & set(sys.modules)), file=sys.stderr)
"""


@pytest.mark.parametrize("command", ["", "resample", "score", "compare", "demo"])
def test_help_imports_neither_numpy_nor_jax_and_shows_its_own_examples(command):
    proc = subprocess.run([sys.executable, "-c", HELP_MODULES, *command.split(), "--help"], capture_output=True,
                          text=True, timeout=120)
    assert proc.stderr.splitlines()[-1] == "0 []", proc.stderr
    examples = proc.stdout.split("examples:\n")[1]
    lines = [line.split()[:2] for line in examples.splitlines() if line.startswith("  hgjax ")]
    assert lines and (not command or all(line == ["hgjax", command] for line in lines)), examples
    assert ("130  interrupted" in proc.stdout) == (not command)  # the global notes once, in hgjax --help


def _option(command: str, dest: str):
    commands = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    return next(a for a in commands[command]._actions if a.dest == dest)


@pytest.mark.parametrize("command", ["resample", "score"])
def test_the_parsers_methods_are_the_registrys(command):
    method = _option(command, "method")
    names = [m for m in sorted(hgjax.METHODS) if command == "resample" or isinstance(hgjax.METHODS[m], hgjax.Method)]
    assert (method.choices, method.default) == (names, hgjax.engine._registry.DEFAULT)


def test_the_parsers_formats_are_the_writers():
    assert tuple(_option("resample", "format").choices) == tuple(ext[1:] for ext in io.WRITE_EXTENSIONS)


def test_the_registry_refuses_method_names_its_name_list_does_not_hold():
    with pytest.raises(RuntimeError, match="hgjax._names lists"):
        hgjax.engine._registry._by_name(*[e for m, e in hgjax.METHODS.items() if m != "fps"])
    assert hgjax.engine._registry._by_name(*hgjax.METHODS.values()) == hgjax.METHODS


@pytest.mark.parametrize("args, message", [
    (["resample", "missing.ply", "-o", "x.ply"], "cannot read missing.ply: no such file"),
    (["resample", MESH, "-o", "x.ply", "--ratio", "1.5"], "ratio must be in (0, 1]"),
    (["resample", MESH, "-o", "x.ply", "--ratio", "abc"], "not a number: 'abc'"),
    (["resample", MESH, "-o", "x.ply", "--method", "nope"], "invalid choice: 'nope'"),
    (["resample", MESH, "-o", "x.obj"], "hgjax does not write .obj files"),
    (["resample", MESH, "-o", "new/x.foo"], "cannot write new/x.foo: hgjax does not write .foo files"),
    (["resample", MESH, "-o", "x.ply", "--samples", "500", "--variant", "nope"], "unknown variant 'nope'"),
    (["resample", MESH, "-o", "x.ply", "--samples", "0"], "must be >= 1"),
    (["resample", MESH, "-o", "x.ply", "--seed", "-1"], "argument --seed: must be in [0, 2**32); got -1"),
    (["resample", MESH, "-o", "x.ply", "--seed", str(2**32)], "must be in [0, 2**32)"),
    (["resample", MESH, "-o", "x.ply", "--seed", "1.5"], "argument --seed: not an integer: '1.5'"),
    (["resample", MESH, "-o", "x.ply", "--key", "-3"], "argument --key: must be in [0, 2**32)"),
    (["compare", MESH, "--methods", "hkc,nope"], "unknown method(s) ['nope']"),
    (["score", DATA / "README.md", "-o", "x.ply"], "README.md"),
    (["score", MESH, "-o", "x.npy", "--method", "fps"], "invalid choice: 'fps'"),
    (["frobnicate"], "invalid choice"),
    (["resample", MESH, "-o", "out", "--method", "pca_ac", "--tile", "0.5"],
     "--method pca_ac cannot run in tiles: PCA-AC clusters the scores of the whole cloud at once (Ward), so its"
     " selection cannot be cut into tiles; leave out --tile to run it on the whole cloud at once"),
])
def test_usage_errors_exit_2(capsys, monkeypatch, tmp_path, args, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_here(capsys, *args)
    assert code == 2
    assert message in err and out == ""
    assert not list(tmp_path.iterdir())


def test_errors_in_a_subprocess_exit_2_without_traceback(tmp_path):
    for args in (["resample", "missing.ply", "-o", tmp_path / "x.ply"],
                 ["resample", LAMPPOST, "-o", tmp_path / "x.ply", "--seed", "4294967296"],
                 ["resample", LAMPPOST, "-o", tmp_path / "x.ply", "--method", "pca_ac", "--tile", "1"]):
        proc = run(*args)
        assert proc.returncode == 2 and proc.stdout == "" and "tile=None" not in proc.stderr, proc.stderr


def test_a_missing_directory_of_the_output_file_is_created(capsys, tmp_path):
    target = tmp_path / "single" / "deeper" / "x.ply"
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", target, "--method", "uniform", "--samples", "500")
    assert code == 0 and len(io.read_points(target)) == 100, err


def test_unwritable_output_is_refused_before_computing(capsys, tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise AssertionError("computed before the output was checked")

    monkeypatch.setattr(engine, "run", fail)
    monkeypatch.setattr(io, "read_points", fail)
    (tmp_path / "file").write_text("")
    code, _, err = run_here(capsys, "resample", MESH, "-o", tmp_path / "file" / "dir" / "x.ply")
    assert code == 2 and "cannot create the directory of -o" in err and "Not a directory" in err, err
    (tmp_path / "out" / "scan_lamppost.ply").mkdir(parents=True)
    code, _, err = run_here(capsys, "resample", MESH, LAMPPOST, "-o", tmp_path / "out")
    assert code == 2 and "scan_lamppost.ply: it is a directory" in err
    assert os.listdir(tmp_path / "out") == ["scan_lamppost.ply"]


def test_output_onto_the_input(capsys, tmp_path):
    path = tmp_path / "scan.ply"
    source = io.read_points(SCAN, samples=3000)
    io.write_points(path, source.points, attributes=source.attributes)
    code, _, err = run_here(capsys, "resample", path, "-o", path, "--method", "lhf", "--ratio", 0.25,
                            "--dtype", "float64")
    assert code == 0, err
    idx = np.sort(hgjax.resample(source.points, 0.25, method="lhf"))
    kept = io.read_points(path)
    np.testing.assert_array_equal(kept.points, source.points[idx])
    np.testing.assert_array_equal(kept.attributes["colors"], source.attributes["colors"][idx])


def test_write_failure_exits_1(tmp_path, capsys, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(io, "write_points", full)
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "x.ply")
    assert code == 1 and "failed: OSError" in err and "No space left" in err


def test_too_many_samples_are_refused_up_front(capsys, tmp_path, monkeypatch):
    start = time.perf_counter()
    code, _, err = run_here(capsys, "resample", MESH, "-o", tmp_path / "x.ply", "--samples", 10**9)
    cost = hgjax.METHODS["hkc"].bytes_per_sample
    assert code == 2 and f"--samples 1000000000 needs about {cost:.1f} GB" in err and "or fewer" in err
    assert time.perf_counter() - start < 5
    monkeypatch.setattr(cli_common, "_available_memory", lambda: 2**30)  # where _check_samples reads it
    code, _, err = run_here(capsys, "compare", MESH, "--samples", 10**6)
    costliest = max(e.bytes_per_sample for e in hgjax.METHODS.values())  # compare runs every method
    assert code == 2 and f"use --samples {2**30 // costliest} or fewer" in err
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "x.ply", "--samples", 10**6)
    assert code == 0, err  # a point cloud is only subset: nothing is sampled
    code, _, err = run_here(capsys, "resample", DATA / "meshes" / "bunny.ply", "-o", tmp_path / "x.ply",
                            "--samples", 10**6)
    assert code == 2 and "to sample" in err and "bunny.ply" in err  # a PLY mesh is sampled


def test_available_memory_from_the_system():
    memory = cli_common._available_memory()
    assert 2**20 < memory < 2**50


@pytest.mark.full
def test_ctrl_c_exits_130_with_one_line(tmp_path):
    scans = tmp_path / "scans"
    scans.mkdir()
    points = hgjax.eval.box_union_cloud(seed=0, n_points=20000).points
    for i in range(200):
        io.write_points(scans / f"s{i:03d}.npy", points)
    args = ["resample", scans, "-o", tmp_path / "out", "--method", "lhf", "--no-progress"]
    # As from a terminal: a runner that starts tests in the background passes SIGINT on as
    # ignored, and a process started that way rightly keeps ignoring it.
    as_from_a_terminal = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler);"
                          " runpy.run_module('hgjax', run_name='__main__')")
    proc = subprocess.Popen([sys.executable, "-c", as_from_a_terminal, *map(str, args)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stderr.readline()
    assert first.startswith("lhf: kept 4000 of 20000 points"), first + proc.stderr.read()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.splitlines()[-1] == "hgjax: interrupted" and "Traceback" not in stderr and stdout == ""
    written = sorted(set(os.listdir(tmp_path / "out")) - {"hgjax-manifest.json"})
    assert 1 <= len(written) < 200
    for name in written:  # no partial file
        assert len(io.read_points(tmp_path / "out" / name)) == 4000


def test_float32_run_on_float64_input_does_not_warn(capsys, tmp_path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", tmp_path / "x.ply", "--method", "hkc")
    assert code == 0 and "warning" not in err.lower()
    assert not [w for w in caught if issubclass(w.category, hgjax.PrecisionWarning)]


def test_jax_settings_are_restored_after_a_run(capsys, tmp_path):
    import jax

    before = (jax.config.jax_enable_x64, jax.config.jax_compilation_cache_dir)
    code, _, err = run_here(capsys, "score", LAMPPOST, "-o", tmp_path / "s.ply", "--dtype", "float64")
    assert code == 0, err
    assert io.read_points(tmp_path / "s.ply").attributes["score"].dtype == np.float64
    assert (jax.config.jax_enable_x64, jax.config.jax_compilation_cache_dir) == before


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
    with pytest.raises(ValueError, match="colors must have shape"):
        show_resampling(pts, np.arange(3), colors=np.ones((3, 3)))
    with pytest.raises(ValueError, match="columns must be"):
        show_resampling(pts, np.arange(3), columns=0)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(ImportError, match=r'pip install "\.\[plot\]"'):
        show_resampling(pts, np.arange(3))


def test_show_resampling_grid_and_scan_colours():
    from hgjax.plot import show_resampling

    pts = np.random.default_rng(0).random((40, 3))
    panels = {f"m{i}": np.arange(i + 1) for i in range(9)}
    fig = show_resampling(pts, panels)
    width, height = fig.get_size_inches()
    assert (width, height) == (16.0, 12.0)  # 10 panels: 4 columns, 3 rows
    assert len({ax.get_subplotspec().rowspan.start for ax in fig.axes}) == 3
    colors = np.zeros((40, 3), np.uint8)
    colors[:, 0] = np.arange(40) * 6
    fig = show_resampling(pts, np.array([3, 7]), colors=colors, columns=2)
    fig.draw_without_rendering()
    np.testing.assert_allclose(np.sort(fig.axes[1].collections[0].get_facecolors()[:, 0]), [18 / 255, 42 / 255])
    wide = show_resampling(pts, {"a": np.arange(3)}, colors=colors.astype(np.uint16) * 257)
    wide.draw_without_rendering()
    np.testing.assert_allclose(np.sort(wide.axes[0].collections[0].get_facecolors()[:, 0]), colors[:, 0] / 255)


def test_compare_writes_table_and_a_readable_picture(tmp_path, capsys):
    import matplotlib.image

    code, out, err = run_here(capsys, "compare", SCAN, "-o", tmp_path, "--samples", 2000)
    assert code == 0, err
    assert "| hkc | 400 | 2000 |" in out
    assert (tmp_path / "compare.csv").read_text().count("\n") == len(hgjax.METHODS) + 1
    height, width = matplotlib.image.imread(tmp_path / "compare.png").shape[:2]
    assert width <= 2400 and 0.5 <= height / width <= 1.5, (width, height)


@pytest.mark.parametrize("method", sorted(hgjax.METHODS))
def test_every_method_resamples_to_ply_with_its_score(tmp_path, capsys, method):
    out = tmp_path / "k.ply"
    code, _, err = run_here(capsys, "resample", LAMPPOST, "-o", out, "--samples", 600, "--method", method,
                            "--ratio", 0.1, "--quiet")
    assert code == 0, err
    kept = io.read_points(out)
    assert len(kept) == 60
    assert ("score" in kept.attributes) == isinstance(hgjax.METHODS[method], hgjax.Method)


@pytest.mark.parametrize("command", ["resample", "score", "compare", "demo"])
def test_each_command_help_holds_its_own_examples_not_the_global_epilog(capsys, command):
    code, text, _ = run_here(capsys, command, "--help")
    assert code == 0
    examples = text.split("examples:\n", 1)[1].splitlines()
    assert examples[0].strip().startswith(f"hgjax {command}")
    assert "130  interrupted" not in text and "Inputs: PLY" not in text
    assert text.rstrip().endswith(cli_main.MORE.strip())
    assert "-q, --quiet" in text and "--no-progress" in text and "-v, --verbose" in text
