"""PLY point clouds: read exactly (every vertex property in its stored type), written ascii or binary.

A PLY that is not a plain point cloud (faces, list properties) is left to trimesh (:mod:`._mesh`).
"""

from __future__ import annotations

import warnings
from typing import BinaryIO, Callable

import numpy as np

from hgjax.io._columns import _flat_columns, _native_column, _savetxt
from hgjax.io._errors import PointCloudReadError
from hgjax.io._mesh import _read_trimesh

_PLY_SCALARS = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
                "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
                "int64": "i8", "uint64": "u8", "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


_PLY_ORDER = {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}


def _ply_layout(fh: BinaryIO) -> tuple[str, int, np.dtype, int] | None:
    """(format, vertex count, vertex dtype, header lines) of a PLY point cloud, ``fh`` (read past its
    ``ply`` line) left at its data.

    None when the file is something else this reader leaves to trimesh: a header without an end, a
    vertex property that is a list or of an unknown type, or another element with rows (faces:
    a mesh)."""
    fmt, elements, lines = None, [], 1
    for raw_line in iter(lambda: fh.readline(1 << 16), b""):
        lines += 1
        words = raw_line.decode("ascii", "replace").split()
        if words[:1] == ["end_header"]:
            break
        if words[:1] == ["format"] and len(words) >= 2:
            fmt = words[1]
        elif words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"] and elements:
            elements[-1][2].append(words[1:])
    else:
        return None
    vertex = [e for e in elements if e[0] == "vertex"]
    if fmt not in _PLY_ORDER or len(vertex) != 1 or any(count for name, count, _ in elements if name != "vertex"):
        return None
    _, n, properties = vertex[0]
    if not properties or any(len(p) != 2 or p[0] not in _PLY_SCALARS for p in properties):
        return None
    order = _PLY_ORDER[fmt]
    return fmt, n, np.dtype([(name, order + _PLY_SCALARS[kind]) for kind, name in properties]), lines


def _read_ply(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], None, bool]:
    """A PLY point cloud read exactly (every vertex property in its stored type, the vertex
    count checked against the header); meshes and other PLY files through trimesh."""
    with open(path, "rb") as fh:
        if fh.readline().strip() != b"ply":
            raise PointCloudReadError(f"cannot read {path}: not a PLY file (its first line is not `ply`)")
        layout = _ply_layout(fh)
        if layout is None:
            return _read_trimesh(path, samples, seed)
        fmt, n, row, lines = layout
        if fmt != "ascii":
            data = fh.read(n * row.itemsize)
            if len(data) < n * row.itemsize:
                raise PointCloudReadError(f"cannot read {path}: binary PLY data is truncated (its header announces {n}"
                                          f" vertices of {row.itemsize} bytes; the file holds {len(data)} bytes)")
            table = np.frombuffer(data, row)
    if fmt == "ascii":
        with open(path, encoding="ascii", errors="replace") as fh:
            for _ in range(lines):
                next(fh)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # np.loadtxt warns on a body without rows
                table = np.loadtxt(fh, dtype=row, max_rows=n, ndmin=1, comments=None)
        if table.shape[0] < n:
            raise PointCloudReadError(f"cannot read {path}: ascii PLY data is truncated (its header announces {n}"
                                      f" vertices; the file holds {table.shape[0]} rows)")
    return {name: table[name].astype(table.dtype[name].newbyteorder("=")) for name in row.names}, None, False


_PLY_TYPES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
              "i8": "int64", "u8": "uint64", "f4": "float", "f8": "double"}


def _ply_column(values: np.ndarray) -> np.ndarray:
    """A column in a dtype PLY can store: 64-bit integers become int32 when they fit (every PLY
    reader knows ``int``), else stay 64-bit (``int64``/``uint64``, as trimesh and hgjax read them)."""
    values = _native_column(values)
    if values.dtype.kind in "iu" and values.dtype.itemsize == 8:
        info = np.iinfo(np.int32)
        if values.size == 0 or (values.min() >= info.min and values.max() <= info.max):
            return values.astype(np.int32)
    return values


def _ply_writer(points, attributes, header, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
    columns = _flat_columns(points, attributes, column=_ply_column)
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "comment written by hgjax",
              f"element vertex {points.shape[0]}"]
    header += [f"property {_PLY_TYPES[col.dtype.str[1:]]} {name}" for name, col in columns]
    header = ("\n".join(header) + "\nend_header\n").encode("ascii")

    def write(fh: BinaryIO) -> None:
        fh.write(header)
        if binary:
            row = np.dtype([(name, col.dtype.newbyteorder("<")) for name, col in columns])
            table = np.empty(points.shape[0], row)
            for name, col in columns:
                table[name] = col
            fh.write(table.tobytes())
        else:
            _savetxt(fh, columns)

    return write
