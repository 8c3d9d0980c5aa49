"""Named columns, the form every reader returns and every writer takes.

Reading: a table's columns by name (:func:`_named_columns`), colours to 8 or 16 bits.
Writing: attributes checked against the points (:func:`_validated`), flattened into (N,)
columns in a dtype files store (:func:`_flat_columns`), and text rows that read back exactly.
"""

from __future__ import annotations

import re
from typing import BinaryIO, Callable, Mapping

import numpy as np

from hgjax.io._errors import PointCloudReadError

_COLOR_NAMES = (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"))


_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))


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


def _check_unique(names: list[str]) -> None:
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"attributes would be written to the same column names {repeated}; rename them")


def _validated(points, attributes: Mapping[str, np.ndarray] | None, scores) -> tuple[np.ndarray, dict]:
    """Points (N, 3) and attributes (each (N,) or (N, C), ``colors`` (N, 3|4), ``normals`` (N, 3))."""
    from hgjax import _validate

    pts = np.asarray(_validate.check_points(points, empty=True))
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
