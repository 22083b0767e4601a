"""What went wrong under the history writer (ops/history_writer.py): a database that is not one any more,
and what the file system says about writing a file now."""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

__all__ = ["Corrupt", "file_system_view", "is_corrupt", "sqlite_error"]

_LOW_SPACE = 64 * 1024  # a file system with less than this free is called full


class Corrupt(Exception):
    """The database cannot be read as one (SQLite's CORRUPT or NOTADB)."""


def sqlite_error(exc: BaseException) -> sqlite3.Error | None:
    if isinstance(exc, sqlite3.Error):
        return exc
    cause = exc.__cause__
    return cause if isinstance(cause, sqlite3.Error) else None


def is_corrupt(exc: BaseException) -> bool:
    error = sqlite_error(exc)
    if error is None:
        return False
    name = getattr(error, "sqlite_errorname", "")
    text = str(error)
    return name in ("SQLITE_CORRUPT", "SQLITE_NOTADB") or "malformed" in text or "not a database" in text


def file_system_view(path: Path) -> str:
    """What the file system says about writing ``path`` now: read-only, full, the directory gone; or ''."""
    directory = path.parent
    try:
        st = os.statvfs(directory)
    except FileNotFoundError:
        return f"the directory {directory} is gone"
    except OSError as exc:
        return f"the directory {directory}: {exc.strerror or exc}"
    if st.f_flag & os.ST_RDONLY:
        return f"the file system of {directory} is read-only"
    free = st.f_bavail * st.f_frsize
    if free < _LOW_SPACE:
        return f"the file system of {directory} is full ({free // 1024} KiB free)"
    return ""
