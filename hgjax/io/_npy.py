"""NumPy ``.npy`` files: a plain (N, 3 + C) array or an (N,) structured one, read and written back alike."""

from __future__ import annotations

import math
from typing import BinaryIO, Callable

import numpy as np

from hgjax.io._columns import _flat_columns, _named_columns, _native_column
from hgjax.io._errors import PointCloudReadError


def _read_npy(path: str) -> tuple[dict[str, np.ndarray], np.dtype | None]:
    """(columns, the dtype of a plain (N, C) array or None for a structured one) of a .npy file."""
    array = np.load(path, allow_pickle=False)
    if array.dtype.names:
        if array.ndim != 1:
            raise PointCloudReadError(f"cannot read {path}: expected a structured array of shape (N,); got shape"
                                      f" {array.shape}")
        return {name: np.asarray(array[name]).reshape(array.shape[0], math.prod(array.dtype[name].shape)).squeeze(1)
                for name in array.dtype.names}, None
    if array.dtype.kind not in "fiu":
        raise PointCloudReadError(f"cannot read {path}: expected a numeric (N, 3) array; got dtype {array.dtype}")
    if array.ndim != 2:
        raise PointCloudReadError(f"cannot read {path}: expected a numeric array of shape (N, 3) or (N, 3 + C);"
                                  f" got shape {array.shape}")
    return _named_columns(array, None, path), array.dtype


def _npy_reader(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], np.dtype | None, bool]:
    return (*_read_npy(path), False)  # _read_npy is looked up here, when called (tests wrap it)


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
