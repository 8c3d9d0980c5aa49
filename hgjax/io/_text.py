"""XYZ/TXT text columns: the header line, the separator, integer columns read exactly; the writer."""

from __future__ import annotations

import re
import warnings
from typing import BinaryIO, Callable

import numpy as np

from hgjax.io._columns import _flat_columns, _named_columns, _savetxt
from hgjax.io._errors import PointCloudReadError

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


_NOT_A_NUMBER = re.compile(r"could not convert string (?P<token>.*) to \w+ at row (?P<row>\d+), column (?P<column>\d+)")
_COLUMNS_CHANGED = re.compile(r"the number of columns changed from (?P<before>\d+) to (?P<after>\d+) at row"
                              r" (?P<row>\d+)")


def _line(path: str, skip: int, row: int) -> int:
    """The file's line, counted from 1 as an editor counts, of data row ``row`` (counted from 0 after
    ``skip`` lines, comment and blank lines left out, as NumPy reads them)."""
    line = skip
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for _ in range(skip):
            fh.readline()
        for text in fh:
            line += 1
            if _INLINE_COMMENT.split(text, maxsplit=1)[0].strip():
                if row == 0:
                    break
                row -= 1
    return line


def _on_its_line(err: ValueError, path: str, skip: int) -> Exception:
    """NumPy's "at row R" (a token that is not a number: R counts data rows from 0; a row of another
    number of values: from 1) said as the file's line (:func:`_line`): a PointCloudReadError; other
    errors as they are."""
    found = _NOT_A_NUMBER.search(str(err))
    if found is not None:
        return PointCloudReadError(f"cannot read {path}: line {_line(path, skip, int(found['row']))}, column"
                                   f" {found['column']}: {found['token']} is not a number")
    found = _COLUMNS_CHANGED.search(str(err))
    if found is not None:
        return PointCloudReadError(f"cannot read {path}: line {_line(path, skip, int(found['row']) - 1)} has"
                                   f" {found['after']} values where the lines before it have {found['before']}")
    return err


def _read_text(path: str, samples: int = 0, seed: int = 0) -> tuple[dict[str, np.ndarray], None, bool]:
    names, skip, delimiter, row = _text_layout(path)
    with open(path, encoding="utf-8-sig", errors="replace") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.loadtxt warns on files without data rows
        try:
            table = np.loadtxt(fh, comments=("#", "//"), delimiter=delimiter, ndmin=2, skiprows=skip)
        except ValueError as err:
            raise _on_its_line(err, path, skip) from None
    columns = _named_columns(table, names, path)
    written_as_integers = [j for j, name in enumerate(columns) if name.lower() not in ("x", "y", "z")
                           and j < len(row) and re.fullmatch(r"[+-]?\d+", row[j])]
    for j, values in _integer_columns(path, table, written_as_integers, skip, delimiter).items():
        columns[list(columns)[j]] = values
    return columns, None, False


def _text_writer(points, attributes, header, binary: bool, compressed: bool) -> Callable[[BinaryIO], None]:
    columns = _flat_columns(points, attributes)
    return lambda fh: _savetxt(fh, columns, " ".join(name for name, _ in columns))
