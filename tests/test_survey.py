"""resample_files: a survey of LAS/LAZ tiles resampled as one cloud, in process and on a 2-worker LocalCluster."""

import errno
import json
import logging
import os
import re
import struct
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

import hgjax
from hgjax import io, survey, tiles
from hgjax.engine import _runners

laspy = pytest.importorskip("laspy")

OFFSET = np.array([500000.0, 4000000.0, 0.0])
TILE = 120.0  # the four-file survey in 37 tiles, each holding points of several files


def _survey(directory, ext=".las", n_files=4, n=3000):
    """Four LAS/LAZ tiles of one surface with UTM-like offsets and an extra dimension; returns (paths, cloud)."""
    base = hgjax.eval.box_union_cloud(seed=7, n_points=n_files * n).points * 50
    paths, parts = [], []
    for i in range(n_files):
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.offsets, header.scales = OFFSET, np.array([0.01, 0.01, 0.001])
        header.add_extra_dims([laspy.ExtraBytesParams("height", np.float32)])
        las = laspy.LasData(header)
        xyz = base[i * n:(i + 1) * n] + OFFSET
        las.x, las.y, las.z = xyz.T
        las.intensity = np.arange(n, dtype=np.uint16) + i
        las["height"] = np.float32(xyz[:, 2] - OFFSET[2])
        path = os.path.join(directory, f"tile{i}{ext}")
        las.write(path)
        paths.append(path)
        parts.append(io.read_points(path).points)
    return paths, np.concatenate(parts)


def _kept_ids(paths, out_dir):
    """Global ids of the output points (each output is a subset of its input, in input order)."""
    ids, start = [], 0
    for p in paths:
        src, out = io.read_points(p), io.read_points(os.path.join(out_dir, os.path.basename(p)))
        rows = {tuple(r): i for i, r in enumerate(src.points)}
        local = np.array([rows[tuple(r)] for r in out.points], dtype=np.int64)
        assert (np.diff(local) > 0).all()
        np.testing.assert_array_equal(out.attributes["intensity"], src.attributes["intensity"][local])
        np.testing.assert_array_equal(out.attributes["height"], src.attributes["height"][local])
        np.testing.assert_array_equal(out.header.scales, src.header.scales)
        np.testing.assert_array_equal(out.header.offsets, src.header.offsets)
        ids.append(local + start)
        start += len(src)
    return np.concatenate(ids)


@pytest.fixture(scope="module")
def survey_reference(tmp_path_factory):
    """The four-tile survey's cloud (the same in .las and .laz) and its tiled HKC kept ids, computed once."""
    _, cloud = _survey(tmp_path_factory.mktemp("reference"))
    return cloud, np.sort(tiles.resample(cloud, 0.2, method="hkc", tile=TILE))


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_survey_equals_the_concatenated_cloud(tmp_path, ext, survey_reference):
    paths, cloud = _survey(tmp_path, ext)
    reference, want = survey_reference
    np.testing.assert_array_equal(cloud, reference)
    before = [Path(p).read_bytes() for p in paths]
    result = survey.resample_files(str(tmp_path / f"*{ext}"), tmp_path / "kept", 0.2, method="hkc", tile=TILE)
    np.testing.assert_array_equal(_kept_ids(paths, tmp_path / "kept"), want)
    assert [Path(p).read_bytes() for p in paths] == before
    assert result.failures == {} and len(result.written) == 4
    manifest = json.loads((tmp_path / "kept" / survey.MANIFEST).read_text())
    assert manifest["m"] == want.size and sum(o["kept"] for o in manifest["outputs"]) == want.size
    assert not [f for f in os.listdir(tmp_path / "kept") if f.startswith(".")]


@pytest.mark.parametrize("method", ["lhf", "gfr"])
def test_manifest_records_the_resolved_plan_and_threshold(tmp_path, method):
    paths, cloud = _survey(tmp_path, n_files=2, n=1000)
    key = jax.random.key(3) if method == "gfr" else None
    tile = 200.0 if method == "gfr" else TILE  # GFR's radius (10 spacings) wants tiles of more than a few points
    survey.resample_files(paths, tmp_path / "kept", 0.2, method=method, tile=tile, key=key)
    resolved = json.loads((tmp_path / "kept" / survey.MANIFEST).read_text())["resolved"]
    plan, cloud_tiles = tiles.plan(cloud, 0.2, method=method, tile=tile)
    assert len(cloud_tiles.members) >= 4
    idx, scores = tiles.resample(cloud, 0.2, method=method, tile=tile, key=key, return_scores=True)
    assert resolved["plan"] == plan.record()
    assert resolved["plan"]["n"] == cloud.shape[0] and resolved["plan"]["m"] == idx.size
    np.testing.assert_array_equal(resolved["plan"]["origin"], plan.origin)
    assert resolved["threshold"]["gid"] == idx[-1]
    if method == "lhf":
        assert resolved["threshold"]["value"] == float(scores[idx[-1]])
        assert set(resolved["selection"]) == {"gamma_a", "gamma_b"}
    else:  # GFR's random mode keeps by perturbed log weight: its sum is what the weights need
        assert resolved["selection"]["score_sum"] == pytest.approx(float(np.sum(scores, dtype=np.float64)), rel=1e-12)


@pytest.mark.full
def test_survey_on_a_local_cluster(tmp_path, client):
    paths, cloud = _survey(tmp_path)
    survey.resample_files(paths, tmp_path / "kept", 0.2, method="ea", tile=TILE, client=client)
    np.testing.assert_array_equal(_kept_ids(paths, tmp_path / "kept"),
                                  np.sort(hgjax.resample(cloud, 0.2, method="ea")))


def test_a_point_on_a_tile_edge_is_owned_once(tmp_path):
    paths, cloud = _survey(tmp_path, n_files=2, n=1500)
    lo = cloud.min(axis=0)
    edge = lo + TILE  # exactly on a grid plane of the tiles in every axis (0.01 and 0.001 steps)
    las = laspy.read(paths[0])
    las.x[0], las.y[0], las.z[0] = edge
    las.write(paths[0])
    paths, cloud = paths, np.concatenate([io.read_points(p).points for p in paths])
    result = survey.resample_files(paths, tmp_path / "kept", 1.0, method="ea", tile=TILE)
    assert sum(len(io.read_points(p)) for p in result.written) == cloud.shape[0]


def test_a_corrupt_file_is_named_before_any_output(tmp_path):
    paths, _ = _survey(tmp_path, n_files=3, n=1500)
    with open(paths[1], "r+b") as fh:
        fh.truncate(os.path.getsize(paths[1]) // 2)
    with pytest.raises(io.PointCloudReadError, match="tile1.las"):
        survey.resample_files(paths, tmp_path / "kept", 0.2, method="ea", tile=TILE)
    assert not os.path.exists(tmp_path / "kept") or os.listdir(tmp_path / "kept") == []
    result = survey.resample_files(paths, tmp_path / "kept", 0.2, method="ea", tile=TILE, keep_going=True)
    assert list(result.failures) == [paths[1]] and len(result.written) == 2
    good = [paths[0], paths[2]]
    cloud = np.concatenate([io.read_points(p).points for p in good])
    np.testing.assert_array_equal(_kept_ids(good, tmp_path / "kept"), np.sort(hgjax.resample(cloud, 0.2, method="ea")))


def test_skip_existing_resumes(tmp_path):
    paths, _ = _survey(tmp_path, n_files=2, n=1500)
    out = tmp_path / "kept"
    survey.resample_files(paths, out, 0.2, method="ea", tile=TILE)
    first = (out / "tile0.las").read_bytes()
    os.unlink(out / "tile1.las")
    result = survey.resample_files(paths, out, 0.2, method="ea", tile=TILE, skip_existing=True)
    assert result.skipped == [str(out / "tile0.las")] and result.written == [str(out / "tile1.las")]
    assert (out / "tile0.las").read_bytes() == first
    again = survey.resample_files(paths, out, 0.2, method="ea", tile=TILE, skip_existing=True)
    assert again.written == [] and len(again.skipped) == 2
    changed = survey.resample_files(paths, out, 0.3, method="ea", tile=TILE, skip_existing=True)
    assert len(changed.written) == 2



def test_a_file_that_keeps_no_point_is_written_empty(tmp_path):
    """A small far file ranks below the kept count: its output holds no point, the others are written as usual."""
    paths, cloud = _survey(tmp_path, n_files=2, n=1500)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = OFFSET, np.array([0.01, 0.01, 0.001])
    far = laspy.LasData(header)
    far.x, far.y, far.z = (OFFSET + [9000.0, 9000.0, 0.0] + np.arange(9.0).reshape(3, 3) * 0.001).T
    far.write(tmp_path / "far.las")
    paths.append(str(tmp_path / "far.las"))
    out = tmp_path / "kept"
    result = survey.resample_files(paths, out, 0.01, method="ea")
    assert result.written == [str(out / Path(p).name) for p in paths] and not result.failures
    assert io.header_count(out / "far.las") == 0
    kept = [io.header_count(out / Path(p).name) for p in paths[:2]]
    assert sum(kept) == int(np.ceil(0.01 * (len(cloud) + 3)))
    manifest = json.loads((out / "hgjax-manifest.json").read_text())
    assert [o["kept"] for o in manifest["outputs"]] == kept + [0]

@pytest.mark.full
def test_cli_survey_on_two_workers(tmp_path):
    paths, cloud = _survey(tmp_path, n_files=2, n=1500)
    out = tmp_path / "kept"
    run = subprocess.run([sys.executable, "-m", "hgjax", "resample", *paths, "-o", str(out), "--method", "ea",
                          "--ratio", "0.2", "--tile", f"{TILE:g}", "--dtype", "float64", "--workers", "2"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    np.testing.assert_array_equal(_kept_ids(paths, out), np.sort(hgjax.resample(cloud, 0.2, method="ea")))
    assert (out / survey.MANIFEST).exists()
    assert run.stderr.startswith("hgjax resample: ea keeps 0.2 of a survey of 2 files as one cloud in tiles of 120")
    assert "Worker process still alive" not in run.stderr and "warn" not in run.stderr.lower(), run.stderr


@pytest.mark.full
def test_cli_workers_close_without_a_kill_warning(tmp_path, capsys, monkeypatch):
    """A worker that takes longer than Dask's 4 s to close is waited for, not killed with a warning."""
    distributed = pytest.importorskip("distributed")
    from hgjax import cli

    class SlowClose(distributed.WorkerPlugin):
        def teardown(self, worker):
            time.sleep(4.5)

    class Client(distributed.Client):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.register_plugin(SlowClose())

    monkeypatch.setattr(distributed, "Client", Client)
    records, handler, logger = [], logging.Handler(), logging.getLogger("distributed.nanny")
    handler.emit = records.append
    logger.addHandler(handler)
    try:
        paths, _ = _survey(tmp_path, n_files=1, n=500)
        code = cli.main(["resample", *paths, "-o", str(tmp_path / "kept"), "--method", "uniform", "--workers", "1",
                         "--quiet"])
    finally:
        logger.removeHandler(handler)
    assert code == 0, capsys.readouterr().err
    assert not [r for r in records if r.levelno >= logging.WARNING], [r.getMessage() for r in records]


@pytest.mark.parametrize("extra,message", [(["--workers", "0"], "--workers"),
                                           (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
                                           (["--tile", "30", "--count", "10"], "--count")])
def test_cli_survey_bad_arguments(tmp_path, capsys, extra, message):
    from hgjax import cli

    paths, _ = _survey(tmp_path, n_files=2, n=100)
    assert cli.main(["resample", *paths, "-o", str(tmp_path / "kept"), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "kept").exists()


def test_cli_survey_keep_going_exits_1(tmp_path, capsys):
    from hgjax import cli

    paths, _ = _survey(tmp_path, n_files=2, n=1500)
    (tmp_path / "bad.las").write_bytes(b"not a las file")
    code = cli.main(["resample", *paths, str(tmp_path / "bad.las"), "-o", str(tmp_path / "kept"), "--method", "ea",
                     "--tile", f"{TILE:g}", "--keep-going"])
    assert code == 1 and "bad.las" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path / "kept")) == ["hgjax-manifest.json", "tile0.las", "tile1.las"]



@pytest.mark.parametrize("method,key", [("lhf", None), ("uniform", 4)])
def test_survey_outputs_carry_the_fields_of_per_file_outputs(tmp_path, method, key):
    """A scoring method writes each kept point's score from this run (that of tiles.resample with return_scores on
    the concatenated cloud), replacing a stale one read back from the input; a sampler carries it as it is."""
    base = hgjax.eval.box_union_cloud(seed=7, n_points=2000).points * 50
    paths = [str(tmp_path / f"part{i}.ply") for i in range(2)]
    for i, path in enumerate(paths):
        io.write_points(path, base[i * 1000:(i + 1) * 1000], attributes={"index": np.arange(1000) + 1000 * i},
                        scores=np.full(1000, -1.0))
    cloud = np.concatenate([io.read_points(p).points for p in paths])
    key = None if key is None else jax.random.key(key)
    survey.resample_files(paths, tmp_path / "kept", 0.2, method=method, tile=TILE, key=key)
    outs = [io.read_points(tmp_path / "kept" / os.path.basename(p)) for p in paths]
    ids = np.concatenate([o.attributes["index"] for o in outs])
    written = np.concatenate([o.attributes["score"] for o in outs])
    idx, scores = tiles.resample(cloud, 0.2, method=method, tile=TILE, key=key, return_scores=True)
    np.testing.assert_array_equal(ids, np.sort(idx))
    if scores is None:
        np.testing.assert_array_equal(written, -1.0)
    else:
        assert (written != -1.0).all()
        np.testing.assert_allclose(written, scores[ids], rtol=1e-6)


def test_progress_from_the_first_stage(tmp_path, capsys):
    paths, _ = _survey(tmp_path, n_files=2, n=1000)
    survey.resample_files(paths, tmp_path / "kept", 0.2, method="ea", tile=TILE, progress=True,
                          on_stage=lambda name, seconds: print(f"stage {name} ended", file=sys.stderr))
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == f"hgjax survey: check: 2 files, {_runners.Ticker.si(sum(map(os.path.getsize, paths)))} bytes"
    assert lines.index("stage check ended") > 1  # the check reported its files before it ended
    stages = [line.split()[1] for line in lines if line.startswith("stage ")]
    assert stages == ["check", "plan", "tiles", "keep", "write"]
    passes = [(line.split(": ")[0], line.split(": ")[1]) for line in lines if re.match(r"hgjax \w+: [\w ]+: \d+ ", line)]
    assert [what for _, what in passes] == ["check", "census", "tile scores", "write"]  # EA resolves nothing
    for prefix, what in passes:  # the last line of each pass: all its tasks and points, a rate and no time left
        last = [line for line in lines if line.startswith(f"{prefix}: {what} ")][-1]
        done = re.fullmatch(rf"{prefix}: {what} (\d+)/(\d+) (?:files|tiles), (\S+)/(\S+) (points|bytes), \S+ \5/s,"
                            r" ETA 0 s", last)
        assert done and done[1] == done[2] and done[3] == done[4], last


def test_ticker_lines_and_bar(capsys, monkeypatch):
    tick = _runners.Ticker("tile scores", {"a": 1500, "b": 500})
    tick("a")
    tick("b")
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "hgjax tiles: tile scores: 2 tiles, 2k points"
    assert re.fullmatch(r"hgjax tiles: tile scores 2/2 tiles, 2k/2k points, \S+ points/s, ETA 0 s", lines[-1])
    pytest.importorskip("tqdm")
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # a terminal: a tqdm bar instead
    tick = _runners.Ticker("tile scores", {"a": 1500, "b": 500})
    tick("a")
    tick("b")
    err = capsys.readouterr().err
    assert "hgjax tiles: tile scores (2 tiles)" in err and "100%" in err and "ETA" not in err


def test_tickers_in_many_threads_print_whole_lines(monkeypatch):
    """A pass's last line comes from a Dask callback thread while the next pass's first line comes from the
    main thread: every line is whole, none empty, even on a stream that lets another thread run inside a write."""
    import threading
    from io import StringIO

    class Slow(StringIO):
        def write(self, text):
            time.sleep(0.001)  # another thread runs here
            return super().write(text)

        def isatty(self):
            return False

    stream = Slow()
    monkeypatch.setattr(sys, "stderr", stream)
    monkeypatch.setattr(_runners.Ticker, "PERIOD", 0.0)
    sizes = {i: 10 for i in range(20)}

    def one_pass(name):
        tick = _runners.Ticker(name, sizes)
        for key in sizes:
            tick(key)

    threads = [threading.Thread(target=one_pass, args=(f"pass {i}",)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 4 * 21
    assert all(re.fullmatch(r"hgjax tiles: pass \d:? [^:]*", line) for line in lines), lines


@pytest.mark.parametrize("method,stages", [("ea", ["plan", "tiles", "keep"]), ("voxel", ["copy", "sample"])])
def test_cli_survey_verbose_prints_every_stage(tmp_path, capsys, method, stages):
    from hgjax import cli

    paths, _ = _survey(tmp_path, n_files=2, n=1000)
    code = cli.main(["resample", *paths, "-o", str(tmp_path / "kept"), "--method", method, "--tile", f"{TILE:g}", "-v",
                     "--quiet", "--dtype", "float64"])
    err = capsys.readouterr().err
    assert code == 0, err
    lines = [line.split(":") for line in err.splitlines() if line.startswith("  ")]
    assert [name.strip() for name, _ in lines] == ["check", *stages, "write", "total"]
    assert all(re.fullmatch(r" \d+\.\d{3} s", seconds) for _, seconds in lines), lines


@pytest.mark.parametrize("method,params", [("uniform", {"key": jax.random.key(5)}), ("voxel", {}),
                                           ("gfr", {"variant": "reference", "mode": "top"})])
def test_whole_cloud_methods_equal_the_concatenated_cloud(tmp_path, method, params):
    paths, cloud = _survey(tmp_path, n_files=2, n=1000)
    survey.resample_files(paths, tmp_path / "kept", 0.2, method=method, **params)
    np.testing.assert_array_equal(_kept_ids(paths, tmp_path / "kept"),
                                  np.sort(hgjax.resample(cloud, 0.2, method=method, **params)))
    assert not [f for f in os.listdir(tmp_path / "kept") if f.startswith(".")]


def test_uniform_reads_no_coordinate_after_the_check(tmp_path, monkeypatch):
    paths, cloud = _survey(tmp_path, n_files=2, n=1000)
    read = []
    chunks = io.chunks
    monkeypatch.setattr(io, "chunks", lambda path: read.append(path) or chunks(path))
    key = jax.random.key(6)
    survey.resample_files(paths, tmp_path / "kept", 0.3, method="uniform", key=key, tile=30.0)
    assert sorted(read) == sorted(os.path.abspath(p) for p in paths)  # the check's one read of each file
    np.testing.assert_array_equal(_kept_ids(paths, tmp_path / "kept"),
                                  np.sort(hgjax.resample(cloud, 0.3, method="uniform", key=key)))


COPC = Path(__file__).parent / "data" / "survey.copc.laz"  # written by tests/data/make_copc.py


def _same_dimensions(out, src, kept):
    """Every dimension of ``src`` at ``kept``, bit for bit, in ``out``, then the new score (a scoring method)."""
    names = list(src.point_format.dimension_names)
    assert list(out.point_format.dimension_names) == [*names, "score"]
    for name in names:
        np.testing.assert_array_equal(np.asarray(out[name]), np.asarray(src[name])[kept], err_msg=name)


def test_copc_tiles_read_only_the_octree_nodes_they_meet(tmp_path, monkeypatch):
    path = tmp_path / "octree.laz"  # a COPC file is known by its COPC info VLR, not by its name
    path.write_bytes(COPC.read_bytes())
    src = laspy.read(path)
    cloud = np.stack([np.asarray(src.x), np.asarray(src.y), np.asarray(src.z)], axis=1)
    assert len(tiles.plan(cloud, 0.2, method="hkc", tile=100.0)[1].members) >= 4
    decoded, fetch = [], laspy.copc.CopcReader._fetch_and_decompress_points_of_nodes
    monkeypatch.setattr(laspy.copc.CopcReader, "_fetch_and_decompress_points_of_nodes",
                        lambda reader, nodes: decoded.append(len(nodes)) or fetch(reader, nodes))
    survey.resample_files([path], tmp_path / "kept", 0.2, method="hkc", tile=100.0)
    with laspy.copc.CopcReader.open(path) as reader:
        nodes = len(laspy.copc.load_octree_for_query(reader.source, reader.copc_info, reader.root_page))
    assert max(decoded) == nodes and min(decoded) < nodes  # the check reads every node, a tile only some
    want = np.sort(hgjax.resample(cloud, 0.2, method="hkc"))
    out = laspy.read(tmp_path / "kept" / "octree.laz")
    _same_dimensions(out, src, want)
    np.testing.assert_array_equal(out.header.scales, src.header.scales)
    np.testing.assert_array_equal(out.header.offsets, src.header.offsets)


@pytest.mark.full
def test_copc_among_las_tiles_on_a_local_cluster_keeps_global_ids_in_file_order(tmp_path, client):
    paths, cloud = _survey(tmp_path, ".laz", n_files=1, n=1500)
    copc = io.read_points(COPC).points
    survey.resample_files([COPC, *paths], tmp_path / "kept", 0.2, method="ea", tile=100.0, client=client)
    want = np.sort(hgjax.resample(np.concatenate([copc, cloud]), 0.2, method="ea"))
    kept = want[want < copc.shape[0]]
    out = laspy.read(tmp_path / "kept" / COPC.name)
    _same_dimensions(out, laspy.read(COPC), kept)
    np.testing.assert_array_equal(_kept_ids(paths, tmp_path / "kept") + copc.shape[0], want[want >= copc.shape[0]])


def _corrupt_copc(path, what):
    """Rewrite the COPC file ``path`` in place: one node's hierarchy count one short, or its octree half as wide."""
    data = bytearray(path.read_bytes())
    with laspy.copc.CopcReader.open(path) as reader:
        info, entry = reader.copc_info, max(reader.root_page.entries.values(), key=lambda e: e.point_count)
    if what == "count":
        k = entry.key
        old = struct.pack("<iiiiQii", k.level, k.x, k.y, k.z, entry.offset, entry.byte_size, entry.point_count)
        new = old[:-4] + struct.pack("<i", entry.point_count - 1)
    else:
        old = struct.pack("<4d", *info.center, info.halfsize)
        new = struct.pack("<4d", *info.center, info.halfsize / 2)
    at = data.index(old)
    data[at:at + len(old)] = new
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("what,message", [("count", "header announces 4000"), ("bounds", "outside the node's bounds")])
def test_a_corrupt_copc_octree_is_named_before_any_output(tmp_path, what, message):
    paths, _ = _survey(tmp_path, ".laz", n_files=1, n=1000)
    bad = tmp_path / "bad.copc.laz"
    bad.write_bytes(COPC.read_bytes())
    _corrupt_copc(bad, what)
    with pytest.raises(io.PointCloudReadError, match=message):
        survey.resample_files([*paths, bad], tmp_path / "kept", 0.2, method="ea", tile=100.0)
    assert not os.path.exists(tmp_path / "kept") or os.listdir(tmp_path / "kept") == []


def test_copc_chunks_number_points_in_file_order(monkeypatch):
    monkeypatch.setattr(io, "CHUNK_ROWS", 500)  # several batches of nodes
    src = laspy.read(COPC)
    xyz = np.stack([np.asarray(src.x), np.asarray(src.y), np.asarray(src.z)], axis=1)
    whole = list(io.chunks(str(COPC)))
    np.testing.assert_array_equal(np.concatenate([s + np.arange(x.shape[0]) for s, x in whole]), np.arange(len(xyz)))
    np.testing.assert_array_equal(np.concatenate([x for _, x in whole]), xyz)
    lo, hi = xyz.min(axis=0) + 40.0, xyz.min(axis=0) + 90.0
    part = list(io.chunks(str(COPC), box=(lo, hi)))
    ids = np.concatenate([s + np.arange(x.shape[0]) for s, x in part])
    np.testing.assert_array_equal(np.concatenate([x for _, x in part]), xyz[ids])
    inside = np.flatnonzero(((xyz >= lo) & (xyz <= hi)).all(axis=1))
    assert inside.size and np.isin(inside, ids).all() and ids.size < len(xyz)


@pytest.fixture
def full_disk(tmp_path):
    """A 256 KiB tmpfs (needs root and a mount that works here), unmounted after the test."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = tmp_path / "full"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    yield mount
    subprocess.run(["umount", str(mount)], check=True)


def _enospc(*args):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("method,tile", [("voxel", TILE), ("fps", None)])
def test_a_disk_too_small_for_the_coordinates_is_named_and_the_temporary_removed(tmp_path, monkeypatch, method, tile):
    paths, _ = _survey(tmp_path, n_files=1, n=500)
    monkeypatch.setattr(os, "posix_fallocate", _enospc)
    with pytest.raises(OSError, match="No space left") as err:
        survey.resample_files(paths, tmp_path / "kept", 0.2, method=method, tile=tile)
    assert err.value.errno == errno.ENOSPC and str(tmp_path / "kept") in str(err.value)
    assert os.listdir(tmp_path / "kept") == []


def test_without_posix_fallocate_the_coordinates_are_written_as_zeros_first(tmp_path, monkeypatch):
    paths, cloud = _survey(tmp_path, n_files=2, n=1000)
    monkeypatch.delattr(os, "posix_fallocate", raising=False)
    survey.resample_files(paths, tmp_path / "kept", 0.2, method="voxel")
    np.testing.assert_array_equal(_kept_ids(paths, tmp_path / "kept"),
                                  np.sort(hgjax.resample(cloud, 0.2, method="voxel")))
    assert not [f for f in os.listdir(tmp_path / "kept") if f.startswith(".")]


def test_cli_survey_on_a_full_disk_exits_1_naming_it(tmp_path, full_disk):
    path = tmp_path / "cloud.ply"
    io.write_points(path, np.random.default_rng(0).random((40_000, 3)) * 10)
    run = subprocess.run([sys.executable, "-m", "hgjax", "resample", str(path), "-o", str(full_disk), "--tile", "5",
                          "--method", "voxel", "--ratio", "0.1", "--quiet"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stderr
    assert "No space left" in run.stderr and str(full_disk) in run.stderr
    assert os.listdir(full_disk) == []
