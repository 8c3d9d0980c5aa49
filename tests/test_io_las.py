"""hgjax.io with LAS/LAZ: files built by laspy round-trip bit-exact through read, subset, write."""

import pathlib

import numpy as np
import pytest

from hgjax import io

laspy = pytest.importorskip("laspy")
pytest.importorskip("lazrs")

SCAN = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scans" / "scan_lamppost.ply"

# (version, point format, extra dimensions): 1.2 without extra bytes, 1.4 with scalar,
# scaled and array extra dimensions.
LAYOUTS = [
    ("1.2", 3, []),
    ("1.4", 6, [laspy.ExtraBytesParams("height", "f8")]),
    ("1.4", 7, [laspy.ExtraBytesParams("refl", "u2", scales=np.array([0.01]), offsets=np.array([5.0]))]),
    ("1.4", 8, [laspy.ExtraBytesParams("echo", "i4"), laspy.ExtraBytesParams("vec", "3f4")]),
]


def _make_las(path, version, point_format, extra, n=300, seed=0):
    """A LAS/LAZ file written by laspy, with UTM-like coordinates and random values in every dimension."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.add_extra_dims(extra)
    header.scales = np.array([0.001, 0.001, 0.01])
    header.offsets = np.array([500000.0, 4100000.0, -50.0])
    las = laspy.LasData(header, laspy.ScaleAwarePointRecord.zeros(n, header=header))
    las.X = rng.integers(-2**31, 2**31 - 1, n, dtype=np.int64).astype(np.int32)
    las.Y = rng.integers(0, 10**9, n).astype(np.int32)
    las.Z = rng.integers(-10**5, 10**5, n).astype(np.int32)
    for dim in las.point_format.dimensions:
        if dim.name in ("X", "Y", "Z"):
            continue
        shape = (n, dim.num_elements) if dim.num_elements > 1 else (n,)
        raw = las.points.array[dim.name] if dim.name in las.points.array.dtype.names else None
        if raw is not None and raw.dtype.kind == "f":
            las[dim.name] = rng.normal(0, 1e5, shape).astype(raw.dtype)
        elif dim.name in las.point_format.extra_dimension_names and dim.scales is not None:
            las.points.array[dim.name] = rng.integers(0, 2**16, n, dtype=np.uint16)
        else:
            las[dim.name] = rng.integers(int(dim.min), int(dim.max) + 1, shape)
    las.write(path)
    return laspy.read(path)


@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize("version, point_format, extra", LAYOUTS, ids=lambda v: str(v) if not isinstance(v, list)
                         else ",".join(e.name for e in v) or "no-extra")
def test_read_subset_write_is_bit_exact(tmp_path, ext, version, point_format, extra):
    src_path = tmp_path / f"in{ext}"
    original = _make_las(src_path, version, point_format, extra)
    before = src_path.read_bytes()
    data = io.read_points(src_path)
    assert src_path.read_bytes() == before  # the input is never modified

    # Coordinates are the real float64 values X * scale + offset, with no precision lost.
    assert data.points.dtype == np.float64
    assert data.points[:, 0].min() > 4e5 - 3e6 and 4.1e6 <= data.points[:, 1].min()
    for i, axis in enumerate("XYZ"):
        raw = original.points.array[axis].astype(np.float64)
        np.testing.assert_array_equal(data.points[:, i], raw * original.header.scales[i] + original.header.offsets[i])
    # Every dimension is an attribute, in its stored dtype; RGB as 16-bit colours.
    names = [d for d in original.point_format.dimension_names if d not in ("X", "Y", "Z", "red", "green", "blue")]
    assert set(data.attributes) == set(names) | ({"colors"} if "red" in original.point_format.dimension_names else set())
    for name in names:
        np.testing.assert_array_equal(data.attributes[name], np.asarray(original[name]))
    if "colors" in data.attributes:
        assert data.attributes["colors"].dtype == np.uint16
        np.testing.assert_array_equal(data.attributes["colors"][:, 2], original.blue)

    keep = np.random.default_rng(1).permutation(len(data))[:120]
    kept = data.subset(keep)
    out = tmp_path / f"out{ext}"
    io.write_points(out, kept.points, attributes=kept.attributes, header=kept.header)
    back = laspy.read(out)
    assert back.header.version == original.header.version
    assert back.header.point_format == original.header.point_format  # same id and extra dimensions
    np.testing.assert_array_equal(back.header.scales, original.header.scales)
    np.testing.assert_array_equal(back.header.offsets, original.header.offsets)
    assert back.header.point_count == keep.size
    assert back.points.array.dtype == original.points.array.dtype
    assert back.points.array.tobytes() == original.points.array[keep].tobytes()  # every byte of every point
    np.testing.assert_array_equal(back.header.mins, np.min(np.stack([back.x, back.y, back.z], 1), axis=0))
    assert kept.header.point_count == original.header.point_count  # the header passed in is not modified


def test_attributes_added_to_a_las_subset_become_extra_dimensions(tmp_path):
    _make_las(tmp_path / "in.laz", "1.2", 3, [])
    data = io.read_points(tmp_path / "in.laz", samples=50, seed=2)
    score = np.linspace(0, 1, 50)
    io.write_points(tmp_path / "out.laz", data.points, attributes=data.attributes, scores=score,
                    header=data.header)
    back = io.read_points(tmp_path / "out.laz")
    np.testing.assert_array_equal(back.attributes["score"], score)
    described = {d.name: d.description for d in back.header.point_format.extra_dimensions}
    assert described["score"] == "hgjax resampling score"
    np.testing.assert_array_equal(back.attributes["gps_time"], data.attributes["gps_time"])
    np.testing.assert_array_equal(back.points, data.points)
    assert back.header.point_format.id == 3 and str(back.header.version) == "1.2"


def test_values_that_do_not_fit_a_las_dimension_are_refused(tmp_path):
    pts = np.random.default_rng(0).random((4, 3))
    with pytest.raises(ValueError, match="'intensity'.*does not fit"):
        io.write_points(tmp_path / "a.las", pts, attributes={"intensity": np.array([0.5, 1.0, 2.0, 3.0])})
    with pytest.raises(ValueError, match="'return_number' does not fit"):
        io.write_points(tmp_path / "a.las", pts, attributes={"return_number": np.array([1, 2, 3, 16])})
    with pytest.raises(ValueError, match=r"'gps_time' \(int64\) does not fit LAS dimension 'gps_time' \(float64\)"):
        io.write_points(tmp_path / "a.las", pts, attributes={"gps_time": np.array([0, 1, 2**53, 2**53 + 1])})
    with pytest.raises(ValueError, match=r"'gps_time' \(uint64\) does not fit"):
        io.write_points(tmp_path / "a.las", pts, attributes={"gps_time": np.array([0, 1, 2, 2**64 - 1], np.uint64)})
    exact = np.array([-2**60, 7, 2**53, 2**62], np.int64)  # integers a float64 holds exactly are written
    io.write_points(tmp_path / "exact.las", pts, attributes={"gps_time": exact})
    assert io.read_points(tmp_path / "exact.las").attributes["gps_time"].tolist() == exact.tolist()
    (tmp_path / "exact.las").unlink()
    _make_las(tmp_path / "in.las", "1.2", 3, [])
    data = io.read_points(tmp_path / "in.las")
    with pytest.raises(ValueError, match="coordinates do not fit"):
        io.write_points(tmp_path / "b.las", data.points + 1e7, header=data.header)
    with pytest.raises(TypeError, match="laspy.LasHeader"):
        io.write_points(tmp_path / "b.las", data.points, header={"scale": 0.01})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.las"]


def test_ply_scan_to_las_picks_format_scale_and_offset(tmp_path):
    src = io.read_points(SCAN)
    src = io.PointData(src.points + [500000.0, 4100000.0, 0.0], {
        **src.attributes, "intensity": np.arange(len(src), dtype=np.uint16),
        "colors": np.random.default_rng(0).integers(0, 256, (len(src), 3), dtype=np.uint8)})
    out = tmp_path / "scan.laz"
    io.write_points(out, src.points, attributes=src.attributes)
    header = laspy.read(out).header
    assert header.point_format.id == 7 and str(header.version) == "1.4"
    np.testing.assert_array_equal(header.offsets, np.floor(src.points.min(axis=0)))
    span = (src.points - np.floor(src.points.min(axis=0))).max()
    assert 1e-3 <= span < 1e4  # so the documented scale is 1e-6 of it, rounded down to a power of ten
    assert header.scales.tolist() == [float(f"1e{int(np.floor(np.log10(span))) - 6}")] * 3
    back = io.read_points(out)
    np.testing.assert_allclose(back.points, src.points, rtol=0, atol=header.scales[0] / 2 * (1 + 1e-9))
    np.testing.assert_array_equal(back.attributes["intensity"], src.attributes["intensity"])
    np.testing.assert_array_equal(back.attributes["colors"], src.attributes["colors"].astype(np.uint16) * 257)
    io.write_points(tmp_path / "scan.ply", back.points, attributes={"colors": back.attributes["colors"]})
    np.testing.assert_array_equal(io.read_points(tmp_path / "scan.ply").attributes["colors"], src.attributes["colors"])


def test_las_scale_rule():
    assert io._las._las_scale(0.0) == 0.001
    assert io._las._las_scale(1.5) == 1e-6
    assert io._las._las_scale(950.0) == 1e-4
    assert io._las._las_scale(20000.0) == 1e-3  # at most 1 mm
    assert io._las._las_scale(5e7) == 0.1  # coarser only when int32 would overflow
    assert 5e7 / io._las._las_scale(5e7) < 2**31 - 1


def test_missing_las_packages_name_the_extra(tmp_path, monkeypatch):
    _make_las(tmp_path / "in.las", "1.2", 3, [])
    monkeypatch.setitem(__import__("sys").modules, "lazrs", None)
    with pytest.raises(ImportError, match=r'pip install "\.\[las\]"'):
        io.read_points(tmp_path / "in.las")
    with pytest.raises(ImportError, match=r'pip install "\.\[las\]"'):
        io.check_writable(tmp_path / "out.laz")
    assert len(io.read_points(SCAN)) == 1771  # other formats do not need the extra


# ------------------------------------------------------------------ chunked reading: io.chunks, io.header_count

COPC = pathlib.Path(__file__).parent / "data" / "survey.copc.laz"  # written by tests/data/make_copc.py


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_chunks_cover_the_file_in_order(tmp_path, monkeypatch, ext):
    path = tmp_path / f"scan{ext}"
    _make_las(path, "1.4", 6, [], n=1000)
    want = io.read_points(path).points
    monkeypatch.setattr(io, "CHUNK_ROWS", 300)
    parts = list(io.chunks(path))
    assert [first for first, _ in parts] == [0, 300, 600, 900]
    np.testing.assert_array_equal(np.concatenate([xyz for _, xyz in parts]), want)
    assert io.header_count(path) == 1000


def test_chunks_of_other_formats_are_the_whole_file(tmp_path):
    path = tmp_path / "scan.xyz"
    io.write_points(path, np.eye(3))
    assert [(first, xyz.tolist()) for first, xyz in io.chunks(path)] == [(0, np.eye(3).tolist())]
    assert io.header_count(path) is None
    assert io.header_count(tmp_path / "missing.ply") is None  # no header to read: the file is not opened
    with pytest.raises(io.PointCloudNotFoundError, match="missing.las"):
        io.header_count(tmp_path / "missing.las")
    (tmp_path / "junk.las").write_bytes(b"not a las file")
    with pytest.raises(io.PointCloudReadError, match="junk.las"):
        io.header_count(tmp_path / "junk.las")


def test_copc_chunks_are_nodes_numbered_in_file_order(tmp_path):
    path = tmp_path / "octree.laz"  # a COPC file is known by its COPC info VLR, not by its name
    path.write_bytes(COPC.read_bytes())
    whole = io.read_points(path).points
    parts = list(io.chunks(path))
    assert sum(xyz.shape[0] for _, xyz in parts) == whole.shape[0] == io.header_count(path)
    for first, xyz in parts:
        np.testing.assert_array_equal(xyz, whole[first:first + xyz.shape[0]])
    lo, hi = whole.min(axis=0), (whole.min(axis=0) + whole.max(axis=0)) / 2
    inside = np.flatnonzero(((whole >= lo) & (whole <= hi)).all(axis=1))
    some = list(io.chunks(path, box=(lo, hi)))
    assert len(some) < len(parts)
    got = np.concatenate([np.arange(first, first + xyz.shape[0]) for first, xyz in some])
    assert set(inside.tolist()) <= set(got.tolist())  # every point in the box is in a node that meets it
