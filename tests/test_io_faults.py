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


@pytest.mark.parametrize("text, line, found, before", [("1 2 3\n4 5 6 7\n", 2, 4, 3),
                                                       ("x y z\n1 2 3\n\n# note\n4 5 6\n7 8\n", 6, 2, 3)])
def test_a_text_row_of_another_width_is_reported_on_its_line(tmp_path, text, line, found, before):
    path = tmp_path / "ragged.xyz"
    path.write_text(text)
    message = _refused(path, f"line {line} has {found} values where the lines before it have {before}")
    assert "usecols" not in message and "at row" not in message


def test_an_extension_hgjax_does_not_read_is_named_with_those_it_reads(tmp_path):
    path = tmp_path / "scan.foo"
    path.write_text("1 2 3\n")
    message = _refused(path, "hgjax does not read .foo files; give one of .ply, .xyz, .txt, .npy, .pcd, .las, .laz")
    assert ".obj" in message and "NotImplementedError" not in message
    bare = tmp_path / "scan"
    bare.write_text("1 2 3\n")
    _refused(bare, "hgjax does not read files without an extension")


# ------------------------------------------------------------------ PLY, NPY, PCD, STL, LAS

def test_a_ply_without_its_ply_line_is_not_a_ply_file(tmp_path):
    path = tmp_path / "garbage.ply"
    path.write_text("garbage\n1 2 3\n")
    _refused(path, "not a PLY file (its first line is not `ply`)")


@pytest.mark.parametrize("lines, says", [
    ({"FIELDS": None}, "invalid PCD header: no FIELDS line"),
    ({"POINTS": None}, "invalid PCD header: no POINTS line"),
    ({"SIZE": "SIZE 4 4 four"}, "invalid PCD header: SIZE: 'four' is not a whole number"),
    ({"WIDTH": "WIDTH 2.5"}, "invalid PCD header: WIDTH: '2.5' is not a whole number"),
])
def test_a_pcd_header_fault_names_its_line(tmp_path, lines, says):
    pytest.importorskip("pypcd4")
    header = {"VERSION": "VERSION 0.7", "FIELDS": "FIELDS x y z", "SIZE": "SIZE 4 4 4", "TYPE": "TYPE F F F",
              "COUNT": "COUNT 1 1 1", "WIDTH": "WIDTH 2", "HEIGHT": "HEIGHT 1", "POINTS": "POINTS 2",
              "DATA": "DATA ascii"}
    header.update(lines)
    path = tmp_path / "bad.pcd"
    path.write_text("\n".join(line for line in header.values() if line) + "\n1 2 3\n4 5 6\n")
    message = _refused(path, says)
    assert "Field required" not in message and "invalid literal" not in message

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
