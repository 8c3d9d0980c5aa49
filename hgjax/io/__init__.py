"""Reading and writing point clouds: PLY, XYZ/TXT, NPY, PCD, LAS/LAZ, and every mesh trimesh reads.

Host-side file IO for the command line and for scripts; nothing here is traced by JAX.

Readers, chosen by the file extension (case-insensitive):

- ``.ply`` point clouds: every vertex property is kept in its stored type (``red green blue
  [alpha]`` become ``colors``, ``nx ny nz`` become ``normals``, any other column keeps its
  name); a file holding fewer vertices than its header announces is refused.
- Meshes (``.ply`` with faces, ``.obj``, ``.stl``, ``.off``, ``.glb``, ``.gltf`` and the
  other formats trimesh loads): ``samples`` points (default 20000) are drawn uniformly on
  the surface with :func:`trimesh.sample.sample_surface`, seeded by ``seed``; the face
  normal of each sample is kept as ``normals``. Scenes are merged into one mesh.
- ``.xyz`` / ``.txt`` (UTF-8, with or without a byte-order mark; undecodable bytes in comments
  are ignored): whitespace- or comma-separated columns (the separator is that of the first
  data row), ``#`` and ``//`` start comments, inline ones too. A first line of names that
  include ``x y z`` (plain, or after ``#`` or ``//``) names the columns, each once;
  otherwise the first three columns are x, y, z and extra columns are kept as
  ``column_3``, ... A column other than x, y, z written as integers only (``255``, not
  ``255.0``) is read as int64 (uint64 beyond int64), exactly; the others as float64.
- ``.npy``: an (N, 3+) numeric array (extra columns as for XYZ; its dtype is kept as
  :attr:`PointData.header`, so that the points write back as the same plain array) or an
  (N,) structured array with fields ``x``, ``y``, ``z``.
- ``.pcd`` (PCL; needs the ``pcd`` extra): ``DATA ascii``, ``binary`` and
  ``binary_compressed``, read through pypcd4. A packed ``rgb``/``rgba`` field becomes
  ``colors`` (in ascii files it may be written as the packed float or, as PCL does, as
  the packed unsigned integer); ``normal_x`` ... become ``normals``; fields named ``_``
  (PCL's padding) are skipped; a field with COUNT C > 1 is kept as an (N, C) attribute.
- ``.stl``: ASCII or binary; a binary file whose size disagrees with its triangle count is
  refused as truncated or corrupt.
- ``.las`` / ``.laz`` (LAS 1.0-1.4, every point format; needs the ``las`` extra),
  read through laspy (LAZ through lazrs): ``points`` are the real coordinates
  X * scale + offset in float64 (exact for every int32 X), every other dimension of the
  point format and every extra dimension is an attribute under its laspy name in its
  stored dtype (``intensity``, ``return_number``, ``classification``, ``gps_time``,
  ``scan_angle`` or ``scan_angle_rank``, ...; scaled extra dimensions as float64), except
  ``red green blue``, which become ``colors`` (N, 3) uint16. The file's
  :class:`laspy.LasHeader` is kept as :attr:`PointData.header`. An uncompressed file
  holding fewer point records than its header announces is refused as truncated.

For an input that is already a point cloud, ``samples`` is ignored when it is None or at
least the number of points; when smaller it selects a seeded random subset (in file
order). Points with a NaN or inf coordinate are dropped with a :class:`NonFinitePointsWarning`
that says how many. Every failure raises :class:`PointCloudReadError` naming the file; a
missing optional package raises :class:`ImportError` naming the extra to install.

Writers (:func:`write_points`) cover the same point-cloud formats, chosen by the extension
(:data:`WRITE_EXTENSIONS`). Every write goes to a temporary file in the target's directory
that is then renamed onto the target, so an interrupted or failed write never leaves a
partial file and writing onto the file that was read never destroys it midway. Whatever is
written reads back with the same values (64-bit integer attributes stay integers).

Large files are read in parts by :func:`chunks` (LAS/LAZ :data:`CHUNK_ROWS` points at a
time, COPC one octree node at a time) and announce their size by :func:`header_count`.

Every format is one record of one table keyed by the extension: its reader, writer, chunk
reader, header count and optional extra; any other extension is read as a mesh by trimesh.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
import importlib
import math
import os
import re
import secrets
import socket
import warnings
from typing import Any, BinaryIO, Callable, Mapping

import numpy as np

__all__ = [
    "CHUNK_ROWS",
    "DEFAULT_SAMPLES",
    "NonFinitePointsWarning",
    "PointCloudNotFoundError",
    "PointCloudReadError",
    "PointCloudWriteError",
    "PointData",
    "WRITE_EXTENSIONS",
    "check_format",
    "check_writable",
    "chunks",
    "header_count",
    "holds_scores",
    "read_points",
    "remove_stale_temporaries",
    "write_indices",
    "write_points",
]

DEFAULT_SAMPLES = 20000
CHUNK_ROWS = 1 << 20
"""Points per chunk of :func:`chunks` on a LAS/LAZ file (and per batch of COPC nodes)."""

_COLOR_NAMES = (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"))
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_MODULES = {"las": ("laspy", "lazrs"), "pcd": ("pypcd4",)}


class PointCloudReadError(ValueError):
    """A file could not be read as a point cloud; the message names the file and the cause."""


class PointCloudNotFoundError(PointCloudReadError, FileNotFoundError):
    """The file to read does not exist (also a :class:`FileNotFoundError`)."""


class PointCloudWriteError(ValueError):
    """A point cloud cannot be written to a path; the message names the path and the cause."""


class NonFinitePointsWarning(UserWarning):
    """Points with NaN or inf coordinates were dropped while reading a file."""


@dataclasses.dataclass(frozen=True)
class PointData:
    """A point cloud read from a file, with its per-point attributes.

    Attributes:
      points: (N, 3) float64 coordinates, all finite.
      attributes: per-point arrays with leading axis N, by name: ``colors`` (N, 3) or
        (N, 4) uint8 ((N, 3) uint16 from LAS/LAZ), ``normals`` (N, 3) float, and any other
        column of the file.
      source: the file it was read from (None when built in memory).
      header: the source file's header when the format has one that :func:`write_points`
        needs to write the points back the same way: the :class:`laspy.LasHeader` of a
        LAS/LAZ file (point format, version, scale, offset, extra dimensions, VLRs), the
        :class:`numpy.dtype` of a plain (N, 3 + C) .npy array (so that a .npy output is the
        same plain array); None for other formats.

    Examples:
      >>> import numpy as np
      >>> data = PointData(np.zeros((4, 3)), {"intensity": np.arange(4.0)})
      >>> data.subset(np.array([3, 1])).attributes["intensity"]
      array([3., 1.])
    """

    points: np.ndarray
    attributes: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)
    source: str | None = None
    header: Any = None

    def __len__(self) -> int:
        return self.points.shape[0]

    def subset(self, indices) -> "PointData":
        """The points at ``indices`` (M,) and their attributes, in that order.

        Args:
          indices: (M,) integer indices (or an (N,) boolean mask).

        Returns:
          A new :class:`PointData` of M points with the same source and header.

        Examples:
          >>> import numpy as np
          >>> PointData(np.eye(3)).subset(np.array([2])).points
          array([[0., 0., 1.]])
        """
        indices = np.asarray(indices)
        return PointData(self.points[indices], {k: v[indices] for k, v in self.attributes.items()},
                         self.source, self.header)


def _require(extra: str, what: str) -> tuple:
    """Import the optional packages of ``extra`` (e.g. laspy and lazrs for ``las``)."""
    from hgjax import _validate

    try:
        return tuple(importlib.import_module(name) for name in _MODULES[extra])
    except ImportError as err:
        raise ImportError(f"{what} needs the optional package {err.name!r}: {_validate.install_hint(extra)}") from err


# ----------------------------------------------------------------------------- reading


def read_points(path, *, samples: int | None = None, seed: int = 0) -> PointData:
    """Read a point cloud, or sample one from a mesh, from a file.

    Args:
      path: file path; the format comes from the extension (see the module docstring).
        The file is never modified.
      samples: for meshes, the number of surface samples (default 20000); for point
        clouds, a seeded random subset of this size when smaller than the cloud (default
        None: all points).
      seed: integer seed of the surface sampling or the subset (default 0).

    Returns:
      :class:`PointData` with (N, 3) float64 finite points, per-point attributes and, for
      LAS/LAZ, the file's header.

    Raises:
      PointCloudNotFoundError: the file does not exist.
      PointCloudReadError: the file is empty, cannot be parsed, or holds no finite point.
      ImportError: the optional package for the format (PCD, LAS/LAZ) is not installed.
      TypeError, ValueError: ``samples`` or ``seed`` is not a valid integer.

    Warns:
      NonFinitePointsWarning: points with NaN or inf coordinates were dropped.

    Examples:
      >>> import os, tempfile, numpy as np
      >>> path = os.path.join(tempfile.mkdtemp(), "cloud.xyz")
      >>> np.savetxt(path, [[0, 0, 0, 5], [1, 0, 0, 6]], header="x y z intensity")
      >>> data = read_points(path)
      >>> data.points.shape, data.attributes["intensity"].tolist()
      ((2, 3), [5.0, 6.0])
    """
    from hgjax import _validate

    if samples is not None:
        samples = _validate.check_int(samples, "samples", minimum=1)
    seed = _validate.check_int(seed, "seed", minimum=0)
    path = os.fspath(path)
    if not os.path.exists(path):
        raise PointCloudNotFoundError(f"cannot read {path}: no such file")
    if os.path.isdir(path):
        raise PointCloudReadError(f"cannot read {path}: it is a directory")
    if os.path.getsize(path) == 0:
        raise PointCloudReadError(f"cannot read {path}: the file is empty")
    fmt = _format(path)
    if fmt.extra is not None:
        _require(fmt.extra, f"reading {path}")
    try:
        columns, header, is_mesh = fmt.read(path, samples or DEFAULT_SAMPLES, seed)
    except PointCloudReadError:
        raise
    except Exception as err:  # any parser failure becomes one clear error naming the file
        raise PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err
    data = _to_point_data(columns, path, header)
    if not is_mesh and samples is not None and samples < len(data):
        keep = np.sort(np.random.default_rng(seed).choice(len(data), samples, replace=False))
        data = data.subset(keep)
    return data


def _to_point_data(columns: dict[str, np.ndarray], path: str, header: Any) -> PointData:
    """Group named (N,) columns into points, colors, normals and the remaining attributes."""
    for c in "xyz":
        named = [name for name in columns if name.lower() == c]
        if len(named) > 1:
            raise PointCloudReadError(f"cannot read {path}: the columns {' and '.join(map(repr, named))} both name"
                                      f" the {c} coordinate")
    names = {name.lower(): name for name in columns}
    if not all(c in names for c in "xyz"):
        raise PointCloudReadError(f"cannot read {path}: no x, y, z columns (found {sorted(columns)})")
    points = np.stack([np.asarray(columns.pop(names[c]), np.float64) for c in "xyz"], axis=1)
    attributes: dict[str, np.ndarray] = {}
    for group in _COLOR_NAMES:
        present = [names[c] for c in group if c in names and names[c] in columns]
        if len(present) >= 3 and present[:3] == [names[c] for c in group[:3]]:
            attributes["colors"] = _as_uint8(np.stack([columns.pop(c) for c in present], axis=1))
            break
    for group in _NORMAL_NAMES:
        if all(c in names and names[c] in columns for c in group):
            attributes["normals"] = np.stack([columns.pop(names[c]) for c in group], axis=1)
            break
    attributes.update(columns)
    if points.shape[0] == 0:
        raise PointCloudReadError(f"cannot read {path}: the file holds no points")
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        n_bad = int((~finite).sum())
        if not finite.any():
            raise PointCloudReadError(f"cannot read {path}: all {n_bad} points have NaN or inf coordinates")
        warnings.warn(f"{path}: dropped {n_bad} of {points.shape[0]} points with NaN or inf coordinates",
                      NonFinitePointsWarning, stacklevel=3)
        points = points[finite]
        attributes = {k: v[finite] for k, v in attributes.items()}
    return PointData(points, attributes, path, header)


def _as_uint8(values: np.ndarray) -> np.ndarray:
    """Colours (N, C) as uint8: floats in [0, 1] are scaled by 255, integers above 255 (16-bit
    colour, as in LAS) by 255 / 65535."""
    values = np.asarray(values)
    if values.dtype.kind == "f":
        scale = 255.0 if values.size and np.nanmax(values) <= 1.0 else 1.0
        values = np.rint(np.nan_to_num(values) * scale)
    elif values.dtype.kind in "iu" and values.size and values.max() > 255:
        values = np.rint(values / 257.0)
    return np.clip(values, 0, 255).astype(np.uint8)


def _as_uint16(values: np.ndarray) -> np.ndarray:
    """Colours (N, C) as LAS's 16-bit channels: uint16 is kept, 8-bit colour is scaled by 257."""
    values = np.asarray(values)
    if values.dtype == np.uint16:
        return values
    return _as_uint8(values).astype(np.uint16) * np.uint16(257)


def _read_trimesh(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], None, bool]:
    """(columns, no header, whether they are samples of a mesh) of any file trimesh loads."""
    import trimesh

    geometry = trimesh.load(path)
    if isinstance(geometry, trimesh.Scene):
        if not geometry.geometry:
            raise PointCloudReadError(f"cannot read {path}: no mesh or points found")
        geometry = trimesh.load(path, force="mesh")
    if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces) > 0:
        samples_xyz, face = trimesh.sample.sample_surface(geometry, samples, seed=seed)
        columns = dict(zip("xyz", np.asarray(samples_xyz, np.float64).T))
        columns.update(zip(("nx", "ny", "nz"), np.asarray(geometry.face_normals[face]).T))
        return columns, None, True
    raw = getattr(geometry, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
    if raw is not None:  # PLY point cloud: keep every vertex property (ascii gives a dict)
        names = raw.dtype.names if isinstance(raw, np.ndarray) else tuple(raw)
        return {name: np.asarray(raw[name]).reshape(len(raw[name]), -1).squeeze(1) for name in names}, None, False
    vertices = np.asarray(getattr(geometry, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    columns = dict(zip("xyz", vertices.T))
    colors = np.asarray(getattr(geometry, "colors", ()))
    if colors.shape == (len(vertices), 4):
        columns.update(zip(("red", "green", "blue", "alpha"), colors.T))
    return columns, None, False


_PLY_SCALARS = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
                "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
                "int64": "i8", "uint64": "u8", "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_PLY_ORDER = {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}


def _ply_layout(fh: BinaryIO) -> tuple[str, int, np.dtype, int] | None:
    """(format, vertex count, vertex dtype, header lines) of a PLY point cloud, ``fh`` left at its data.

    None when the file is something else this reader leaves to trimesh: not a PLY header, a
    vertex property that is a list or of an unknown type, or another element with rows (faces:
    a mesh)."""
    if fh.readline().strip() != b"ply":
        return None
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


def _read_stl(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], None, bool]:
    """Surface samples of an STL mesh; a binary STL whose size disagrees with its triangle count is refused."""
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        head = fh.read(1024)
    announced = int.from_bytes(head[80:84], "little") if len(head) >= 84 else None
    binary = announced is not None and size == 84 + 50 * announced
    ascii_text = head.lstrip()[:5].lower() == b"solid" and b"\0" not in head and (b"facet" in head or size <= 1024)
    if not binary and not ascii_text:
        found = "" if announced is None else f": its header announces {announced} triangles ({84 + 50 * announced} bytes)"
        raise PointCloudReadError(f"cannot read {path}: truncated or corrupt binary STL{found}; the file holds"
                                  f" {size} bytes")
    return _read_trimesh(path, samples, seed)


_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.IGNORECASE)
_INLINE_COMMENT = re.compile(r"#|//")


def _text_layout(path: str) -> tuple[list[str] | None, int, str | None, list[str]]:
    """(column names or None, lines before the data, separator, first data row's values) of an XYZ/TXT file.

    The first line that is not blank may name the columns as a ``#``/``//`` comment; the first
    other line that holds no number is a header line (skipped; it names the columns when it
    holds ``x y z``); the separator is that of the first data row (``,`` when it has one),
    whatever the lines before it."""
    names, skip, first, header = None, 0, True, False
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for i, line in enumerate(fh):
            comment = line.lstrip().startswith(("#", "//"))
            body = line.lstrip().lstrip("#/") if comment else _INLINE_COMMENT.split(line, maxsplit=1)[0]
            tokens = body.replace(",", " ").split()
            if not tokens:
                continue
            named = {"x", "y", "z"} <= {t.lower() for t in tokens}
            if comment:
                names, first = tokens if first and named else names, False
                continue
            first = False
            if not header and not any(_NUMBER.match(t) for t in tokens):
                names, skip, header = tokens if named else names, i + 1, True
                continue
            return names, skip, "," if "," in body else None, tokens
    return names, skip, None, []


def _integer_columns(path: str, table: np.ndarray, columns: list[int], skip: int, delimiter) -> dict:
    """{column: int64 or uint64 values} of those of ``columns`` written as integers only, read exactly."""
    integral = [j for j in columns if np.isfinite(table[:, j]).all() and (table[:, j] == np.trunc(table[:, j])).all()]
    found = {}
    for dtype in (np.int64, np.uint64):
        for group in ([integral] if len(integral) > 1 else []) + [[j] for j in integral]:
            group = [j for j in group if j not in found]
            if not group:
                continue
            try:
                with open(path, encoding="utf-8-sig", errors="replace") as fh:
                    values = np.loadtxt(fh, comments=("#", "//"), delimiter=delimiter, ndmin=2, skiprows=skip,
                                        usecols=group, dtype=dtype)
            except (ValueError, OverflowError):  # a token such as 255.0 further down: a float column
                continue
            found.update((j, values[:, i]) for i, j in enumerate(group))
    return found


def _read_text(path: str, samples: int = 0, seed: int = 0) -> tuple[dict[str, np.ndarray], None, bool]:
    names, skip, delimiter, row = _text_layout(path)
    with open(path, encoding="utf-8-sig", errors="replace") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.loadtxt warns on files without data rows
        table = np.loadtxt(fh, comments=("#", "//"), delimiter=delimiter, ndmin=2, skiprows=skip)
    columns = _named_columns(table, names, path)
    written_as_integers = [j for j, name in enumerate(columns) if name.lower() not in ("x", "y", "z")
                           and j < len(row) and re.fullmatch(r"[+-]?\d+", row[j])]
    for j, values in _integer_columns(path, table, written_as_integers, skip, delimiter).items():
        columns[list(columns)[j]] = values
    return columns, None, False


def _named_columns(table: np.ndarray, names: list[str] | None, path: str) -> dict[str, np.ndarray]:
    if table.size == 0:
        raise PointCloudReadError(f"cannot read {path}: the file holds no points")
    if table.ndim != 2 or table.shape[1] < 3:
        raise PointCloudReadError(f"cannot read {path}: expected at least 3 columns (x y z); got shape {table.shape}")
    if names is None:
        names = ["x", "y", "z"] + [f"column_{i}" for i in range(3, table.shape[1])]
    if len(names) != table.shape[1]:
        raise PointCloudReadError(f"cannot read {path}: {len(names)} column names for {table.shape[1]} columns")
    repeated = [name for i, name in enumerate(names) if name in names[:i]]
    if repeated:
        where = [i + 1 for i, name in enumerate(names) if name == repeated[0]]
        raise PointCloudReadError(f"cannot read {path}: the header names column {repeated[0]!r} twice (columns"
                                  f" {' and '.join(map(str, where))}); give each column its own name")
    return {name: table[:, i] for i, name in enumerate(names)}


def _read_npy(path: str) -> tuple[dict[str, np.ndarray], np.dtype | None]:
    """(columns, the dtype of a plain (N, C) array or None for a structured one) of a .npy file."""
    array = np.load(path, allow_pickle=False)
    if array.dtype.names:
        if array.ndim != 1:
            raise PointCloudReadError(f"cannot read {path}: expected a structured array of shape (N,); got shape"
                                      f" {array.shape}")
        return {name: np.asarray(array[name]).reshape(array.shape[0], -1).squeeze(1)
                for name in array.dtype.names}, None
    if array.dtype.kind not in "fiu":
        raise PointCloudReadError(f"cannot read {path}: expected a numeric (N, 3) array; got dtype {array.dtype}")
    if array.ndim != 2:
        raise PointCloudReadError(f"cannot read {path}: expected a numeric array of shape (N, 3) or (N, 3 + C);"
                                  f" got shape {array.shape}")
    return _named_columns(array, None, path), array.dtype


def _npy_reader(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], np.dtype | None, bool]:
    return (*_read_npy(path), False)  # _read_npy is looked up here, when called (tests wrap it)


def _read_pcd(path: str, samples: int = 0, seed: int = 0) -> tuple[dict[str, np.ndarray], None, bool]:
    (pypcd4,) = _require("pcd", f"reading {path}")
    with open(path, "rb") as fh:
        lines = []
        for raw_line in fh:
            line = raw_line.decode("ascii").strip()
            if line and not line.startswith("#"):
                lines.append(line)
            if line.upper().startswith("DATA"):
                break
        try:
            meta = pypcd4.MetaData.parse_header(lines)
        except ValueError as err:  # pydantic's ValidationError
            problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}"
                                 + ("" if e["type"] == "missing" else f" (got {e.get('input')!r})")
                                 for e in getattr(err, "errors", lambda: [])()) or str(err)
            raise PointCloudReadError(f"cannot read {path}: invalid PCD header: {problems}") from None
        n, fields = meta.points, list(zip(meta.fields, meta.type, meta.size, meta.count))
        if meta.data == pypcd4.Encoding.ASCII:
            raw = _pcd_ascii_fields(fh, fields, n, path)
        else:
            row = meta.build_dtype()
            if meta.data == pypcd4.Encoding.BINARY and os.fstat(fh.fileno()).st_size - fh.tell() < n * row.itemsize:
                raise PointCloudReadError(f"cannot read {path}: binary PCD data is truncated (less than {n}"
                                          f" points of {row.itemsize} bytes)")
            fh.seek(0)
            try:
                table = pypcd4.PointCloud.from_fileobj(fh).pc_data
            except Exception as err:
                raise PointCloudReadError(f"cannot read {path}: {meta.data.value} PCD data is truncated or"
                                          f" corrupt ({type(err).__name__}: {err})") from err
            # by position: pypcd4 gives each padding field ``_`` a new random name at every parse
            stored = iter(table.dtype.names)
            raw = {}
            for name, _, _, count in fields:
                parts = [table[next(stored)] for _ in range(count)]
                raw[name] = np.stack(parts, axis=1)
    return _pcd_columns(raw), None, False


def _pcd_ascii_fields(fh: BinaryIO, fields: list[tuple], n: int, path: str) -> dict[str, np.ndarray]:
    """Parse the rows of an ascii PCD body into (N, COUNT) arrays of each field's type.

    Values are parsed as float64 and then cast, so a packed ``rgb`` float written as PCL
    writes it (the packed unsigned integer) keeps its bits; 64-bit integer fields are parsed
    as integers, exactly."""
    if n == 0:
        raise PointCloudReadError(f"cannot read {path}: the file holds no points (POINTS 0)")
    wide = any(kind.upper() in "IU" and size == 8 for _, kind, size, _ in fields)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.loadtxt warns on a body without rows
        table = np.loadtxt(fh, dtype=str if wide else np.float64, ndmin=2, encoding="ascii")
    counts = [count for *_, count in fields]
    if table.shape[0] < n or (n and table.shape[1] != sum(counts)):
        raise PointCloudReadError(f"cannot read {path}: ascii PCD data is truncated or malformed (header: {n}"
                                  f" points of {sum(counts)} values; found {table.shape[0]} rows of"
                                  f" {table.shape[1]} values)")
    raw = {}
    for (name, kind, size, _), values in zip(fields, np.split(table[:n], np.cumsum(counts)[:-1], axis=1)):
        if kind.upper() in "IU" and size == 8:
            raw[name] = values.astype(f"{kind.lower()}8")
            continue
        values = values.astype(np.float64)
        packed_int = (name.lower() in ("rgb", "rgba") and values.size and np.all(values == np.floor(values))
                      and values.max() >= 1)
        raw[name] = values.astype(np.uint32 if packed_int else f"{kind.lower()}{size}")
    return raw


def _pcd_columns(raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Flatten PCD fields into named columns; unpack PCL's packed ``rgb``/``rgba``."""
    columns = {}
    for name, values in raw.items():
        if not name.isidentifier():  # PCL's "_" padding fields
            continue
        if name.lower() in ("rgb", "rgba") and values.shape[1] == 1:
            packed = np.ascontiguousarray(values[:, 0]).view(np.uint32) if values.itemsize == 4 else \
                values[:, 0].astype(np.uint32)
            channels = ("red", "green", "blue") + (("alpha",) if name.lower() == "rgba" else ())
            for channel, shift in zip(channels, (16, 8, 0, 24)):
                columns[channel] = ((packed >> shift) & 0xFF).astype(np.uint8)
        elif values.shape[1] == 1:
            columns[name] = values[:, 0]
        else:
            columns[name] = values
    return columns


def _las_size_check(path: str, header) -> None:
    """Refuse an uncompressed LAS file that holds fewer point records than its header announces."""
    if header.are_points_compressed:
        return
    need = header.offset_to_point_data + header.point_count * header.point_format.size
    size = os.path.getsize(path)
    if size < need:
        whole, rest = divmod(max(size - header.offset_to_point_data, 0), header.point_format.size)
        partial = f" and {rest} bytes of one more" if rest else ""
        raise PointCloudReadError(f"cannot read {path}: the file is truncated: it holds {whole} points{partial}; its"
                                  f" header announces {header.point_count} ({header.point_format.size} bytes each,"
                                  f" {need} bytes in all; the file holds {size} bytes)")


def _read_las(path: str, samples: int = 0, seed: int = 0) -> tuple[dict[str, np.ndarray], Any, bool]:
    laspy, _ = _require("las", f"reading {path}")
    with laspy.open(path) as reader:
        _las_size_check(path, reader.header)
        try:
            las = reader.read()
        except Exception as err:  # lazrs: "failed to fill whole buffer", ...
            raise PointCloudReadError(f"cannot read {path}: the point data is truncated or corrupt"
                                      f" ({type(err).__name__}: {err})") from err
    names = [name for name in las.point_format.dimension_names if name not in ("X", "Y", "Z")]
    columns = {axis: np.asarray(getattr(las, axis), np.float64) for axis in "xyz"}
    if {"red", "green", "blue"} <= set(names):
        columns["colors"] = np.stack([np.asarray(las[c]) for c in ("red", "green", "blue")], axis=1)
        names = [name for name in names if name not in ("red", "green", "blue")]
    columns.update((name, np.asarray(las[name])) for name in names)
    if len(las.points) != las.header.point_count:
        raise PointCloudReadError(f"cannot read {path}: the file holds {len(las.points)} points; its header"
                                  f" announces {las.header.point_count} (truncated or corrupt)")
    return columns, las.header, False


def _las_count(path: str) -> int:
    laspy, _ = _require("las", f"reading {path}")
    with laspy.open(path) as f:
        return int(f.header.point_count)


def _las_chunks(path: str, box: tuple | None):
    laspy, _ = _require("las", f"reading {path}")
    at = 0
    with laspy.open(path) as f:
        if any(isinstance(v, laspy.copc.CopcInfoVlr) for v in f.header.vlrs):
            yield from _copc_nodes(path, box)
            return
        _las_size_check(path, f.header)
        points = f.chunk_iterator(CHUNK_ROWS)
        while True:
            try:
                chunk = next(points, None)
            except Exception as err:  # lazrs: "failed to fill whole buffer", ...
                raise PointCloudReadError(f"cannot read {path}: the point data is truncated or corrupt"
                                          f" ({type(err).__name__}: {err})") from err
            if chunk is None:
                return
            yield at, np.stack([np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)], axis=1)
            at += len(chunk)


def _copc_nodes(path: str, box: tuple | None):
    """(position of a node's first point in the file, (R, 3) float64 coordinates) per COPC octree node.

    The nodes' point chunks are stored in the file in the order of their offsets, so a node's
    first point sits at the sum of the point counts of the nodes stored before it (its
    hierarchy entry: offset, point count). The whole hierarchy is read (laspy's
    ``load_octree_for_query``, every page), then only the nodes whose bounds, grown by one
    scale step, meet ``box`` are decompressed (laspy's ``CopcReader`` chunk reader, nodes
    batched by CHUNK_ROWS points: a batch starts at the node holding the next multiple), in
    file order. A point outside its node's bounds (one scale step of slack) makes the file
    unreadable: a spatial query could miss it.

    Raises:
      PointCloudReadError: a point lies outside its node's bounds.
    """
    from laspy.copc import CopcReader, load_octree_for_query

    with CopcReader.open(path) as reader:
        nodes = load_octree_for_query(reader.source, reader.copc_info, reader.root_page)
        nodes = sorted((node for node in nodes if node.point_count > 0), key=lambda node: node.offset)
        starts = np.cumsum([0] + [node.point_count for node in nodes])[:-1].tolist()
        step = np.asarray(reader.header.scales, dtype=np.float64)
        picked = [(s, node) for s, node in zip(starts, nodes)
                  if box is None or ((node.bounds.mins - step <= box[1]) & (node.bounds.maxs + step >= box[0])).all()]
        counts = np.array([node.point_count for _, node in picked], dtype=np.int64)
        firsts = np.flatnonzero(np.diff((np.cumsum(counts) - counts) // CHUNK_ROWS)) + 1
        batches = np.split(np.arange(len(picked)), firsts)
        for batch in ([picked[i] for i in rows] for rows in batches if rows.size):
            record = reader._fetch_and_decompress_points_of_nodes([node for _, node in batch])
            xyz = np.stack([np.asarray(record.x), np.asarray(record.y), np.asarray(record.z)], axis=1)
            at = 0
            for s, node in batch:
                x, at = xyz[at:at + node.point_count], at + node.point_count
                if ((x < node.bounds.mins - step) | (x > node.bounds.maxs + step)).any():
                    raise PointCloudReadError(f"cannot read {path}: a point of COPC node {node.key} lies outside"
                                              f" the node's bounds (corrupt octree)")
                yield s, x


def header_count(path) -> int | None:
    """The number of points a file's header announces (the header read alone); None for formats without one.

    Args:
      path: a point-cloud file; only LAS/LAZ headers announce a count.

    Returns:
      The header's point count of a LAS/LAZ file; None for any other format (the file is not opened).

    Raises:
      PointCloudNotFoundError: a LAS/LAZ file does not exist.
      PointCloudReadError: its header cannot be read.
      ImportError: the ``las`` extra is not installed.

    Examples:
      >>> header_count("cloud.ply") is None
      True
    """
    path = os.fspath(path)
    fmt = _format(path)
    if fmt.count is None:
        return None
    if not os.path.isfile(path):
        raise PointCloudNotFoundError(f"cannot read {path}: no such file")
    if fmt.extra is not None:
        _require(fmt.extra, f"reading {path}")
    try:
        return fmt.count(path)
    except Exception as err:
        raise PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err


def chunks(path, *, box: tuple | None = None):
    """(position of the first point in the file, (R, 3) float64 coordinates of consecutive points), in file order.

    LAS/LAZ :data:`CHUNK_ROWS` points at a time (laspy's chunked reading); a COPC file (one with a
    COPC info VLR, whatever its name) one octree node at a time, only the nodes whose bounds meet
    ``box`` (lo (3,), hi (3,) in file coordinates) when given; any other format whole
    (:func:`read_points`). Chunks may hold points outside ``box``.

    Args:
      path: a point-cloud file, any format :func:`read_points` reads.
      box: optional (lo (3,), hi (3,)): COPC nodes that do not meet it are skipped.

    Yields:
      (first, xyz): the position of the chunk's first point in the file and its (R, 3)
      float64 coordinates.

    Raises:
      PointCloudReadError: the file cannot be read (truncated, corrupt), naming it.
      ImportError: the optional package of the format is not installed.

    Examples:
      >>> import os, tempfile, numpy as np
      >>> path = os.path.join(tempfile.mkdtemp(), "cloud.xyz")
      >>> np.savetxt(path, np.eye(3))
      >>> [(first, xyz.shape) for first, xyz in chunks(path)]
      [(0, (3, 3))]
    """
    path = os.fspath(path)
    fmt = _format(path)
    if fmt.chunks is None:
        yield 0, read_points(path).points
        return
    if fmt.extra is not None:
        _require(fmt.extra, f"reading {path}")
    try:
        yield from fmt.chunks(path, box)
    except PointCloudReadError:
        raise
    except Exception as err:
        raise PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err


# ----------------------------------------------------------------------------- writing

_PLY_TYPES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
              "i8": "int64", "u8": "uint64", "f4": "float", "f8": "double"}


def check_writable(path) -> str:
    """Check, before any computation, that a point cloud can be written to ``path``.

    Args:
      path: output file; its extension must be one of :data:`WRITE_EXTENSIONS`
        (case-insensitive), its directory must exist and be writable, and an existing file
        there must be writable.

    Returns:
      The absolute path that will be written, with symbolic links resolved.

    Raises:
      PointCloudWriteError: (a ValueError) the extension is not supported, the path is a
        directory, the directory does not exist or is not writable, or the file is
        read-only; the message names the path.
      ImportError: the optional package the format needs (``hgjax[pcd]``, ``hgjax[las]``)
        is not installed.

    Examples:
      >>> import os, tempfile
      >>> folder = tempfile.mkdtemp()
      >>> check_writable(os.path.join(folder, "out.las")) == os.path.realpath(os.path.join(folder, "out.las"))
      True
      >>> check_writable(os.path.join(folder, "out.obj"))
      Traceback (most recent call last):
      ...
      hgjax.io.PointCloudWriteError: cannot write .../out.obj: unsupported extension '.obj' in argument path; expected one of .ply, .xyz, .txt, .npy, .pcd, .las, .laz
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    fmt = _format(path)
    if fmt.write is None:
        raise PointCloudWriteError(f"cannot write {path}: unsupported extension {ext!r} in argument path;"
                                   f" expected one of {', '.join(WRITE_EXTENSIONS)}")
    if fmt.extra is not None:
        _require(fmt.extra, f"writing {path}")
    target = os.path.realpath(path)
    directory = os.path.dirname(target)
    if os.path.isdir(target):
        raise PointCloudWriteError(f"cannot write {path}: it is a directory")
    if not os.path.isdir(directory):
        raise PointCloudWriteError(f"cannot write {path}: directory {directory} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise PointCloudWriteError(f"cannot write {path}: directory {directory} is not writable")
    if os.path.exists(target) and not os.access(target, os.W_OK):
        raise PointCloudWriteError(f"cannot write {path}: the file is read-only")
    return target


_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<host>[A-Za-z0-9-]*)\.(?P<pid>\d+)\.[0-9a-f]{12}\.tmp$")
"""The temporary files of :func:`_atomic_write`: ``.NAME.HOST.PID.HEX.tmp``."""


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())


def _is_running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def remove_stale_temporaries(directory) -> list[str]:
    """Remove the temporary files that killed writers (``kill -9``, power loss) left in ``directory``.

    Only files named as :func:`write_points` names its temporaries (``.NAME.HOST.PID.HEX.tmp``)
    by a process of this host that is no longer running are removed; other files, and the
    temporaries of running writers or other hosts (a shared file system), are left alone.

    Args:
      directory: a directory path.

    Returns:
      The paths removed, sorted.

    Examples:
      >>> import os, tempfile
      >>> folder = tempfile.mkdtemp()
      >>> stale = os.path.join(folder, f".kept.ply.{_host()}.999999999.0123456789ab.tmp")
      >>> open(stale, "w").close()
      >>> remove_stale_temporaries(folder) == [stale], os.listdir(folder)
      (True, [])
    """
    removed, host = [], _host()
    with os.scandir(directory) as entries:
        for entry in entries:
            match = _TEMP_NAME.match(entry.name)
            if (match and match["host"] == host and entry.is_file(follow_symlinks=False)
                    and not _is_running(int(match["pid"]))):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(entry.path)
                    removed.append(entry.path)
    return sorted(removed)


def _atomic_write(target: str, write: Callable[[BinaryIO], None]) -> None:
    """Call ``write`` on a new temporary file next to ``target``, then rename it onto ``target``.

    On any exception (or interruption) the temporary file is removed and ``target`` is
    left as it was. The temporary file is named ``.NAME.HOST.PID.HEX.tmp`` so that
    :func:`remove_stale_temporaries` can tell one left by a killed process."""
    temp = os.path.join(os.path.dirname(target), f".{os.path.basename(target)}.{_host()}.{os.getpid()}"
                        f".{secrets.token_hex(6)}.tmp")
    fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    OPEN_TEMPORARIES.add(temp)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(temp, target)
    except BaseException:
        if os.path.exists(temp):
            os.unlink(temp)
        raise
    finally:
        OPEN_TEMPORARIES.discard(temp)


OPEN_TEMPORARIES: set[str] = set()
"""The temporary files :func:`_atomic_write` is writing now (the command line removes them
when a signal ends the process at once)."""


def _native_column(values: np.ndarray) -> np.ndarray:
    """A numeric column in native byte order (bools as uint8, float16 as float32)."""
    values = np.asarray(values)
    if values.dtype.kind == "b":
        return values.astype(np.uint8)
    if values.dtype.kind not in "iuf":
        raise TypeError(f"attribute columns must be numeric; got dtype {values.dtype}")
    if values.dtype.kind == "f" and values.dtype.itemsize not in (4, 8):
        return values.astype(np.float32)
    return values.astype(values.dtype.newbyteorder("="), copy=False)


def _ply_column(values: np.ndarray) -> np.ndarray:
    """A column in a dtype PLY can store: 64-bit integers become int32 when they fit (every PLY
    reader knows ``int``), else stay 64-bit (``int64``/``uint64``, as trimesh and hgjax read them)."""
    values = _native_column(values)
    if values.dtype.kind in "iu" and values.dtype.itemsize == 8:
        info = np.iinfo(np.int32)
        if values.size == 0 or (values.min() >= info.min and values.max() <= info.max):
            return values.astype(np.int32)
    return values


def _check_unique(names: list[str]) -> None:
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"attributes would be written to the same column names {repeated}; rename them")


def _validated(points, attributes: Mapping[str, np.ndarray] | None, scores) -> tuple[np.ndarray, dict]:
    """Points (N, 3) and attributes (each (N,) or (N, C), ``colors`` (N, 3|4), ``normals`` (N, 3))."""
    from hgjax import _validate

    pts = np.asarray(_validate.check_points(points))
    n = pts.shape[0]
    attrs = {name: np.asarray(value) for name, value in (attributes or {}).items()}
    if scores is not None:
        if "score" in attrs:
            raise ValueError("scores and attributes['score'] are both given; pass only one")
        attrs["score"] = np.asarray(scores)
    for name, value in attrs.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", str(name)):
            raise ValueError(f"attribute names must be identifiers; got {name!r}")
        widths = {"colors": (3, 4), "normals": (3,)}.get(name)
        if widths is not None and (value.ndim != 2 or value.shape[0] != n or value.shape[1] not in widths):
            raise ValueError(f"attributes[{name!r}] must have shape (N, 3){' or (N, 4)' * (name == 'colors')}"
                             f" with N = {n}; got {value.shape}")
        if value.ndim == 0 or value.shape[0] != n or value.ndim > 2:
            raise ValueError(f"attribute {name!r} must have shape (N,) or (N, C) with N = {n}; got {value.shape}")
        _native_column(value)
    return pts, attrs


def _flat_columns(points: np.ndarray, attributes: dict, *, column: Callable = _native_column,
                  normal_names: tuple = _NORMAL_NAMES[0]) -> list[tuple[str, np.ndarray]]:
    """(name, (N,) column) pairs in file order: x y z, colours, normals, the other attributes."""
    columns = [(c, column(points[:, i])) for i, c in enumerate("xyz")]
    for name, value in attributes.items():
        if name == "colors":
            value = _as_uint8(value)
        if value.ndim == 1:
            columns.append((name, column(value)))
            continue
        names = {"colors": _COLOR_NAMES[0], "normals": normal_names}.get(name)
        names = names[:value.shape[1]] if names else [f"{name}_{i}" for i in range(value.shape[1])]
        columns += [(label, column(value[:, i])) for i, label in enumerate(names)]
    _check_unique([name for name, _ in columns])
    return columns


def _savetxt(fh: BinaryIO, columns: list[tuple[str, np.ndarray]], header: str = "") -> None:
    """Write columns as text rows, each value in a format that reads back exactly."""
    table = np.rec.fromarrays([c for _, c in columns], names=[name for name, _ in columns])
    fmt = ["%d" if c.dtype.kind in "iu" else "%.9g" if c.dtype.itemsize <= 4 else "%.17g" for _, c in columns]
    np.savetxt(fh, table, fmt=fmt, header=header, comments="# ")


def _text_writer(points, attributes, header, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
    columns = _flat_columns(points, attributes)
    return lambda fh: _savetxt(fh, columns, " ".join(name for name, _ in columns))


def _is_plain(header) -> bool:
    """Whether ``header`` is the layout of a plain (N, C) .npy array (its dtype, without fields)."""
    return isinstance(header, np.dtype) and header.names is None


def _npy_writer(points, attributes, header, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
    if not _is_plain(header):
        columns = _flat_columns(points, attributes)
        table = np.rec.fromarrays([c for _, c in columns], names=[name for name, _ in columns]).view(np.ndarray)
        return lambda fh: np.save(fh, table, allow_pickle=False)
    names = [f"column_{i}" for i in range(3, 3 + len(attributes))]
    for name, value in attributes.items():
        if name not in names or value.ndim != 1:
            raise ValueError(f"attribute {name!r} has no column in a plain .npy array (header: the dtype of a plain"
                             f" (N, 3 + C) input, whose columns are x y z column_3 ...); write a structured .npy"
                             f" (header=None) or another format")
    table = np.column_stack([points] + [_native_column(attributes[name]) for name in names])
    stored = table.astype(header)
    if not np.array_equal(stored, table, equal_nan=stored.dtype.kind == table.dtype.kind == "f"):
        stored = table  # values the input's dtype cannot hold: in their own dtype, never rounded
    return lambda fh: np.save(fh, stored, allow_pickle=False)


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


def _pcd_writer(points, attributes, header, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
    (pypcd4,) = _require("pcd", "writing PCD")
    attributes = dict(attributes)
    colors = attributes.pop("colors", None)
    columns = _flat_columns(points, attributes, normal_names=_NORMAL_NAMES[1])
    text_columns = list(columns)
    if colors is not None:
        c = _as_uint8(colors).astype(np.uint32)
        packed = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2] | (c[:, 3] << 24 if c.shape[1] == 4 else 0)
        name = "rgba" if c.shape[1] == 4 else "rgb"
        columns.insert(3, (name, packed if name == "rgba" else packed.view(np.float32)))
        text_columns.insert(3, (name, packed))  # ascii: the packed integer, as PCL writes it
        _check_unique([name for name, _ in columns])
    cloud = pypcd4.PointCloud.from_points([c for _, c in columns], [name for name, _ in columns],
                                          [c.dtype for _, c in columns])
    if binary:
        encoding = pypcd4.Encoding.BINARY_COMPRESSED if compressed else pypcd4.Encoding.BINARY
        return lambda fh: cloud.save(fh, encoding=encoding)

    def write(fh: BinaryIO) -> None:
        fh.write(cloud.metadata.compose_header(data=pypcd4.Encoding.ASCII).encode("ascii"))
        _savetxt(fh, text_columns)

    return write


def _las_scale(span: float) -> float:
    """The coordinate scale for a new LAS file whose coordinates reach ``span`` above the offset."""
    if span == 0:
        return 0.001
    exponent = min(-3, math.floor(math.log10(span)) - 6)
    return float(f"1e{max(exponent, math.ceil(math.log10(span / (2**31 - 1))))}")


def _las_writer(points, attributes, header, binary: bool, compressed: bool, *, compress: bool
                ) -> Callable[[BinaryIO], None]:
    laspy, _ = _require("las", "writing LAS/LAZ")
    values = {name: value for name, value in attributes.items() if name not in ("colors", "normals")}
    pairs = list(values.items())
    if "colors" in attributes:
        colors = attributes["colors"]
        pairs += zip(("red", "green", "blue"), _as_uint16(colors[:, :3]).T)
        if colors.shape[1] == 4:
            pairs.append(("alpha", _as_uint8(colors)[:, 3]))
    if "normals" in attributes:
        pairs += zip(_NORMAL_NAMES[0], attributes["normals"].T)
    if header is None or _is_plain(header):  # no header, or a plain .npy input's layout
        header = laspy.LasHeader(point_format=6 + ("colors" in attributes) + ("colors" in attributes and
                                                                             "nir" in values), version="1.4")
        header.offsets = np.floor(points.min(axis=0).astype(np.float64))
        header.scales = np.full(3, _las_scale(float((points - header.offsets).max())))
    elif not isinstance(header, laspy.LasHeader):
        raise TypeError(f"header must be a laspy.LasHeader (PointData.header of a LAS/LAZ file) or None;"
                        f" got {type(header).__name__}")
    else:
        header = copy.deepcopy(header)
        for name in ("vlrs", "evlrs"):  # a COPC input's octree describes its own points: the output is plain LAS/LAZ
            records = getattr(header, name)
            if records:
                setattr(header, name, type(records)(v for v in records if v.user_id != "copc"))
    dims = set(header.point_format.dimension_names)
    flat = []
    for name, value in pairs:
        value = _native_column(value)
        if name in dims or value.ndim == 1:
            flat.append((name, value))
        else:
            flat += [(f"{name}_{i}", value[:, i]) for i in range(value.shape[1])]
    _check_unique([name for name, _ in flat])
    header.add_extra_dims([laspy.ExtraBytesParams(name, value.dtype) for name, value in flat if name not in dims])
    las = laspy.LasData(header, laspy.ScaleAwarePointRecord.zeros(points.shape[0], header=header))
    try:
        las.x, las.y, las.z = points.T
    except OverflowError:
        raise ValueError(f"coordinates do not fit LAS int32 with scale {list(header.scales)} and offset"
                         f" {list(header.offsets)}; write without that header") from None
    for name, value in flat:
        try:
            las[name] = value
        except OverflowError as err:
            raise ValueError(f"attribute {name!r} does not fit LAS dimension {name!r}: {err}") from None
        stored = np.asarray(las[name])
        if not np.array_equal(stored, value, equal_nan=stored.dtype.kind == value.dtype.kind == "f"):
            raise ValueError(f"attribute {name!r} ({value.dtype}) does not fit LAS dimension {name!r}"
                             f" ({stored.dtype}) without loss; convert or rename it")
    return lambda fh: las.write(fh, do_compress=compress)


def write_points(path, points, *, attributes: Mapping[str, np.ndarray] | None = None, scores=None,
                 header=None, binary: bool = True, compressed: bool = True) -> None:
    """Write points, their attributes and optional per-point scores, atomically.

    The file is first written to a temporary file in the same directory, then renamed onto
    ``path``: an interrupted or failed write leaves ``path`` as it was, and ``path`` may be
    the file the points were read from. Nothing passed in is modified.

    Args:
      path: output file; the extension picks the format (:data:`WRITE_EXTENSIONS`):
        ``.ply`` (one ``vertex`` element; 64-bit integers as ``int`` when they fit, else
        ``int64``/``uint64``), ``.xyz``/``.txt`` (space-separated columns under a ``# x y z
        ...`` line; integers as integers), ``.npy`` (a structured array with fields ``x y z
        ...``, or a plain array: see ``header``),
        ``.pcd`` (PCL; colours as a packed ``rgb`` float, or ``rgba`` uint32 for 4
        channels; normals as ``normal_x`` ...), ``.las`` / ``.laz`` (see ``header``).
      points: (N, 3) float32 or float64; PLY, NPY and PCD store them in that dtype.
      attributes: per-point arrays with leading axis N: ``colors`` (N, 3|4) (as ``red green
        blue [alpha]``, 8-bit except in LAS), ``normals`` (N, 3) (as ``nx ny nz``), and any
        other (N,) or (N, C) numeric column (as ``name`` or ``name_0 ... name_{C-1}``).
      scores: optional (N,) per-point score, written as the column ``score`` (not written to
        a plain .npy array, which has no column for it: :func:`holds_scores`).
      header: .npy: the :attr:`PointData.header` of a plain (N, 3 + C) .npy input (its
        dtype) writes the same plain array: x, y, z and the attributes ``column_3`` ... (no
        other attribute, no score), in that dtype when it holds every value exactly (else
        float64), so ``np.load`` gives the points as it did for the input.
        LAS/LAZ: the :attr:`PointData.header` of the file the points were read
        from. Its point format, version, scale, offset, extra dimensions and VLRs are
        kept (except a COPC file's octree VLRs, user id ``copc``: the output is plain
        LAS/LAZ), so a subset of a LAS file writes back bit-exact; attributes the format lacks
        become extra dimensions. With None (default), a LAS 1.4 file of point format 6
        (7 with ``colors``, 8 with ``colors`` and ``nir``) is written with offset the
        floor of each axis' minimum and one scale for all axes: 1e-6 of the largest
        coordinate above the offset, rounded down to a power of ten, at most 0.001 (1 mm
        for metric data) and at least what keeps the stored integers within int32.
        Attributes named like a dimension of the format (``intensity``,
        ``classification``, ``gps_time``, ...) fill it and must fit it exactly; 8-bit
        colours are scaled by 257 to 16 bits; an alpha channel and normals become extra
        dimensions ``alpha``, ``nx ny nz``.
        Other formats ignore it, and so do the formats it was not read from.
      binary: PLY: ``binary_little_endian`` (default) or ``ascii`` when False. PCD: binary
        data (default) or ``DATA ascii`` when False.
      compressed: PCD with ``binary``: ``DATA binary_compressed`` (default) or ``binary``.

    Returns:
      None.

    Raises:
      PointCloudWriteError: see :func:`check_writable`.
      ImportError: the optional package for PCD or LAS/LAZ is not installed.
      TypeError, ValueError: invalid points, an attribute of the wrong shape or dtype, two
        attributes written to the same column, or a value that does not fit its LAS
        dimension.
      OSError: the file cannot be written.

    Examples:
      >>> import os, tempfile, numpy as np
      >>> path = os.path.join(tempfile.mkdtemp(), "kept.ply")
      >>> write_points(path, np.eye(3), scores=np.array([0.5, 1.0, 2.0]))
      >>> read_points(path).attributes["score"].tolist()
      [0.5, 1.0, 2.0]
    """
    target = check_writable(path)
    _atomic_write(target, _writer(path, points, attributes, scores, header, binary, compressed))


def _writer(path, points, attributes, scores, header, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
    """The function writing the points to an open file in the format of ``path``'s extension,
    after every check of the points and attributes against that format."""
    fmt = _format(path)
    pts, attrs = _validated(points, attributes, scores if fmt.holds_scores(header) else None)
    return fmt.write(pts, attrs, header, binary, compressed)


def check_format(path, points, *, attributes: Mapping[str, np.ndarray] | None = None, scores=None,
                 header=None) -> None:
    """Check, before any computation, that :func:`write_points` can write these points to ``path``.

    Runs every check of :func:`write_points` on the points, attributes and header (column
    names, dtypes, LAS dimensions and value ranges) without writing anything, so an input
    whose attributes the output format cannot hold (a float ``intensity`` into LAS) is
    refused before a long computation. A subset of the points passes whenever all of them do.

    Args:
      path: output file; the extension picks the format, as for :func:`write_points`.
      points, attributes, scores, header: as for :func:`write_points`.

    Returns:
      None.

    Raises:
      PointCloudWriteError, ImportError, TypeError, ValueError: as :func:`write_points` would.

    Examples:
      >>> import numpy as np
      >>> check_format("kept.las", np.zeros((2, 3)), attributes={"intensity": np.array([0.5, 1.0])})
      Traceback (most recent call last):
      ...
      ValueError: attribute 'intensity' (float64) does not fit LAS dimension 'intensity' (uint16) without loss; convert or rename it
    """
    check_writable(path)
    _writer(path, points, attributes, scores, header, binary=True, compressed=True)


def write_indices(path, indices) -> None:
    """Write resampling indices as an int64 ``.npy`` file, atomically (as :func:`write_points`).

    Args:
      path: output file ending in ``.npy``.
      indices: (M,) integer indices, e.g. from :func:`hgjax.resample`.

    Returns:
      None.

    Raises:
      TypeError: ``indices`` is not an integer array.
      ValueError: ``path`` does not end in ``.npy`` or ``indices`` is not 1-D.
      PointCloudWriteError: see :func:`check_writable`.

    Examples:
      >>> import os, tempfile, numpy as np
      >>> path = os.path.join(tempfile.mkdtemp(), "kept.npy")
      >>> write_indices(path, np.array([4, 0, 2]))
      >>> np.load(path)
      array([4, 0, 2])
    """
    path = os.fspath(path)
    if not path.lower().endswith(".npy"):
        raise ValueError(f"indices are written as .npy; got path {path!r}")
    indices = np.asarray(indices)
    if indices.dtype.kind not in "iu":
        raise TypeError(f"indices must be an integer array; got dtype {indices.dtype}")
    if indices.ndim != 1:
        raise ValueError(f"indices must have shape (M,); got {indices.shape}")
    table = indices.astype(np.int64)
    _atomic_write(check_writable(path), lambda fh: np.save(fh, table, allow_pickle=False))


def holds_scores(path, *, header=None) -> bool:
    """Whether :func:`write_points` writes ``scores`` to ``path`` given this ``header``.

    True for every format but a plain .npy array: when ``header`` is the dtype of a plain
    (N, 3 + C) .npy input (:attr:`PointData.header`), a .npy output is the same plain array
    of the kept rows, so that ``np.load`` still gives points, and it has no column for a score.

    Args:
      path: output file; the extension picks the format.
      header: the :attr:`PointData.header` of the input, or None.

    Returns:
      Whether the scores are written.

    Examples:
      >>> import numpy as np
      >>> holds_scores("kept.npy"), holds_scores("kept.npy", header=np.dtype(np.float64)), holds_scores("kept.ply")
      (True, False, True)
    """
    return _format(path).holds_scores(header)


# ----------------------------------------------------------------------------- formats


@dataclasses.dataclass(frozen=True)
class _Format:
    """One file format: how it is read, written and read in chunks, and which extra it needs.

    Attributes:
      read: (path, samples, seed) -> (columns by name, header or None, whether the points are
        samples of a mesh).
      write: (points, attributes, header, binary, compressed) -> the function writing them to an
        open binary file, after every check; None for formats read only.
      chunks: (path, box) -> (first position, (R, 3) float64 coordinates) in file order; None:
        the file is read whole.
      count: path -> the point count its header announces; None: the format has no such header.
      extra: the optional dependency group it needs (``pip install hgjax[extra]``), or None.
      holds_scores: header -> whether a written file has a column for the scores.
    """

    read: Callable
    write: Callable | None = None
    chunks: Callable | None = None
    count: Callable | None = None
    extra: str | None = None
    holds_scores: Callable = lambda header: True


_MESH = _Format(_read_trimesh)
"""Any extension the table does not name: a mesh (or point cloud) that trimesh loads."""
_FORMATS = {
    ".ply": _Format(_read_ply, _ply_writer),
    ".xyz": _Format(_read_text, _text_writer),
    ".txt": _Format(_read_text, _text_writer),
    ".npy": _Format(_npy_reader, _npy_writer, holds_scores=lambda header: not _is_plain(header)),
    ".pcd": _Format(_read_pcd, _pcd_writer, extra="pcd"),
    ".las": _Format(_read_las, functools.partial(_las_writer, compress=False), _las_chunks, _las_count, "las"),
    ".laz": _Format(_read_las, functools.partial(_las_writer, compress=True), _las_chunks, _las_count, "las"),
    ".stl": _Format(_read_stl),
}
WRITE_EXTENSIONS = tuple(ext for ext, fmt in _FORMATS.items() if fmt.write is not None)
"""The extensions :func:`write_points` writes (case-insensitive): ``.ply .xyz .txt .npy .pcd .las .laz``."""


def _format(path) -> _Format:
    return _FORMATS.get(os.path.splitext(os.fspath(path))[1].lower(), _MESH)
