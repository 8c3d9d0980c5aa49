"""Reading and writing point clouds: PLY, XYZ/TXT, NPY, PCD, LAS/LAZ, and every mesh trimesh reads.

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
- ``.pcd`` (PCL; needs the ``pcd`` extra): ``DATA ascii``, ``binary`` and
  ``binary_compressed``, read through pypcd4. A packed ``rgb``/``rgba`` field becomes
  ``colors`` (in ascii files it may be written as the packed float or, as PCL does, as
  the packed unsigned integer); ``normal_x`` ... become ``normals``; fields named ``_``
  (padding) are skipped; a field with COUNT C > 1 is kept as an (N, C) attribute.
- ``.las`` / ``.laz`` (LAS 1.0-1.4, every point format; needs the ``las`` extra),
  read through laspy (LAZ through lazrs): ``points`` are the real coordinates
  X * scale + offset in float64 (exact for every int32 X), every other dimension of the
  point format and every extra dimension is an attribute under its laspy name in its
  stored dtype (``intensity``, ``return_number``, ``classification``, ``gps_time``,
  ``scan_angle`` or ``scan_angle_rank``, ...; scaled extra dimensions as float64), except
  ``red green blue``, which become ``colors`` (N, 3) uint16. The file's
  :class:`laspy.LasHeader` is kept as :attr:`PointData.header`.

For an input that is already a point cloud, ``samples`` is ignored when it is None or at
least the number of points; when smaller it selects a seeded random subset (in file
order). Points with a NaN or inf coordinate are dropped with a :class:`NonFinitePointsWarning`
that says how many. Every failure raises :class:`PointCloudReadError` naming the file; a
missing optional package raises :class:`ImportError` naming the extra to install.

Writers (:func:`write_points`) cover the same point-cloud formats, chosen by the extension
(:data:`WRITE_EXTENSIONS`). Every write goes to a temporary file in the target's directory
that is then renamed onto the target, so an interrupted or failed write never leaves a
partial file and writing onto the file that was read never destroys it midway.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
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
    "DEFAULT_SAMPLES",
    "NonFinitePointsWarning",
    "PointCloudNotFoundError",
    "PointCloudReadError",
    "PointCloudWriteError",
    "PointData",
    "WRITE_EXTENSIONS",
    "check_format",
    "check_writable",
    "read_points",
    "remove_stale_temporaries",
    "write_indices",
    "write_points",
]

DEFAULT_SAMPLES = 20000
WRITE_EXTENSIONS = (".ply", ".xyz", ".txt", ".npy", ".pcd", ".las", ".laz")

_COLOR_NAMES = (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"))
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_EXTRAS = {".las": "las", ".laz": "las", ".pcd": "pcd"}
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
        LAS/LAZ file (point format, version, scale, offset, extra dimensions, VLRs); None
        for other formats.

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
    ext = os.path.splitext(path)[1].lower()
    if ext in _EXTRAS:
        _require(_EXTRAS[ext], f"reading {path}")
    header, is_mesh = None, False
    try:
        if ext in (".xyz", ".txt"):
            columns = _read_text(path)
        elif ext == ".npy":
            columns = _read_npy(path)
        elif ext == ".pcd":
            columns = _read_pcd(path)
        elif ext in (".las", ".laz"):
            columns, header = _read_las(path)
        else:
            columns, is_mesh = _read_trimesh(path, samples or DEFAULT_SAMPLES, seed)
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


def _read_pcd(path: str) -> dict[str, np.ndarray]:
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
            raw = {name: np.stack([table[f"{name}__{i:04d}"] for i in range(count)], axis=1) if count > 1
                   else table[name][:, None] for name, _, _, count in fields}
    return _pcd_columns(raw)


def _pcd_ascii_fields(fh: BinaryIO, fields: list[tuple], n: int, path: str) -> dict[str, np.ndarray]:
    """Parse the rows of an ascii PCD body into (N, COUNT) arrays of each field's type.

    Values are parsed as float64 and then cast, so a packed ``rgb`` float written as PCL
    writes it (the packed unsigned integer) keeps its bits."""
    if n == 0:
        raise PointCloudReadError(f"cannot read {path}: the file holds no points (POINTS 0)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.loadtxt warns on a body without rows
        table = np.loadtxt(fh, dtype=np.float64, ndmin=2, encoding="ascii")
    counts = [count for *_, count in fields]
    if table.shape[0] < n or (n and table.shape[1] != sum(counts)):
        raise PointCloudReadError(f"cannot read {path}: ascii PCD data is truncated or malformed (header: {n}"
                                  f" points of {sum(counts)} values; found {table.shape[0]} rows of"
                                  f" {table.shape[1]} values)")
    raw = {}
    for (name, kind, size, _), values in zip(fields, np.split(table[:n], np.cumsum(counts)[:-1], axis=1)):
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


def _read_las(path: str) -> tuple[dict[str, np.ndarray], Any]:
    laspy, _ = _require("las", f"reading {path}")
    las = laspy.read(path)
    names = [name for name in las.point_format.dimension_names if name not in ("X", "Y", "Z")]
    columns = {axis: np.asarray(getattr(las, axis), np.float64) for axis in "xyz"}
    if {"red", "green", "blue"} <= set(names):
        columns["colors"] = np.stack([np.asarray(las[c]) for c in ("red", "green", "blue")], axis=1)
        names = [name for name in names if name not in ("red", "green", "blue")]
    columns.update((name, np.asarray(las[name])) for name in names)
    if len(las.points) != las.header.point_count:
        raise PointCloudReadError(f"cannot read {path}: the file holds {len(las.points)} points; its header"
                                  f" announces {las.header.point_count} (truncated or corrupt)")
    return columns, las.header


# ----------------------------------------------------------------------------- writing

_PLY_TYPES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
              "f4": "float", "f8": "double"}


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
    if ext not in WRITE_EXTENSIONS:
        raise PointCloudWriteError(f"cannot write {path}: unsupported extension {ext!r} in argument path;"
                                   f" expected one of {', '.join(WRITE_EXTENSIONS)}")
    if ext in _EXTRAS:
        _require(_EXTRAS[ext], f"writing {path}")
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
    """A column in a dtype PLY can store: 64-bit integers become int32 when they fit, else double."""
    values = _native_column(values)
    if values.dtype.kind in "iu" and values.dtype.itemsize == 8:
        info = np.iinfo(np.int32)
        fits = values.size == 0 or (values.min() >= info.min and values.max() <= info.max)
        return values.astype(np.int32 if fits else np.float64)
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


def _text_writer(points, attributes) -> Callable[[BinaryIO], None]:
    columns = _flat_columns(points, attributes)
    return lambda fh: _savetxt(fh, columns, " ".join(name for name, _ in columns))


def _npy_writer(points, attributes) -> Callable[[BinaryIO], None]:
    columns = _flat_columns(points, attributes)
    table = np.rec.fromarrays([c for _, c in columns], names=[name for name, _ in columns]).view(np.ndarray)
    return lambda fh: np.save(fh, table, allow_pickle=False)


def _ply_writer(points, attributes, binary: bool) -> Callable[[BinaryIO], None]:
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


def _pcd_writer(points, attributes, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
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


def _las_writer(points, attributes, header, compress: bool) -> Callable[[BinaryIO], None]:
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
    if header is None:
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
        ``.ply`` (one ``vertex`` element), ``.xyz``/``.txt`` (space-separated columns under a
        ``# x y z ...`` line), ``.npy`` (a structured array with fields ``x y z ...``),
        ``.pcd`` (PCL; colours as a packed ``rgb`` float, or ``rgba`` uint32 for 4
        channels; normals as ``normal_x`` ...), ``.las`` / ``.laz`` (see ``header``).
      points: (N, 3) float32 or float64; PLY, NPY and PCD store them in that dtype.
      attributes: per-point arrays with leading axis N: ``colors`` (N, 3|4) (as ``red green
        blue [alpha]``, 8-bit except in LAS), ``normals`` (N, 3) (as ``nx ny nz``), and any
        other (N,) or (N, C) numeric column (as ``name`` or ``name_0 ... name_{C-1}``).
      scores: optional (N,) per-point score, written as the column ``score``.
      header: LAS/LAZ only: the :attr:`PointData.header` of the file the points were read
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
    ext = os.path.splitext(os.fspath(path))[1].lower()
    pts, attrs = _validated(points, attributes, scores)
    if ext in (".xyz", ".txt"):
        return _text_writer(pts, attrs)
    if ext == ".npy":
        return _npy_writer(pts, attrs)
    if ext == ".pcd":
        return _pcd_writer(pts, attrs, binary, compressed)
    if ext in (".las", ".laz"):
        return _las_writer(pts, attrs, header, ext == ".laz")
    return _ply_writer(pts, attrs, binary)


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
