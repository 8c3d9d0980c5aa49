"""Atomic writes: a temporary file beside the target renamed onto it, and the removal of stale temporaries."""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import socket
from typing import BinaryIO, Callable

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
