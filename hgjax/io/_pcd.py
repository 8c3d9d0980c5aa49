"""PCL ``.pcd`` files through pypcd4 (the ``pcd`` extra): ascii, binary and binary_compressed."""

from __future__ import annotations

import os
import re
import warnings
from typing import BinaryIO, Callable

import numpy as np

from hgjax.io._columns import (
    _NORMAL_NAMES,
    _as_uint8,
    _check_unique,
    _flat_columns,
    _savetxt,
)
from hgjax.io._errors import PointCloudReadError, _require


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
            problems = "; ".join(f"no {e['loc'][0].upper()} line" if e["type"] == "missing" else
                                 f"{e['loc'][0].upper()}: {e['msg']} (got {e.get('input')!r})"
                                 for e in getattr(err, "errors", lambda: [])()) or _not_a_number(err, lines)
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


def _not_a_number(err: ValueError, lines: list[str]) -> str:
    """A header value that Python's int() or float() refused, named with its line's keyword; other errors as
    they are."""
    found = re.search(r"(?:(?P<int>invalid literal for int\(\) with base 10)|could not convert string to float):"
                      r" '(?P<value>.*)'", str(err))
    if found is None:
        return str(err)
    keyword = next((line.split()[0] for line in lines if found["value"] in line.split()[1:]), "a line")
    return f"{keyword.upper()}: {found['value']!r} is not a {'whole ' * bool(found['int'])}number"


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
