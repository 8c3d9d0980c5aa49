"""One resume rule for every mode: the manifest in a directory of outputs (hgjax.survey.run_record,
reusable, write_manifest, read_manifest) decides what --skip-existing keeps, file by file (the command line)
and in a survey (hgjax.survey.resample_files), with one line per output saying it was skipped or why it is
recomputed; a corrupt manifest is a clear error; a file reached twice is read once; an interrupted survey of
a whole-cloud method leaves no temporary behind."""

import json
import os
import re

import jax
import numpy as np
import pytest

import hgjax
from fixtures import box_union
from hgjax import io, survey
from hgjax.engine import _run
from hgjax.engine import _survey as engine_survey
from hgjax.cli import main

pytestmark = pytest.mark.usefixtures("cli_cache")

SKIPPED = f"{survey.MANIFEST} records the same method, ratio, parameters, key, version and inputs (--skip-existing)"
SIZES = {"a": 1200, "b": 900}


def _inputs(folder):
    """Two small PLY clouds in ``folder``; their paths, sorted."""
    folder.mkdir()
    for seed, (name, n) in enumerate(SIZES.items()):
        io.write_points(folder / f"{name}.ply", box_union(n, seed=seed))
    return sorted(str(p) for p in folder.glob("*.ply"))


def _cli(capsys, *args):
    """The CLI in this process: (exit code, stderr)."""
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, err


def _resume_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith(("skipped ", "recomputing "))]


def _stamps(out) -> dict:
    return {name: os.stat(out / name).st_mtime_ns for name in sorted(os.listdir(out)) if name != survey.MANIFEST}


def _touch(path):
    """Rewrite ``path`` with the same points and one more: another size and modification time."""
    data = io.read_points(path)
    io.write_points(path, np.concatenate([data.points, data.points[:1] + 1e-3]))


# (baseline arguments, rerun arguments, what changes between the runs, {output stem: the reason, or None: skipped})
PER_FILE = {
    "unchanged": ([], [], None, {"a": None, "b": None}),
    "seed of a deterministic method": ([], ["--seed", "5"], None, {"a": None, "b": None}),
    "method": ([], ["--method", "mss"], None, {s: 'the method changed ("ea" -> "mss")' for s in SIZES}),
    "ratio": ([], ["--ratio", "0.3"], None, {s: "the ratio changed (0.2 -> 0.3)" for s in SIZES}),
    "count": ([], ["--count", "100"], None, {s: "the count changed (null -> 100)" for s in SIZES}),
    "params": ([], ["-p", "k=12"], None, {s: 'the parameters changed ({} -> {"k": 12})' for s in SIZES}),
    "a parameter at its default": ([], ["-p", "k=16"], None, {"a": None, "b": None}),
    "key": (["--method", "uniform", "--key", "1"], ["--method", "uniform", "--key", "2"], None,
            {s: "the key changed" for s in SIZES}),
    "version": ([], [], "version", {s: "the hgjax version changed" for s in SIZES}),
    "input": ([], [], "input", {"a": "the input", "b": None}),
    "output": ([], [], "output", {"a": f"it changed since {survey.MANIFEST} recorded it", "b": None}),
    "missing": ([], [], "missing", {"a": "it does not exist", "b": None}),
}


def _change(what, src, out, monkeypatch):
    if what == "version":
        monkeypatch.setattr(hgjax, "__version__", "99.0")
    elif what == "input":
        _touch(src / "a.ply")
    elif what == "output":
        _touch(out / "a.ply")
    elif what == "missing":
        os.unlink(out / "a.ply")


@pytest.mark.full
@pytest.mark.parametrize("case", list(PER_FILE))
def test_per_file_resume_matrix(capsys, tmp_path, monkeypatch, case):
    before, after, what, want = PER_FILE[case]
    src, out = tmp_path / "src", tmp_path / "out"
    _inputs(src)
    base = ["resample", src, "-o", out, "--method", "ea", "--dtype", "float64"]  # the default ratio, 0.2
    code, err = _cli(capsys, *base, *before)
    assert code == 0, err
    assert sorted(os.listdir(out)) == ["a.ply", "b.ply", survey.MANIFEST]
    _change(what, src, out, monkeypatch)
    stamps = _stamps(out)
    code, err = _cli(capsys, *base, *before, *after, "--skip-existing")
    assert code == 0, err
    lines = _resume_lines(err)
    assert len(lines) == 2, err  # one line per output, in input order
    for line, (stem, reason) in zip(lines, want.items()):
        target = os.path.join(out, f"{stem}.ply")
        if reason is None:
            assert line == f"skipped {target}: {SKIPPED}"
            assert os.stat(target).st_mtime_ns == stamps[f"{stem}.ply"]
        else:
            assert line.startswith(f"recomputing {target}: ") and reason in line, line
            assert f"of {src / stem}.ply" in err.split(line)[1]  # it was computed after the line
    code, err = _cli(capsys, *base, *before, *after, "--skip-existing")  # the manifest records the new run
    assert code == 0 and _resume_lines(err) == [f"skipped {os.path.join(out, s)}.ply: {SKIPPED}" for s in SIZES], err


SURVEY = {
    "unchanged": ({}, {}, None, None),
    "method": ({}, {"method": "uniform", "key": 1}, None, 'the method changed ("ea" -> "uniform")'),
    "ratio": ({}, {"ratio": 0.3}, None, "the ratio changed (0.2 -> 0.3)"),
    "params": ({}, {"k": 12}, None, 'the parameters changed ({} -> {"k": 12})'),
    "tile": ({}, {"tile": 0.5}, None, "the tile changed (null -> 0.5)"),
    "key": ({"method": "uniform", "key": 1}, {"key": 2}, None, "the key changed"),
    "version": ({}, {}, "version", "the hgjax version changed"),
    "input": ({}, {}, "input", "a.ply changed (size or modification time)"),
}


def _survey(paths, out, lines=None, **changes):
    run = {"method": "ea", "ratio": 0.2, "key": None, **changes}
    if run["key"] is not None:
        run["key"] = jax.random.key(run["key"])
    return survey.resample_files(paths, out, run.pop("ratio"), skip_existing=lines is not None,
                                 on_resume=None if lines is None else lines.append, **run)


@pytest.mark.full
@pytest.mark.parametrize("case", list(SURVEY))
def test_survey_resume_matrix(tmp_path, monkeypatch, case):
    before, after, what, reason = SURVEY[case]
    src, out = tmp_path / "src", tmp_path / "out"
    paths = _inputs(src)
    _survey(paths, out, **before)
    _change(what, src, out, monkeypatch)
    stamps, lines = _stamps(out), []
    result = _survey(paths, out, lines, **{**before, **after})
    targets = [os.path.join(out, os.path.basename(p)) for p in paths]
    if reason is None:  # the same words as the command line's file-by-file mode
        assert lines == [f"skipped {t}: {SKIPPED}" for t in targets]
        assert result.skipped == targets and result.written == [] and _stamps(out) == stamps
    else:  # every output of a survey depends on every input
        assert [line.split(": ")[0] for line in lines] == [f"recomputing {t}" for t in targets]
        assert all(reason in line for line in lines), lines
        assert result.written == targets
    lines.clear()
    assert _survey(paths, out, lines, **{**before, **after}).written == []
    assert lines == [f"skipped {t}: {SKIPPED}" for t in targets]


def test_the_modes_share_one_manifest(capsys, tmp_path):
    """A survey's outputs and file-by-file outputs in one directory: each run keeps the other's records."""
    src, out = tmp_path / "src", tmp_path / "out"
    paths = _inputs(src)
    _survey(paths[:1], out)
    code, err = _cli(capsys, "resample", paths[1], "-o", out, "--method", "ea", "--dtype", "float64")
    assert code == 0, err
    recorded = json.loads((out / survey.MANIFEST).read_text())["outputs"]
    assert sorted(os.path.basename(e["output"]) for e in recorded) == ["a.ply", "b.ply"]
    lines = []
    _survey(paths[:1], out, lines)
    assert lines == [f"skipped {out / 'a.ply'}: {SKIPPED}"]
    code, err = _cli(capsys, "resample", paths[1], "-o", out, "--method", "ea", "--dtype", "float64", "--skip-existing")
    assert code == 0 and _resume_lines(err) == [f"skipped {out / 'b.ply'}: {SKIPPED}"], err


CORRUPT = {"invalid JSON": "{not json", "an array": "[]", "no outputs": '{"hgjax": "0.1.0"}',
           "an entry without a path": '{"outputs": [{"output": 3}]}',
           "an entry without a run": '{"outputs": [{"output": "/x.ply"}]}', "not UTF-8": b"\xff\xfe{}",
           "nested too deeply": '{"outputs": ' + "[" * 200_000 + "]" * 200_000 + "}"}


@pytest.mark.parametrize("case", list(CORRUPT))
def test_a_corrupt_manifest_is_a_clear_error(capsys, tmp_path, case):
    src, out = tmp_path / "src", tmp_path / "out"
    paths = _inputs(src)
    out.mkdir()
    manifest = out / survey.MANIFEST
    content = CORRUPT[case]
    manifest.write_bytes(content if isinstance(content, bytes) else content.encode())
    code, err = _cli(capsys, "resample", src, "-o", out, "--skip-existing", "--method", "ea")
    assert code == 2 and f"{manifest} is not an hgjax manifest" in err and "JSONDecodeError" not in err, err
    with pytest.raises(survey.ManifestError, match=re.escape(f"{manifest} is not an hgjax manifest")):
        _survey(paths, out, [])
    assert sorted(os.listdir(out)) == [survey.MANIFEST]  # refused before anything was computed
    code, err = _cli(capsys, "resample", src, "-o", out, "--method", "ea", "--dtype", "float64")  # replaced
    assert code == 0 and len(survey.read_manifest(manifest)["outputs"]) == 2, err


def test_runs_writing_one_manifest_at_the_same_time_each_add_their_outputs(tmp_path, monkeypatch):
    import threading
    import time

    reading = survey.read_manifest

    def slow(path):  # widens the window between a run's read of the manifest and its write
        got = reading(path)
        time.sleep(0.05)
        return got

    monkeypatch.setattr(survey, "read_manifest", slow)
    outputs = [tmp_path / f"run{i}.ply" for i in range(6)]
    for p in outputs:
        p.write_bytes(b"")
    record = survey.run_record([], method="hkc", ratio=0.2)
    runs = [threading.Thread(target=survey.write_manifest, args=(tmp_path / survey.MANIFEST, [{"output": p, "run": record}]))
            for p in outputs]
    for run in runs:
        run.start()
    for run in runs:
        run.join()
    recorded = reading(tmp_path / survey.MANIFEST)["outputs"]
    assert sorted(e["output"] for e in recorded) == sorted(str(p) for p in outputs)
    assert sorted(os.listdir(tmp_path)) == sorted([survey.MANIFEST, *(p.name for p in outputs)])  # no lock file left


def test_a_file_reached_twice_is_read_once(capsys, tmp_path, monkeypatch):
    src = tmp_path / "src"
    paths = _inputs(src)
    link = tmp_path / "link.ply"
    link.symlink_to(paths[0])
    reads = []
    chunks = io.chunks
    monkeypatch.setattr(io, "chunks", lambda path, **kw: reads.append(os.path.realpath(path)) or chunks(path, **kw))
    result = _survey([paths[0], str(link), paths[0], str(src / "*.ply")], tmp_path / "out", method="uniform", key=1)
    assert result.written == [str(tmp_path / "out" / "a.ply"), str(tmp_path / "out" / "b.ply")]
    assert sorted(reads) == sorted(os.path.realpath(p) for p in paths)  # the check reads each file once
    assert json.loads((tmp_path / "out" / survey.MANIFEST).read_text())["n"] == sum(SIZES.values())
    for extra in ([], ["--tile", "100"]):  # file by file and a survey
        out = tmp_path / f"cli{len(extra)}"
        code, err = _cli(capsys, "resample", paths[0], link, "-o", out, "--method", "uniform", *extra)
        assert code == 0 and f"{link} is {paths[0]} again; it is read once" in err, err
        assert sorted(os.listdir(out)) == ["a.ply", survey.MANIFEST]


def test_a_file_reached_twice_through_a_hard_link_is_read_once(capsys, tmp_path):
    src = tmp_path / "src"
    paths = _inputs(src)
    (tmp_path / "other").mkdir()
    link = tmp_path / "other" / "again.ply"
    os.link(paths[0], link)
    result = _survey([paths[0], str(link), paths[1]], tmp_path / "out", method="uniform", key=1)
    assert result.written == [str(tmp_path / "out" / "a.ply"), str(tmp_path / "out" / "b.ply")]
    manifest = json.loads((tmp_path / "out" / survey.MANIFEST).read_text())
    assert manifest["n"] == sum(SIZES.values()) and manifest["m"] == round(0.2 * sum(SIZES.values()))
    for extra in ([], ["--tile", "100"]):  # file by file and a survey
        out = tmp_path / f"cli{len(extra)}"
        code, err = _cli(capsys, "resample", paths[0], link, "-o", out, "--method", "uniform", *extra)
        assert code == 0 and f"{link} is {paths[0]} again; it is read once" in err, err
        assert sorted(os.listdir(out)) == ["a.ply", survey.MANIFEST]


@pytest.mark.parametrize("stop", [KeyboardInterrupt, SystemExit])
def test_an_interrupted_whole_cloud_survey_leaves_nothing(tmp_path, monkeypatch, stop):
    paths, out = _inputs(tmp_path / "src"), tmp_path / "out"
    seen = []

    def interrupted(points, *args, **kwargs):
        seen.append((type(points), [f for f in os.listdir(out) if f.startswith(".")], set(io.OPEN_TEMPORARIES)))
        raise stop()

    monkeypatch.setattr(_run, "run", interrupted)
    with pytest.raises(stop):
        survey.resample_files(paths, out, 0.2, method="voxel")
    (kind, temporaries, registered), = seen
    assert kind is np.memmap and len(temporaries) == 1 and temporaries[0].startswith(".hgjax-survey-xyz.f8.")
    assert str(out / temporaries[0]) in registered  # the CLI's signal handler removes it when it ends the process
    assert os.listdir(out) == [] and not registered & io.OPEN_TEMPORARIES


def test_a_killed_surveys_temporary_is_removed_by_the_next_run(tmp_path):
    paths, out = _inputs(tmp_path / "src"), tmp_path / "out"
    out.mkdir()
    parts = os.path.basename(engine_survey._temporary(str(out), "hgjax-survey-xyz.f8")).split(".")
    parts[-3] = "999999999"  # the pid of a process that no longer runs
    stale = out / ".".join(parts)
    stale.write_bytes(bytes(48))
    assert io.remove_stale_temporaries(out) == [str(stale)]  # named as hgjax.io names its temporaries
    stale.write_bytes(bytes(48))
    survey.resample_files(paths, out, 0.2, method="voxel")
    assert sorted(os.listdir(out)) == ["a.ply", "b.ply", survey.MANIFEST]
