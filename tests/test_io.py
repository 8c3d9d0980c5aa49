"""hgjax.io: real files round-trip, PCD as PCL writes it, clear errors naming the file."""

import dataclasses
import os
import pathlib
import struct
import sys

import numpy as np
import pytest

from hgjax import io

DATA = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"
SCANS = sorted((DATA / "scans").glob("*.ply"))
MESHES = sorted(p for p in (DATA / "meshes").iterdir() if p.suffix != ".md")


# ------------------------------------------------------------------ PCD writer (the PCL spec)

def _pack_rgb(colors):
    c = colors.astype(np.uint32)
    return ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).view(np.float32)


def _lzf_compress(data: bytes) -> bytes:
    """A naive greedy LZF compressor (liblzf format) so the fixture has back references."""
    out, lit, i, n = bytearray(), bytearray(), 0, len(data)

    def flush():
        while lit:
            chunk = lit[:32]
            out.append(len(chunk) - 1)
            out.extend(chunk)
            del lit[:32]

    while i < n:
        best_len, best_off = 0, 0
        for off in range(1, min(i, 8192) + 1):
            length = 0
            while length < 264 and i + length < n and data[i - off + length] == data[i + length]:
                length += 1  # may overlap the output being written: LZF allows that
            if length > best_len:
                best_len, best_off = length, off
        if best_len >= 3:
            flush()
            length, off = best_len - 2, best_off - 1
            if length < 7:
                out.append((length << 5) | (off >> 8))
            else:
                out.append((7 << 5) | (off >> 8))
                out.append(length - 7)
            out.append(off & 0xFF)
            i += best_len
        else:
            lit.append(data[i])
            i += 1
    flush()
    return bytes(out)


def write_pcd(path, xyz, rgb, normals, intensity, data="ascii", width=None):
    n = xyz.shape[0]
    width = width or n
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        "FIELDS x y z rgb normal_x normal_y normal_z intensity\n"
        "SIZE 4 4 4 4 4 4 4 2\nTYPE F F F F F F F U\nCOUNT 1 1 1 1 1 1 1 1\n"
        f"WIDTH {width}\nHEIGHT {n // width}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    cols = [("x", "<f4", xyz[:, 0]), ("y", "<f4", xyz[:, 1]), ("z", "<f4", xyz[:, 2]),
            ("rgb", "<f4", _pack_rgb(rgb)), ("normal_x", "<f4", normals[:, 0]),
            ("normal_y", "<f4", normals[:, 1]), ("normal_z", "<f4", normals[:, 2]),
            ("intensity", "<u2", intensity)]
    with open(path, "wb") as fh:
        fh.write(header.encode())
        if data == "ascii":
            for i in range(n):
                fh.write((" ".join(repr(float(np.float32(c[i]))) if f == "<f4" else str(int(c[i]))
                                   for _, f, c in cols) + "\n").encode())
        elif data == "binary":
            table = np.empty(n, [(name, f) for name, f, _ in cols])
            for name, _, c in cols:
                table[name] = c
            fh.write(table.tobytes())
        else:  # binary_compressed: fields stored one after another, then LZF
            raw = b"".join(np.asarray(c, f).tobytes() for _, f, c in cols)
            packed = _lzf_compress(raw)
            fh.write(struct.pack("<II", len(packed), len(raw)) + packed)


@pytest.fixture
def pcd_cloud():
    rng = np.random.default_rng(1)
    n = 24
    xyz = rng.normal(size=(n, 3)).astype(np.float32)
    xyz[:, 2] = np.round(xyz[:, 2], 1)  # repeated bytes, so the compressor finds matches
    xyz[5] = np.nan  # an organised cloud's invalid points
    xyz[17, 1] = np.nan
    rgb = rng.integers(0, 256, size=(n, 3), dtype=np.uint8)
    normals = np.tile(np.float32([0, 0, 1]), (n, 1))
    intensity = rng.integers(0, 60000, size=n).astype(np.uint16)
    return xyz, rgb, normals, intensity


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_as_pcl_writes_it(tmp_path, pcd_cloud, data):
    xyz, rgb, normals, intensity = pcd_cloud
    path = tmp_path / f"cloud_{data}.pcd"
    write_pcd(path, xyz, rgb, normals, intensity, data=data, width=6)
    with pytest.warns(io.NonFinitePointsWarning, match="dropped 2 of 24 points"):
        got = io.read_points(path)
    ok = np.isfinite(xyz).all(1)
    np.testing.assert_array_equal(got.points, xyz[ok].astype(np.float64))
    np.testing.assert_array_equal(got.attributes["colors"], rgb[ok])
    np.testing.assert_array_equal(got.attributes["normals"], normals[ok])
    np.testing.assert_array_equal(got.attributes["intensity"], intensity[ok])
    assert got.attributes["intensity"].dtype == np.uint16


def test_pcd_errors_name_the_file(tmp_path, pcd_cloud):
    path = tmp_path / "trunc.pcd"
    write_pcd(path, *pcd_cloud, data="binary")
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(io.PointCloudReadError, match=f"{path}.*truncated"):
        io.read_points(path)
    path.write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nPOINTS 1\nDATA zip\n")
    with pytest.raises(io.PointCloudReadError, match=f"{path}: invalid PCD header: DATA: .*got 'zip'"):
        io.read_points(path)
    path.write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nPOINTS 3\nDATA ascii\n1 2 3\n")
    with pytest.raises(io.PointCloudReadError, match=f"{path}: ascii PCD data is truncated"):
        io.read_points(path)


def test_pcd_ascii_rgb_as_pcl_writes_it(tmp_path):
    """PCL writes the packed rgb float of an ascii file as the packed unsigned integer."""
    path = tmp_path / "pcl.pcd"
    path.write_bytes(b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb _\nSIZE 4 4 4 4 1\nTYPE F F F F U\n"
                     b"COUNT 1 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n"
                     b"0.5 1 2 4278255360 0\n3 4 5 4294967295 0\n")
    data = io.read_points(path)
    np.testing.assert_array_equal(data.points, [[0.5, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(data.attributes["colors"], [[0, 255, 0], [255, 255, 255]])
    assert set(data.attributes) == {"colors"}  # the "_" padding field is skipped


@pytest.mark.parametrize("binary, compressed, data", [(False, True, "ascii"), (True, False, "binary"),
                                                     (True, True, "binary_compressed")])
@pytest.mark.parametrize("alpha", [False, True], ids=["rgb", "rgba"])
def test_pcd_write_round_trip(tmp_path, binary, compressed, data, alpha):
    rng = np.random.default_rng(3)
    n, repeats = 100, 5  # each column repeats, so LZF compresses it
    pts = np.tile((rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-6, 6, (n, 1))).astype(np.float32), (repeats, 1))
    attributes = {
        "colors": rng.integers(0, 256, (n, 4 if alpha else 3), dtype=np.uint8),
        "normals": rng.normal(size=(n, 3)).astype(np.float32),
        "label": rng.integers(-2**40, 2**40, n),
        "intensity": rng.integers(0, 2**16, n, dtype=np.uint16),
        "feat": rng.normal(size=(n, 2)),
    }
    attributes = {name: np.tile(value, (repeats,) + (1,) * (value.ndim - 1)) for name, value in attributes.items()}
    n *= repeats
    before = {k: v.copy() for k, v in attributes.items()}
    path = tmp_path / "out.pcd"
    io.write_points(path, pts, attributes=attributes, scores=rng.random(n), binary=binary, compressed=compressed)
    assert f"DATA {data}\n".encode() in path.read_bytes()[:400]
    back = io.read_points(path)
    np.testing.assert_array_equal(back.points, pts)
    for name, value in attributes.items():
        np.testing.assert_array_equal(attributes[name], before[name])
        if name != "feat":
            np.testing.assert_array_equal(back.attributes[name], value)
            assert back.attributes[name].dtype == value.dtype
    np.testing.assert_array_equal(back.attributes["feat_1"], attributes["feat"][:, 1])
    header = path.read_bytes().split(b"DATA")[0].decode()
    assert ("FIELDS x y z rgba " if alpha else "FIELDS x y z rgb ") in header
    assert "normal_x normal_y normal_z" in header


# ------------------------------------------------------------------ real files

@pytest.mark.parametrize("path", SCANS, ids=lambda p: p.name)
@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
def test_scans_round_trip_with_colour(tmp_path, path, binary):
    src = io.read_points(path, samples=None if binary else 5000)  # ascii is slow: a subset
    assert src.points.dtype == np.float64 and np.isfinite(src.points).all()
    out = tmp_path / "out.ply"
    scores = np.linspace(0.0, 1.0, len(src))
    io.write_points(out, src.points, attributes=src.attributes, scores=scores, binary=binary)
    back = io.read_points(out)
    np.testing.assert_array_equal(back.points, src.points)
    assert set(back.attributes) == set(src.attributes) | {"score"}
    for name, value in src.attributes.items():
        np.testing.assert_array_equal(back.attributes[name], value)
    np.testing.assert_allclose(back.attributes["score"], scores, rtol=1e-7)


def test_scan_with_rgb_keeps_colour():
    data = io.read_points(DATA / "scans" / "scan_table_mug.ply", samples=1000)
    assert data.attributes["colors"].dtype == np.uint8
    assert data.attributes["colors"].shape == (1000, 4)
    assert len(np.unique(data.attributes["colors"][:, 0])) > 10  # real colours, not a default


@pytest.mark.parametrize("path", MESHES, ids=lambda p: p.name)
def test_every_shared_mesh_reads(path):
    data = io.read_points(path, samples=500, seed=3)
    assert data.points.shape == (500, 3) and np.isfinite(data.points).all()
    np.testing.assert_allclose(np.linalg.norm(data.attributes["normals"], axis=1), 1.0, atol=1e-6)
    assert np.ptp(data.points, axis=0).max() > 0
    np.testing.assert_array_equal(io.read_points(path, samples=500, seed=3).points, data.points)
    assert not np.array_equal(io.read_points(path, samples=500, seed=4).points, data.points)


def test_samples_on_a_point_cloud_takes_a_seeded_subset():
    path = DATA / "scans" / "scan_lamppost.ply"
    full = io.read_points(path)
    assert len(full) == 1771
    sub = io.read_points(path, samples=100, seed=7)
    assert len(sub) == 100
    rows = {tuple(p) for p in full.points}
    assert all(tuple(p) in rows for p in sub.points)
    np.testing.assert_array_equal(sub.points, io.read_points(path, samples=100, seed=7).points)
    assert len(io.read_points(path, samples=10**6)) == 1771


# ------------------------------------------------------------------ XYZ / NPY

def test_xyz_with_and_without_header(tmp_path):
    table = np.array([[0.0, 1.0, 2.0, 7.0], [3.0, 4.0, 5.0, 8.0]])
    plain = tmp_path / "plain.xyz"
    np.savetxt(plain, table)
    data = io.read_points(plain)
    np.testing.assert_array_equal(data.points, table[:, :3])
    np.testing.assert_array_equal(data.attributes["column_3"], table[:, 3])
    named = tmp_path / "named.txt"
    named.write_text("//X Y Z R G B\n0 0 0 255 0 10\n1 1 1 0 128 20\n")
    data = io.read_points(named)
    np.testing.assert_array_equal(data.attributes["colors"], [[255, 0, 10], [0, 128, 20]])
    csv = tmp_path / "c.txt"
    csv.write_text("x,y,z,label\n0,0,0,1\n1,2,3,0\n")
    np.testing.assert_array_equal(io.read_points(csv).attributes["label"], [1.0, 0.0])


def test_xyz_written_by_write_points_reads_back(tmp_path):
    pts = np.random.default_rng(0).random((5, 3))
    path = tmp_path / "k.xyz"
    io.write_points(path, pts, attributes={"normals": np.tile([0.0, 0.0, 1.0], (5, 1))},
                    scores=np.arange(5.0))
    back = io.read_points(path)
    np.testing.assert_allclose(back.points, pts, rtol=1e-8)
    np.testing.assert_array_equal(back.attributes["score"], np.arange(5.0))
    assert back.attributes["normals"].shape == (5, 3)


def test_npy_plain_and_structured(tmp_path):
    pts = np.arange(12.0).reshape(4, 3)
    np.save(tmp_path / "a.npy", pts)
    np.testing.assert_array_equal(io.read_points(tmp_path / "a.npy").points, pts)
    rec = np.zeros(3, [("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "i4")])
    rec["label"] = [1, 2, 3]
    np.save(tmp_path / "b.npy", rec)
    np.testing.assert_array_equal(io.read_points(tmp_path / "b.npy").attributes["label"], [1, 2, 3])


def test_nan_points_dropped_with_count(tmp_path):
    path = tmp_path / "nan.xyz"
    path.write_text("0 0 0\nnan 1 1\n1 1 1\n2 2 nan\n")
    with pytest.warns(io.NonFinitePointsWarning, match="dropped 2 of 4"):
        assert len(io.read_points(path)) == 2
    path.write_text("nan 0 0\n")
    with pytest.raises(io.PointCloudReadError, match="all 1 points"):
        io.read_points(path)


# ------------------------------------------------------------------ errors

BAD_FILES = {
    "empty.ply": b"",
    "text.ply": b"hello world\n",
    "noise.stl": bytes(range(256)) * 2,
    "noise.glb": bytes(range(256)) * 2,
    "two_columns.xyz": b"1 2\n3 4\n",
    "words.xyz": b"x y z\na b c\n",
    "only_comment.txt": b"# nothing here\n",
    "zero.ply": b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                b"property float z\nend_header\n",
    "pickle.npy": b"\x93NUMPY\x01\x00v\x00{'descr': '|O', 'fortran_order': False, 'shape': (1,), }" + b" " * 50
                  + b"\n",
    "nonsense.foo": b"abc",
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_unreadable_files_raise_one_clear_error(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(BAD_FILES[name])
    with pytest.raises(io.PointCloudReadError) as info:
        io.read_points(path)
    assert str(path) in str(info.value)


def test_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.ply: no such file"):
        io.read_points(tmp_path / "missing.ply")
    with pytest.raises(io.PointCloudReadError, match="directory"):
        io.read_points(tmp_path)


def test_write_points_validates_and_does_not_modify(tmp_path):
    pts = np.random.default_rng(0).random((4, 3)).astype(np.float32)
    before = pts.copy()
    with pytest.raises(ValueError, match="attribute 'label' must have shape"):
        io.write_points(tmp_path / "a.ply", pts, attributes={"label": np.zeros(3)})
    with pytest.raises(ValueError, match="hgjax does not write .obj files; give one of .ply,"
                                         " .xyz, .txt, .npy, .pcd, .las, .laz"):
        io.write_points(tmp_path / "a.obj", pts)
    with pytest.raises(ValueError, match=r"attributes\['colors'\] must have shape"):
        io.write_points(tmp_path / "a.ply", pts, attributes={"colors": np.zeros((4, 2))})
    io.write_points(tmp_path / "a.ply", pts, attributes={"label": np.arange(4, dtype=np.int64),
                                                          "feat": np.ones((4, 2))})
    np.testing.assert_array_equal(pts, before)
    back = io.read_points(tmp_path / "a.ply")
    np.testing.assert_array_equal(back.points, pts)
    np.testing.assert_array_equal(back.attributes["label"], np.arange(4))
    assert {"feat_0", "feat_1"} <= set(back.attributes)
    header = (tmp_path / "a.ply").read_bytes().split(b"end_header")[0].decode()
    assert "property float x" in header and "property int label" in header


def test_write_indices(tmp_path):
    io.write_indices(tmp_path / "i.npy", np.array([3, 1], dtype=np.int32))
    got = np.load(tmp_path / "i.npy")
    assert got.dtype == np.int64 and got.tolist() == [3, 1]
    with pytest.raises(ValueError, match=".npy"):
        io.write_indices(tmp_path / "i.txt", np.array([1]))
    with pytest.raises(TypeError, match="integer"):
        io.write_indices(tmp_path / "i.npy", np.array([1.0]))


# ------------------------------------------------------------------ output formats, atomic writes

@pytest.mark.parametrize("ext", [".ply", ".xyz", ".txt", ".npy", ".pcd"])
def test_every_format_round_trips_its_attributes(tmp_path, ext):
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(50, 3))
    attributes = {"colors": rng.integers(0, 256, (50, 3), dtype=np.uint8), "normals": rng.normal(size=(50, 3)),
                  "label": rng.integers(0, 9, 50).astype(np.int32)}
    io.write_points(tmp_path / f"out{ext}", pts, attributes=attributes, scores=rng.random(50))
    back = io.read_points(tmp_path / f"out{ext}")
    np.testing.assert_array_equal(back.points, pts)
    assert set(back.attributes) == {"colors", "normals", "label", "score"}
    for name, value in attributes.items():
        np.testing.assert_array_equal(back.attributes[name], value)


def test_write_onto_the_input_file(tmp_path):
    path = tmp_path / "cloud.ply"
    io.write_points(path, np.eye(3))
    data = io.read_points(path)
    io.write_points(path, data.points[:2], attributes={"score": np.array([1.0, 2.0])})
    np.testing.assert_array_equal(io.read_points(path).points, np.eye(3)[:2])
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.ply"]


def test_failed_write_leaves_the_target_untouched(tmp_path, monkeypatch):
    path = tmp_path / "cloud.ply"
    io.write_points(path, np.eye(3))
    before = path.read_bytes()

    def failing_writer(points, attributes, header, binary, compressed):
        def write(fh):
            fh.write(b"ply\nformat binary_little_endian 1.0\n")
            raise RuntimeError("disk on fire")
        return write

    monkeypatch.setitem(io._FORMATS, ".ply", dataclasses.replace(io._FORMATS[".ply"], write=failing_writer))
    with pytest.raises(RuntimeError, match="disk on fire"):
        io.write_points(path, np.ones((5, 3)))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.ply"]  # no temporary file left behind
    with pytest.raises(RuntimeError, match="disk on fire"):
        io.write_points(tmp_path / "new.ply", np.ones((5, 3)))
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.ply"]


def test_check_writable(tmp_path):
    assert io.check_writable(tmp_path / "a.LAZ") == str((tmp_path / "a.LAZ").resolve())
    with pytest.raises(io.PointCloudWriteError, match=f"cannot write {tmp_path / 'a.obj'}: hgjax does not write .obj files"):
        io.check_writable(tmp_path / "a.obj")
    with pytest.raises(ValueError, match=f"{tmp_path / 'missing' / 'a.ply'}: directory .*missing does not exist"):
        io.check_writable(tmp_path / "missing" / "a.ply")
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(io.PointCloudWriteError, match="d.ply: it is a directory"):
        io.check_writable(tmp_path / "d.ply")
    with pytest.raises(io.PointCloudWriteError, match="does not write .obj files"):
        io.write_points(tmp_path / "missing" / "a.obj", np.eye(3))  # checked before anything else
    with pytest.raises(io.PointCloudWriteError, match="it has no extension to choose the format by; give one of"):
        io.check_writable(tmp_path / "a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.ply"]


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root may write anywhere")
def test_check_writable_refuses_read_only_places(tmp_path):
    target = tmp_path / "ro.ply"
    target.write_bytes(b"")
    target.chmod(0o444)
    with pytest.raises(io.PointCloudWriteError, match="ro.ply: the file is read-only"):
        io.check_writable(target)
    tmp_path.chmod(0o555)
    try:
        with pytest.raises(io.PointCloudWriteError, match="is not writable"):
            io.check_writable(tmp_path / "new.ply")
    finally:
        tmp_path.chmod(0o755)


def test_pcd_needs_its_extra(tmp_path, monkeypatch, pcd_cloud):
    path = tmp_path / "c.pcd"
    write_pcd(path, *pcd_cloud, data="binary")
    monkeypatch.setitem(sys.modules, "pypcd4", None)
    with pytest.raises(ImportError, match=r'reading .*c.pcd needs the optional package .*pip install "\.\[pcd\]"'
                                          r' in the hgjax source folder'):
        io.read_points(path)
    with pytest.raises(ImportError, match=r'pip install "\.\[pcd\]"'):
        io.write_points(tmp_path / "d.pcd", np.eye(3))


# ------------------------------------------------------------------ every output is an input

def _cli(capsys, *args):
    from hgjax.cli import main

    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, err


@pytest.mark.usefixtures("cli_cache")
@pytest.mark.parametrize("ext", io.WRITE_EXTENSIONS)
def test_outputs_chain_through_every_command(capsys, tmp_path, ext):
    """resample -> score -> resample -> compare, each reading the file the previous one wrote."""
    import hgjax
    from fixtures import box_union

    if ext in (".las", ".laz"):
        pytest.importorskip("laspy")
    rng = np.random.default_rng(3)
    n = 400
    attributes = {"colors": rng.integers(0, 256, (n, 3), dtype=np.uint8),
                  "intensity": rng.integers(0, 2**16, n, dtype=np.uint16),
                  "id": rng.integers(2**53, 2**62, n, dtype=np.int64)}
    io.write_points(tmp_path / f"src{ext}", box_union(n) * 10.0, attributes=attributes)
    kept, scored, again = (tmp_path / f"{stem}{ext}" for stem in ("kept", "scored", "again"))
    code, err = _cli(capsys, "resample", tmp_path / f"src{ext}", "-o", kept, "--ratio", 0.5, "--dtype", "float64")
    assert code == 0, err
    code, err = _cli(capsys, "score", kept, "-o", scored, "--dtype", "float64")
    assert code == 0, err
    assert err.count("replaced by the new hkc score") == 1, err
    code, err = _cli(capsys, "resample", scored, "-o", again, "--ratio", 0.5, "--dtype", "float64")
    assert code == 0, err
    assert err.count("replaced by the new hkc score") == 1, err
    code, err = _cli(capsys, "compare", again, "--methods", "uniform", "--dtype", "float64")
    assert code == 0, err

    first, middle, last = (io.read_points(path) for path in (kept, scored, again))
    assert set(first.attributes) == set(middle.attributes) == set(last.attributes)
    assert {"colors", "intensity", "id", "score"} <= set(last.attributes)
    np.testing.assert_array_equal(middle.points, first.points)
    idx = np.sort(hgjax.resample(middle.points, 0.5, method="hkc"))
    np.testing.assert_array_equal(last.points, middle.points[idx])
    for name in ("colors", "intensity", "id"):
        assert last.attributes[name].dtype == middle.attributes[name].dtype, name
        np.testing.assert_array_equal(last.attributes[name], middle.attributes[name][idx])
    # the score of one cloud by one method, once written by `score` and once by `resample`
    np.testing.assert_allclose(last.attributes["score"], middle.attributes["score"][idx], rtol=1e-9)


@pytest.mark.usefixtures("cli_cache")
def test_a_plain_npy_stays_a_plain_npy(capsys, tmp_path):
    from fixtures import box_union

    points = box_union(300).astype(np.float32)
    np.save(tmp_path / "plain.npy", points)
    code, err = _cli(capsys, "resample", tmp_path / "plain.npy", "-o", tmp_path / "kept.npy", "--ratio", 0.5)
    assert code == 0, err
    assert err.count("without the score") == 1, err
    kept = np.load(tmp_path / "kept.npy")
    assert kept.dtype == np.float32 and kept.shape == (150, 3) and kept.dtype.names is None
    assert {tuple(p) for p in kept} <= {tuple(p) for p in points}
    code, err = _cli(capsys, "resample", tmp_path / "kept.npy", "-o", tmp_path / "again.npy", "--ratio", 0.5)
    assert code == 0, err
    assert np.load(tmp_path / "again.npy").shape == (75, 3)
    code, err = _cli(capsys, "score", tmp_path / "kept.npy", "-o", tmp_path / "scored.npy")
    assert code == 2 and "plain array" in err and "kept.npy" in err, err
    assert not (tmp_path / "scored.npy").exists()
    code, err = _cli(capsys, "score", tmp_path / "kept.npy", "-o", tmp_path / "scored.ply")
    assert code == 0, err
    assert io.read_points(tmp_path / "scored.ply").attributes["score"].shape == (150,)


def test_a_plain_npy_layout_writes_back_exactly(tmp_path):
    table = np.arange(20, dtype=np.int32).reshape(5, 4)
    np.save(tmp_path / "a.npy", table)
    data = io.read_points(tmp_path / "a.npy")
    assert data.header == np.dtype(np.int32) and not io.holds_scores("b.npy", header=data.header)
    kept = data.subset(np.array([4, 1]))
    io.write_points(tmp_path / "b.npy", kept.points, attributes=kept.attributes, header=kept.header,
                    scores=np.ones(2))  # a plain array has no column for the score: not written
    np.testing.assert_array_equal(np.load(tmp_path / "b.npy"), table[[4, 1]])
    assert np.load(tmp_path / "b.npy").dtype == np.int32
    io.write_points(tmp_path / "c.npy", kept.points + 0.5, attributes=kept.attributes, header=kept.header)
    np.testing.assert_array_equal(np.load(tmp_path / "c.npy")[:, :3], kept.points + 0.5)  # never rounded
    with pytest.raises(ValueError, match="'label' has no column in a plain .npy"):
        io.write_points(tmp_path / "d.npy", kept.points, attributes={"label": np.ones(2)}, header=kept.header)
    io.write_points(tmp_path / "e.ply", kept.points, attributes=kept.attributes, header=kept.header,
                    scores=np.ones(2))  # other formats ignore a plain array's layout
    assert io.read_points(tmp_path / "e.ply").attributes["score"].tolist() == [1.0, 1.0]
    io.write_points(tmp_path / "f.las", kept.points, attributes={}, header=kept.header)
    np.testing.assert_array_equal(io.read_points(tmp_path / "f.las").points, kept.points)


@pytest.mark.usefixtures("cli_cache")
def test_quoted_globs_are_expanded_and_each_file_read_once(capsys, tmp_path):
    from fixtures import box_union

    (tmp_path / "survey").mkdir()
    for name in ("b.xyz", "a.xyz", "c.ply"):
        io.write_points(tmp_path / "survey" / name, box_union(300))
    os.symlink(tmp_path / "survey" / "a.xyz", tmp_path / "link.xyz")
    code, err = _cli(capsys, "resample", tmp_path / "survey" / "*.xyz", tmp_path / "link.xyz", "-o", tmp_path / "out",
                     "--method", "uniform")
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "out")) == ["a.ply", "b.ply", "hgjax-manifest.json"]
    assert "link.xyz is" in err and "read once" in err
    code, err = _cli(capsys, "resample", tmp_path / "survey" / "*.laz", "-o", tmp_path / "none")
    assert code == 2 and "matches no point cloud" in err, err


@pytest.mark.parametrize("text, line", [("x y z\n1 2 abc\n3 4 5\n", 2), ("1 2 3\n1 2 abc\n", 2),
                                        ("# scan\nx y z\n1 2 3\n// note\n\n4 5 6  # inline\n1 2 abc\n", 7)])
def test_a_text_files_bad_value_is_reported_on_its_line(tmp_path, text, line):
    (tmp_path / "a.xyz").write_text(text)
    with pytest.raises(io.PointCloudReadError, match=f"a.xyz: line {line}, column 3: 'abc' is not a number$"):
        io.read_points(tmp_path / "a.xyz")


@pytest.mark.parametrize("ext", io.WRITE_EXTENSIONS)
def test_an_empty_cloud_is_written_and_named_when_read(tmp_path, ext):
    """Zero points (a file a survey keeps nothing of) make a valid file of the format; reading it says it holds none."""
    if ext in (".las", ".laz"):
        pytest.importorskip("laspy")
    if ext == ".pcd":
        pytest.importorskip("pypcd4")
    path = tmp_path / f"empty{ext}"
    io.write_points(path, np.zeros((0, 3)), scores=np.zeros(0), attributes={"intensity": np.zeros(0, np.uint16)})
    assert path.stat().st_size > 0
    assert io.header_count(path) in (0, None)
    with pytest.raises(io.PointCloudReadError, match="holds no points"):
        io.read_points(path)
    with pytest.raises(ValueError, match="points must have shape"):
        io.write_points(tmp_path / f"bad{ext}", np.zeros((0, 2)))
