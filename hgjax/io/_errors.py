"""The errors and warnings of :mod:`hgjax.io`, and the import of a format's optional packages.

The bottom of the package: every reader and writer raises these. The public classes are
re-exported by :mod:`hgjax.io` and name it as their module, so tracebacks, doctests and
pickles call them what users import.
"""

from __future__ import annotations

import importlib

_MODULES = {"las": ("laspy", "lazrs"), "pcd": ("pypcd4",)}


class PointCloudReadError(ValueError):
    """A file could not be read as a point cloud; the message names the file and the cause."""


class PointCloudNotFoundError(PointCloudReadError, FileNotFoundError):
    """The file to read does not exist (also a :class:`FileNotFoundError`)."""


class PointCloudWriteError(ValueError):
    """A point cloud cannot be written to a path; the message names the path and the cause."""


class NonFinitePointsWarning(UserWarning):
    """Points with NaN or inf coordinates were dropped while reading a file."""


for _cls in (PointCloudReadError, PointCloudNotFoundError, PointCloudWriteError, NonFinitePointsWarning):
    _cls.__module__ = "hgjax.io"
del _cls


def _require(extra: str, what: str) -> tuple:
    """Import the optional packages of ``extra`` (e.g. laspy and lazrs for ``las``)."""
    from hgjax import _validate

    try:
        return tuple(importlib.import_module(name) for name in _MODULES[extra])
    except ImportError as err:
        raise ImportError(f"{what} needs the optional package {err.name!r}: {_validate.install_hint(extra)}") from err
