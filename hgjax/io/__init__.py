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

Every format is one record of one table keyed by the extension (``_FORMATS``, at the end of
this module): its reader, writer, chunk reader, header count and optional extra; any other
extension is read as a mesh by trimesh. The readers and writers live in private modules by
format (``_ply``, ``_text``, ``_npy``, ``_pcd``, ``_las``, ``_mesh``), on shared column helpers
(``_columns``), errors (``_errors``) and atomic writes (``_atomic``).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from typing import Any, BinaryIO, Callable, Mapping

import numpy as np

from hgjax.io._atomic import OPEN_TEMPORARIES as OPEN_TEMPORARIES
from hgjax.io._atomic import _atomic_write, remove_stale_temporaries
from hgjax.io._columns import _COLOR_NAMES, _NORMAL_NAMES, _as_uint8, _validated
from hgjax.io._errors import (
    NonFinitePointsWarning,
    PointCloudNotFoundError,
    PointCloudReadError,
    PointCloudWriteError,
    _require,
)
from hgjax.io._las import _las_chunks, _las_count, _las_writer, _read_las
from hgjax.io._mesh import _read_stl, _read_trimesh
from hgjax.io._npy import _is_plain, _npy_reader, _npy_writer
from hgjax.io._pcd import _pcd_writer, _read_pcd
from hgjax.io._ply import _ply_writer, _read_ply
from hgjax.io._text import _read_text, _text_writer

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
    "file_identity",
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
        yield from fmt.chunks(path, box, CHUNK_ROWS)
    except PointCloudReadError:
        raise
    except Exception as err:
        raise PointCloudReadError(f"cannot read {path}: {type(err).__name__}: {err}") from err


def file_identity(path):
    """What tells one file from another however it is reached: its (device, inode) pair.

    A path that cannot be stat'ed (missing, unreadable directory) is identified by its real path,
    so two spellings of one missing file are still one.

    Args:
      path: a file path.

    Returns:
      (st_dev, st_ino) of the file ``path`` reaches (symbolic links followed), or its real path.

    Examples:
      >>> import os, tempfile
      >>> folder = tempfile.mkdtemp()
      >>> open(os.path.join(folder, "a.xyz"), "w").close()
      >>> os.link(os.path.join(folder, "a.xyz"), os.path.join(folder, "b.xyz"))
      >>> file_identity(os.path.join(folder, "a.xyz")) == file_identity(os.path.join(folder, "b.xyz"))
      True
    """
    path = os.fspath(path)
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return os.path.realpath(path)
    return st.st_dev, st.st_ino


# ----------------------------------------------------------------------------- writing


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
      hgjax.io.PointCloudWriteError: cannot write .../out.obj: hgjax does not write .obj files; give one of .ply, .xyz, .txt, .npy, .pcd, .las, .laz
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    fmt = _format(path)
    if fmt.write is None:
        what = f"hgjax does not write {ext} files" if ext else "it has no extension to choose the format by"
        raise PointCloudWriteError(f"cannot write {path}: {what}; give one of {', '.join(WRITE_EXTENSIONS)}")
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
      points: (N, 3) float32 or float64, N >= 0 (no point: a valid empty file of the format, which
        :func:`read_points` refuses as holding none); PLY, NPY and PCD store them in that dtype.
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
      chunks: (path, box, rows) -> (first position, (R, 3) float64 coordinates) in file order,
        ``rows`` (:data:`CHUNK_ROWS`) points per chunk or batch of nodes; None: the file is read whole.
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
