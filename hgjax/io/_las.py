"""LAS/LAZ files through laspy and lazrs (the ``las`` extra): whole, in chunks, COPC by octree node; the writer.

Chunked readers take the points per chunk, ``rows`` (:data:`hgjax.io.CHUNK_ROWS`), from :func:`hgjax.io.chunks`.
"""

from __future__ import annotations

import copy
import math
import os
from typing import Any, BinaryIO, Callable

import numpy as np

from hgjax.io._columns import (
    _NORMAL_NAMES,
    _as_uint8,
    _as_uint16,
    _check_unique,
    _native_column,
)
from hgjax.io._errors import PointCloudReadError, _require
from hgjax.io._npy import _is_plain


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


def _las_chunks(path: str, box: tuple | None, rows: int):
    laspy, _ = _require("las", f"reading {path}")
    at = 0
    with laspy.open(path) as f:
        if any(isinstance(v, laspy.copc.CopcInfoVlr) for v in f.header.vlrs):
            yield from _copc_nodes(path, box, rows)
            return
        _las_size_check(path, f.header)
        points = f.chunk_iterator(rows)
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


def _copc_nodes(path: str, box: tuple | None, rows: int):
    """(position of a node's first point in the file, (R, 3) float64 coordinates) per COPC octree node.

    The nodes' point chunks are stored in the file in the order of their offsets, so a node's
    first point sits at the sum of the point counts of the nodes stored before it (its
    hierarchy entry: offset, point count). The whole hierarchy is read (laspy's
    ``load_octree_for_query``, every page), then only the nodes whose bounds, grown by one
    scale step, meet ``box`` are decompressed (laspy's ``CopcReader`` chunk reader, nodes
    batched by ``rows`` points: a batch starts at the node holding the next multiple), in
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
        firsts = np.flatnonzero(np.diff((np.cumsum(counts) - counts) // rows)) + 1
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


def _las_scale(span: float) -> float:
    """The coordinate scale for a new LAS file whose coordinates reach ``span`` above the offset."""
    if span == 0:
        return 0.001
    exponent = min(-3, math.floor(math.log10(span)) - 6)
    return float(f"1e{max(exponent, math.ceil(math.log10(span / (2**31 - 1))))}")


_DESCRIPTIONS = {"score": "hgjax resampling score"}
"""The description of an extra dimension hgjax adds (LAS allows 32 characters), read by PDAL and CloudCompare."""


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
        header.offsets = np.floor(points.min(axis=0).astype(np.float64)) if points.size else np.zeros(3)
        header.scales = np.full(3, _las_scale(float((points - header.offsets).max(initial=0))))
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
    header.add_extra_dims([laspy.ExtraBytesParams(name, value.dtype, description=_DESCRIPTIONS.get(name, ""))
                           for name, value in flat if name not in dims])
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
        if not _exact(stored, value):
            raise ValueError(f"attribute {name!r} ({value.dtype}) does not fit LAS dimension {name!r}"
                             f" ({stored.dtype}) without loss; convert or rename it")
    return lambda fh: las.write(fh, do_compress=compress)


def _exact(stored: np.ndarray, value: np.ndarray) -> bool:
    """Whether ``stored`` (a LAS dimension as written) holds ``value`` exactly.

    NumPy compares integers with floats as floats, where 2**53 + 1 equals 2**53, so an integer
    column stored as floats is checked exactly in Python for the values beyond the float's
    significand (``gps_time`` given as int64, lossy above 2**53)."""
    if value.dtype.kind in "iu" and stored.dtype.kind == "f":
        if not np.isfinite(stored).all():
            return False
        limit = 2 ** (np.finfo(stored.dtype).nmant + 1)
        beyond = (value > limit) | (value < -limit)
        if not np.array_equal(stored[~beyond], value[~beyond]):
            return False
        return all(int(s) == int(v) for s, v in zip(stored[beyond].tolist(), value[beyond].tolist()))
    return np.array_equal(stored, value, equal_nan=stored.dtype.kind == value.dtype.kind == "f")
