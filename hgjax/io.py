"""Reading and writing point clouds: every format trimesh reads, plus XYZ/TXT, NPY and PCD.

Host-side file IO for the command line and for scripts; nothing here is traced by JAX.

Readers, chosen by the file extension (case-insensitive):

- ``.ply`` point clouds: every vertex property is kept (``red green blue [alpha]`` become
  ``colors``, ``nx ny nz`` become ``normals``, any other column keeps its name).
- Meshes (``.ply`` with faces, ``.obj``, ``.stl``, ``.off``, ``.glb``, ``.gltf`` and the
  other formats trimesh loads): ``samples`` points (default 20000) are drawn uniformly on
  the surface with :func:`trimesh.sample.sample_surface`, seeded by ``seed``; the face
  normal of each sample is kept as ``normals``. Scenes are merged into one mesh.
- ``.xyz`` / ``.txt``: whitespace- or comma-separated columns. A first line of names that
  include ``x y z`` (plain, or after ``#`` or ``//``) names the columns; otherwise the
  first three columns are x, y, z and extra columns are kept as ``column_3``, ...
- ``.npy``: an (N, 3+) numeric array (extra columns as for XYZ) or a structured array with
  fields ``x``, ``y``, ``z``.
- ``.pcd`` (PCL): ``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF, decompressed
  here in pure Python). A packed ``rgb``/``rgba`` field becomes ``colors``; ``normal_x``
  ... become ``normals``.

For an input that is already a point cloud, ``samples`` is ignored when it is None or at
least the number of points; when smaller it selects a seeded random subset (in file
order). Points with a NaN or inf coordinate are dropped with a :class:`NonFinitePointsWarning`
that says how many. Every failure raises :class:`PointCloudReadError` naming the file.
"""

from __future__ import annotations

import dataclasses
import os
import re
import warnings
from typing import Mapping

import numpy as np

__all__ = [
    "NonFinitePointsWarning",
    "PointCloudNotFoundError",
    "PointCloudReadError",
    "PointData",
    "read_points",
    "write_indices",
    "write_points",
]

DEFAULT_SAMPLES = 20000
WRITE_EXTENSIONS = (".ply", ".xyz", ".txt")

_COLOR_NAMES = (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"))
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))


class PointCloudReadError(ValueError):
    """A file could not be read as a point cloud; the message names the file and the cause."""


class PointCloudNotFoundError(PointCloudReadError, FileNotFoundError):
    """The file to read does not exist (also a :class:`FileNotFoundError`)."""


class NonFinitePointsWarning(UserWarning):
    """Points with NaN or inf coordinates were dropped while reading a file."""


@dataclasses.dataclass(frozen=True)
class PointData:
    """A point cloud read from a file, with its per-point attributes.

    Attributes:
      points: (N, 3) float64 coordinates, all finite.
      attributes: per-point arrays with leading axis N, by name: ``colors`` (N, 3) or
        (N, 4) uint8, ``normals`` (N, 3) float, and any extra columns of the file.
      source: the file it was read from (None when built in memory).

    Examples:
      >>> import numpy as np
      >>> data = PointData(np.zeros((4, 3)), {"intensity": np.arange(4.0)})
      >>> data.subset(np.array([3, 1])).attributes["intensity"]
      array([3., 1.])
    """

    points: np.ndarray
    attributes: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)
    source: str | None = None

    def __len__(self) -> int:
        return self.points.shape[0]

    def subset(self, indices) -> "PointData":
        """The points at ``indices`` (M,) and their attributes, in that order.

        Args:
          indices: (M,) integer indices (or an (N,) boolean mask).

        Returns:
          A new :class:`PointData` of M points with the same source.

        Examples:
          >>> import numpy as np
          >>> PointData(np.eye(3)).subset(np.array([2])).points
          array([[0., 0., 1.]])
        """
        indices = np.asarray(indices)
        return PointData(self.points[indices], {k: v[indices] for k, v in self.attributes.items()},
                         self.source)


# ----------------------------------------------------------------------------- reading


def read_points(path, *, samples: int | None = None, seed: int = 0) -> PointData:
    """Read a point cloud, or sample one from a mesh, from a file.

    Args:
      path: file path; the format comes from the extension (see the module docstring).
      samples: for meshes, the number of surface samples (default 20000); for point
        clouds, a seeded random subset of this size when smaller than the cloud (default
        None: all points).
      seed: integer seed of the surface sampling or the subset (default 0).

    Returns:
      :class:`PointData` with (N, 3) float64 finite points and per-point attributes.

    Raises:
      PointCloudNotFoundError: the file does not exist.
      PointCloudReadError: the file is empty, cannot be parsed, or holds no finite point.
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
    ext = os.path.splitext(path)[1].lower()
    try:
        if ext in (".xyz", ".txt"):
            columns, is_mesh = _read_text(path), False
        elif ext == ".npy":
            columns, is_mesh = _read_npy(path), False
        elif ext == ".pcd":
            columns, is_mesh = _read_pcd(path), False
        else:
            columns, is_mesh = _read_trimesh(path, samples or DEFAULT_SAMPLES, seed)
    except PointCloudReadError:
        raise
    except Exception as err:  # any parser failure becomes one clear error naming the file
        raise PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err
    data = _to_point_data(columns, path)
    if not is_mesh and samples is not None and samples < len(data):
        keep = np.sort(np.random.default_rng(seed).choice(len(data), samples, replace=False))
        data = data.subset(keep)
    return data


def _to_point_data(columns: dict[str, np.ndarray], path: str) -> PointData:
    """Group named (N,) columns into points, colors, normals and the remaining attributes."""
    names = {name.lower(): name for name in columns}
    if not all(c in names for c in "xyz"):
        raise PointCloudReadError(f"cannot read {path}: no x, y, z columns (found {sorted(columns)})")
    points = np.stack([np.asarray(columns.pop(names[c]), np.float64) for c in "xyz"], axis=1)
    attributes: dict[str, np.ndarray] = {}
    for group in _COLOR_NAMES:
        present = [names[c] for c in group if c in names and names[c] in columns]
        if len(present) >= 3 and present[:3] == [names[c] for c in group[:3]]:
            attributes["colors"] = np.stack([_as_uint8(columns.pop(c)) for c in present], axis=1)
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
    return PointData(points, attributes, path)


def _as_uint8(values: np.ndarray) -> np.ndarray:
    """Colour channel as uint8; floats in [0, 1] are scaled by 255."""
    values = np.asarray(values)
    if values.dtype.kind == "f":
        scale = 255.0 if values.size and np.nanmax(values) <= 1.0 else 1.0
        values = np.rint(np.nan_to_num(values) * scale)
    return np.clip(values, 0, 255).astype(np.uint8)


def _read_trimesh(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], bool]:
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
        return columns, True
    raw = getattr(geometry, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
    if raw is not None:  # PLY point cloud: keep every vertex property (ascii gives a dict)
        names = raw.dtype.names if isinstance(raw, np.ndarray) else tuple(raw)
        return {name: np.asarray(raw[name]).reshape(len(raw[name]), -1).squeeze(1) for name in names}, False
    vertices = np.asarray(getattr(geometry, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    columns = dict(zip("xyz", vertices.T))
    colors = np.asarray(getattr(geometry, "colors", ()))
    if colors.shape == (len(vertices), 4):
        columns.update(zip(("red", "green", "blue", "alpha"), colors.T))
    return columns, False


_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.IGNORECASE)


def _read_text(path: str) -> dict[str, np.ndarray]:
    with open(path, encoding="utf-8", errors="replace") as fh:
        first = ""
        for first in fh:
            if first.strip():
                break
    delimiter = "," if "," in first else None
    tokens = first.strip().lstrip("#/").replace(",", " ").split()
    is_comment = first.lstrip().startswith(("#", "//"))
    plain_header = not is_comment and not all(_NUMBER.match(t) for t in tokens)
    names = tokens if {"x", "y", "z"} <= {t.lower() for t in tokens} else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.loadtxt warns on files without data rows
        table = np.loadtxt(path, comments=("#", "//"), delimiter=delimiter, ndmin=2,
                           skiprows=int(plain_header), encoding="utf-8")
    return _named_columns(table, names, path)


def _named_columns(table: np.ndarray, names: list[str] | None, path: str) -> dict[str, np.ndarray]:
    if table.size == 0:
        raise PointCloudReadError(f"cannot read {path}: the file holds no points")
    if table.ndim != 2 or table.shape[1] < 3:
        raise PointCloudReadError(f"cannot read {path}: expected at least 3 columns (x y z); got shape {table.shape}")
    if names is None:
        names = ["x", "y", "z"] + [f"column_{i}" for i in range(3, table.shape[1])]
    if len(names) != table.shape[1]:
        raise PointCloudReadError(f"cannot read {path}: {len(names)} column names for {table.shape[1]} columns")
    return {name: table[:, i] for i, name in enumerate(names)}


def _read_npy(path: str) -> dict[str, np.ndarray]:
    array = np.load(path, allow_pickle=False)
    if array.dtype.names:
        return {name: np.asarray(array[name]).reshape(array.shape[0], -1).squeeze(1) for name in array.dtype.names}
    if array.dtype.kind not in "fiu":
        raise PointCloudReadError(f"cannot read {path}: expected a numeric (N, 3) array; got dtype {array.dtype}")
    return _named_columns(array.reshape(array.shape[0], -1) if array.ndim else array, None, path)


# PCL's PCD format: http://pointclouds.org/documentation/tutorials/pcd_file_format.html
_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4",
              ("U", 8): "<u8", ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}


def _read_pcd(path: str) -> dict[str, np.ndarray]:
    with open(path, "rb") as fh:
        blob = fh.read()
    header: dict[str, list[str]] = {}
    offset = 0
    while "DATA" not in header:
        end = blob.find(b"\n", offset)
        if end < 0:
            raise PointCloudReadError(f"cannot read {path}: PCD header has no DATA line")
        line = blob[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if line and not line.startswith("#"):
            key, *values = line.split()
            header[key.upper()] = values
    fields = header.get("FIELDS")
    if not fields:
        raise PointCloudReadError(f"cannot read {path}: PCD header has no FIELDS line")
    sizes = [int(s) for s in header.get("SIZE", [])]
    types = [t.upper() for t in header.get("TYPE", [])]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    if not (len(sizes) == len(types) == len(counts) == len(fields)):
        raise PointCloudReadError(f"cannot read {path}: PCD FIELDS, SIZE, TYPE and COUNT lengths differ")
    n = int(header["POINTS"][0]) if "POINTS" in header else \
        int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0])
    try:
        formats = [np.dtype(_PCD_TYPES[t, s]) for t, s in zip(types, sizes)]
    except KeyError as err:
        raise PointCloudReadError(f"cannot read {path}: unsupported PCD TYPE/SIZE {err.args[0]}") from None
    names = [f if f != "_" else f"_pad{i}" for i, f in enumerate(fields)]
    kind = header["DATA"][0].lower()
    body = blob[offset:]
    if kind == "ascii":
        table = np.loadtxt(body.decode("ascii").splitlines(), ndmin=2, dtype=np.float64)[:n]
        if table.shape[1] != sum(counts):
            raise PointCloudReadError(f"cannot read {path}: {table.shape[1]} values per row, header says {sum(counts)}")
        split = np.cumsum(counts)[:-1]
        raw = {name: col.astype(fmt) for name, fmt, col in zip(names, formats, np.split(table, split, axis=1))}
    elif kind == "binary":
        row = np.dtype([(name, fmt, (c,)) for name, fmt, c in zip(names, formats, counts)])
        if len(body) < n * row.itemsize:
            raise PointCloudReadError(f"cannot read {path}: binary PCD data is truncated "
                                      f"({len(body)} bytes for {n} points of {row.itemsize} bytes)")
        data = np.frombuffer(body, row, count=n)
        raw = {name: data[name] for name in names}
    elif kind == "binary_compressed":
        if len(body) < 8:
            raise PointCloudReadError(f"cannot read {path}: binary_compressed PCD data is truncated")
        compressed, uncompressed = np.frombuffer(body[:8], "<u4")
        data = lzf_decompress(body[8:8 + int(compressed)], int(uncompressed))
        raw, start = {}, 0
        for name, fmt, c in zip(names, formats, counts):  # column-major: one block per field
            stop = start + n * c * fmt.itemsize
            raw[name] = np.frombuffer(data[start:stop], fmt).reshape(n, c)
            start = stop
    else:
        raise PointCloudReadError(f"cannot read {path}: unknown PCD DATA {kind!r}; expected ascii, binary or"
                                  " binary_compressed")
    return _pcd_columns(raw)


def _pcd_columns(raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Flatten PCD fields into named columns; unpack PCL's packed ``rgb``/``rgba``."""
    columns = {}
    for name, values in raw.items():
        values = np.asarray(values)
        if name.startswith("_pad"):
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


def lzf_decompress(data: bytes, size: int) -> bytes:
    """Decompress an LZF block (liblzf's format, used by PCD ``binary_compressed``).

    Args:
      data: the compressed bytes.
      size: the decompressed size in bytes, as stored next to the block.

    Returns:
      The ``size`` decompressed bytes.

    Raises:
      ValueError: the block is corrupt or does not decompress to ``size`` bytes.

    Examples:
      >>> lzf_decompress(bytes([2]) + b"abc" + bytes([0x60, 2]), 8)
      b'abcabcab'
    """
    out = bytearray(size)
    ip = op = 0
    end = len(data)
    try:
        while ip < end:
            ctrl = data[ip]
            ip += 1
            if ctrl < 32:  # literal run of ctrl + 1 bytes
                length = ctrl + 1
                out[op:op + length] = data[ip:ip + length]
                if ip + length > end or op + length > size:
                    raise IndexError
                ip += length
                op += length
            else:  # back reference
                length = ctrl >> 5
                if length == 7:
                    length += data[ip]
                    ip += 1
                ref = op - ((ctrl & 0x1F) << 8) - data[ip] - 1
                ip += 1
                length += 2
                if ref < 0 or op + length > size:
                    raise IndexError
                if ref + length <= op:
                    out[op:op + length] = out[ref:ref + length]
                else:  # overlapping copy repeats the pattern
                    for i in range(length):
                        out[op + i] = out[ref + i]
                op += length
    except IndexError:
        raise ValueError(f"corrupt LZF block at byte {ip} of {end}") from None
    if op != size:
        raise ValueError(f"LZF block decompressed to {op} bytes; header says {size}")
    return bytes(out)


# ----------------------------------------------------------------------------- writing

_PLY_TYPES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
              "f4": "float", "f8": "double"}


def _text_format(values: np.ndarray) -> str:
    """printf format that writes a column without losing precision."""
    return "%d" if values.dtype.kind in "iu" else "%.9g" if values.dtype.itemsize <= 4 else "%.17g"


def _ply_column(values: np.ndarray) -> np.ndarray:
    """A column in a dtype PLY can store (64-bit integers and bools become int32/uint8 or double)."""
    values = np.asarray(values)
    if values.dtype.kind == "b":
        return values.astype(np.uint8)
    if values.dtype.kind in "iu" and values.dtype.itemsize == 8:
        info = np.iinfo(np.int32)
        fits = values.size == 0 or (values.min() >= info.min and values.max() <= info.max)
        return values.astype(np.int32 if fits else np.float64)
    if values.dtype.kind not in "iuf":
        raise TypeError(f"attribute columns must be numeric; got dtype {values.dtype}")
    if values.dtype.kind == "f" and values.dtype.itemsize not in (4, 8):
        return values.astype(np.float32)
    return values


def _flat_columns(points: np.ndarray, attributes: Mapping[str, np.ndarray] | None,
                  scores) -> list[tuple[str, np.ndarray]]:
    """(name, (N,) column) pairs in file order: x y z, colours, normals, extras, score."""
    from hgjax import _validate

    pts = np.asarray(_validate.check_points(points))
    n = pts.shape[0]
    columns = [(c, pts[:, i]) for i, c in enumerate("xyz")]
    attributes = dict(attributes or {})
    extra = dict(attributes)
    for key, names in (("colors", _COLOR_NAMES[0]), ("normals", _NORMAL_NAMES[0])):
        if key in extra:
            value = np.asarray(extra.pop(key))
            if value.ndim != 2 or value.shape[0] != n or value.shape[1] not in ((3, 4) if key == "colors" else (3,)):
                raise ValueError(f"attributes[{key!r}] must have shape (N, 3){' or (N, 4)' * (key == 'colors')}"
                                 f" with N = {n}; got {value.shape}")
            value = _as_uint8(value) if key == "colors" else value
            columns += [(names[i], value[:, i]) for i in range(value.shape[1])]
    if scores is not None:
        extra["score"] = scores
    for name, value in extra.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", str(name)):
            raise ValueError(f"attribute names must be identifiers; got {name!r}")
        value = np.asarray(value)
        if value.ndim == 0 or value.shape[0] != n or value.ndim > 2:
            raise ValueError(f"attribute {name!r} must have shape (N,) or (N, C) with N = {n}; got {value.shape}")
        if value.ndim == 1:
            columns.append((name, _ply_column(value)))
        else:
            columns += [(f"{name}_{i}", _ply_column(value[:, i])) for i in range(value.shape[1])]
    return columns


def write_points(path, points, *, attributes: Mapping[str, np.ndarray] | None = None, scores=None,
                 binary: bool = True) -> None:
    """Write points, their attributes and optional per-point scores to PLY or XYZ/TXT.

    Args:
      path: output file; ``.ply`` writes PLY (one ``vertex`` element), ``.xyz`` or
        ``.txt`` writes space-separated columns under a ``# x y z ...`` header line.
      points: (N, 3) float32 or float64; PLY stores them as ``float`` or ``double``.
      attributes: per-point arrays with leading axis N: ``colors`` (N, 3|4) uint8 (written
        as ``red green blue [alpha]``), ``normals`` (N, 3) (as ``nx ny nz``), and any other
        (N,) or (N, C) numeric column (as ``name`` or ``name_0 ... name_{C-1}``).
      scores: optional (N,) per-point score, written as the property ``score``.
      binary: PLY encoding, ``binary_little_endian`` (default) or ``ascii`` when False.

    Returns:
      None.

    Raises:
      TypeError, ValueError: invalid points, an attribute of the wrong length or dtype, or
        an unsupported extension.
      OSError: the file cannot be written.

    Examples:
      >>> import os, tempfile, numpy as np
      >>> path = os.path.join(tempfile.mkdtemp(), "kept.ply")
      >>> write_points(path, np.eye(3), scores=np.array([0.5, 1.0, 2.0]))
      >>> read_points(path).attributes["score"].tolist()
      [0.5, 1.0, 2.0]
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in WRITE_EXTENSIONS:
        raise ValueError(f"cannot write points to {path!r}: unknown extension {ext!r}; expected one of"
                         f" {list(WRITE_EXTENSIONS)}")
    columns = _flat_columns(points, attributes, scores)
    n = columns[0][1].shape[0]
    if ext in (".xyz", ".txt"):
        table = np.column_stack([c.astype(np.float64) for _, c in columns])
        fmt = [_text_format(c) for _, c in columns]
        np.savetxt(path, table, fmt=fmt, header=" ".join(name for name, _ in columns), comments="# ")
        return
    row = np.dtype([(name, col.dtype.newbyteorder("<")) for name, col in columns])
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "comment written by hgjax",
              f"element vertex {n}"]
    header += [f"property {_PLY_TYPES[col.dtype.str[1:]]} {name}" for name, col in columns]
    header.append("end_header")
    with open(path, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            table = np.empty(n, row)
            for name, col in columns:
                table[name] = col
            fh.write(table.tobytes())
        else:
            fmt = " ".join(_text_format(col) for _, col in columns)
            np.savetxt(fh, np.column_stack([col.astype(np.float64) for _, col in columns]), fmt=fmt)


def write_indices(path, indices) -> None:
    """Write resampling indices as an int64 ``.npy`` file.

    Args:
      path: output file ending in ``.npy``.
      indices: (M,) integer indices, e.g. from :func:`hgjax.resample`.

    Returns:
      None.

    Raises:
      TypeError: ``indices`` is not an integer array.
      ValueError: ``path`` does not end in ``.npy`` or ``indices`` is not 1-D.

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
    np.save(path, indices.astype(np.int64))
