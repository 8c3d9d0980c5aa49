"""hgjax.io: each file is read right or refused naming the file and
the fault; never a silently short read or a lossy round trip."""

import struct

import numpy as np
import pytest

from hgjax import io

BIG = np.array([2**60 + 1, 2**53 + 1, -(2**62) - 3, 7], dtype=np.int64)  # float64 would round the first three


def _refused(path, *words):
    with pytest.raises(io.PointCloudReadError) as err:
        io.read_points(path)
    assert str(path) in str(err.value)
    for word in words:
        assert word in str(err.value), str(err.value)
    return str(err.value)


# ------------------------------------------------------------------ XYZ / TXT

def test_xyz_first_row_with_an_inline_comment_is_a_row(tmp_path):
    path = tmp_path / "inline.xyz"
    path.write_text("1 2 3 # first row\n4 5 6 // second\n7 8 9\n")
    np.testing.assert_array_equal(io.read_points(path).points, [[1, 2, 3], [4, 5, 6], [7, 8, 9]])


def test_xyz_with_a_byte_order_mark_keeps_its_first_row(tmp_path):
    path = tmp_path / "bom.xyz"
    path.write_bytes(b"\xef\xbb\xbf" + b"1 2 3\n4 5 6\n")
    np.testing.assert_array_equal(io.read_points(path).points, [[1, 2, 3], [4, 5, 6]])
    path.write_bytes(b"\xef\xbb\xbf" + b"x y z i\n1 2 3 4.5\n")
    assert io.read_points(path).attributes["i"].tolist() == [4.5]


def test_xyz_with_a_non_utf8_byte_in_a_comment_reads(tmp_path):
    path = tmp_path / "latin1.xyz"
    path.write_bytes(b"# scanned at the caf\xe9\n1 2 3\n4 5 6\n")
    np.testing.assert_array_equal(io.read_points(path).points, [[1, 2, 3], [4, 5, 6]])


def test_comma_separated_xyz_after_a_comment_without_commas(tmp_path):
    path = tmp_path / "comma.xyz"
    path.write_text("# exported by a scanner\n1,2,3,10\n4,5,6,11\n")
    data = io.read_points(path)
    np.testing.assert_array_equal(data.points, [[1, 2, 3], [4, 5, 6]])
    assert data.attributes["column_3"].tolist() == [10, 11]


def test_a_repeated_column_name_is_refused(tmp_path):
    path = tmp_path / "repeated.xyz"
    path.write_text("x y z x\n1 2 3 9\n4 5 6 9\n")
    _refused(path, "'x' twice", "columns 1 and 4")


# ------------------------------------------------------------------ PLY, NPY, PCD, STL, LAS

def test_ascii_ply_with_fewer_rows_than_its_header_is_refused(tmp_path):
    path = tmp_path / "short.ply"
    header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    path.write_text(header + "1 2 3\n4 5 6\n")
    _refused(path, "truncated", "announces 3", "2 rows")


def test_binary_ply_with_fewer_rows_than_its_header_is_refused(tmp_path):
    path = tmp_path / "short.ply"
    io.write_points(path, np.eye(3))
    path.write_bytes(path.read_bytes()[:-5])
    _refused(path, "truncated", "announces 3")


def test_a_3d_npy_is_refused(tmp_path):
    path = tmp_path / "cube.npy"
    np.save(path, np.zeros((4, 3, 3)))
    _refused(path, "(4, 3, 3)")


def test_binary_pcd_with_pcl_padding_reads(tmp_path):
    """PCL pads rows with fields named ``_``; pypcd4 renames them at random at every parse."""
    header = ("VERSION 0.7\nFIELDS x y z _ intensity\nSIZE 4 4 4 1 4\nTYPE F F F U F\nCOUNT 1 1 1 4 1\nWIDTH 2\n"
              "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary\n")
    rows = b"".join(struct.pack("<fff4xf", *row) for row in [(1, 2, 3, 7), (4, 5, 6, 8)])
    path = tmp_path / "padded.pcd"
    path.write_bytes(header.encode() + rows)
    data = io.read_points(path)
    np.testing.assert_array_equal(data.points, [[1, 2, 3], [4, 5, 6]])
    assert set(data.attributes) == {"intensity"} and data.attributes["intensity"].tolist() == [7, 8]


@pytest.mark.parametrize("ext, options", [(".ply", {}), (".ply", {"binary": False}), (".xyz", {}), (".txt", {}),
                                          (".npy", {}), (".pcd", {}), (".pcd", {"binary": False}), (".las", {}),
                                          (".laz", {})])
def test_64_bit_integers_round_trip_exactly(tmp_path, ext, options):
    path = tmp_path / f"ids{ext}"
    unsigned = np.array([2**64 - 1, 2**53 + 1, 0, 5], dtype=np.uint64)
    io.write_points(path, np.arange(12.0).reshape(4, 3), attributes={"id": BIG, "uid": unsigned}, **options)
    back = io.read_points(path).attributes
    for name, want in (("id", BIG), ("uid", unsigned)):
        assert back[name].dtype == want.dtype, (name, back[name].dtype)
        np.testing.assert_array_equal(back[name], want)


def test_xyz_integer_columns_stay_integers_and_float_ones_floats(tmp_path):
    path = tmp_path / "mixed.xyz"
    path.write_text("x y z id w\n0 0 0 9007199254740993 1.0\n1 1 1 -4 2.0\n")
    data = io.read_points(path)
    assert data.attributes["id"].dtype == np.int64 and data.attributes["id"].tolist() == [2**53 + 1, -4]
    assert data.attributes["w"].dtype == np.float64


def test_truncated_binary_stl_says_so(tmp_path):
    import trimesh

    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    path.write_bytes(path.read_bytes()[:-30])
    _refused(path, "truncated or corrupt binary STL", "12 triangles")


def test_las_truncated_mid_record_says_so(tmp_path):
    pytest.importorskip("laspy")
    path = tmp_path / "cut.las"
    io.write_points(path, np.random.default_rng(0).random((100, 3)))
    path.write_bytes(path.read_bytes()[:-7])  # the last record loses 7 of its bytes
    message = _refused(path, "truncated", "it holds 99 points and 23 bytes of one more", "announces 100")
    assert "multiple of element size" not in message
    with pytest.raises(io.PointCloudReadError, match="truncated"):
        list(io.chunks(path))


def test_laz_truncated_says_so(tmp_path):
    pytest.importorskip("laspy")
    path = tmp_path / "cut.laz"
    io.write_points(path, np.random.default_rng(0).random((1000, 3)))
    path.write_bytes(path.read_bytes()[:-100])
    _refused(path, "truncated or corrupt")
    with pytest.raises(io.PointCloudReadError, match="truncated or corrupt"):
        list(io.chunks(path))
