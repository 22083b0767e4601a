"""Files starterbus writes for a user (backups, users files): checked before any work, never clobbered unless
asked, never left half-written.

:func:`check_target` runs before the device is touched; :func:`write_atomically` writes a temporary file in the
same directory and renames it over the target, so a reader sees the old file or the new one, never a part.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path

from starterbus.core.errors import ConfigurationError


def check_target(path: str | Path, *, force: bool = False, option: str = "-o", what: str = "file") -> Path:
    """Refuse ``path`` before any work: an existing file (unless ``force``), a directory, a missing or read-only
    directory. ``option`` and ``what`` name it in the one-line error."""
    target = Path(path)
    if target.is_dir():
        raise ConfigurationError(f"{option} {target}: is a directory, not a {what}")
    if target.exists() and not force:
        raise ConfigurationError(
            f"{option} {target}: the file exists; nothing done (give --force to replace it, or another {option} FILE)"
        )
    parent = target.parent
    if not parent.is_dir():
        raise ConfigurationError(f"{option} {target}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigurationError(f"{option} {target}: directory {parent} is not writable")
    return target


def write_atomically(path: str | Path, text: str, *, replace: bool = False, mode: int = 0o666) -> None:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file and a rename.

    Without ``replace`` an existing ``path`` (one that appeared since :func:`check_target`) is left alone and
    refused. ``mode`` is masked by the umask; 0o600 keeps secrets private from the first byte.
    """
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        if replace:
            os.replace(tmp, target)
        else:
            _link_new(tmp, target)
    except OSError as exc:
        raise ConfigurationError(f"{target}: cannot write: {exc.strerror or exc}; nothing written") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def _link_new(tmp: Path, target: Path) -> None:
    """``tmp`` becomes ``target`` only if ``target`` does not exist (a hard link fails on an existing name)."""
    try:
        os.link(tmp, target)
    except FileExistsError:
        raise ConfigurationError(
            f"{target}: the file appeared while this ran; nothing written (give --force to replace it)"
        ) from None
    except OSError:  # a file system without hard links: the check is then as good as the moment allows
        if target.exists():
            raise ConfigurationError(
                f"{target}: the file appeared while this ran; nothing written (give --force to replace it)"
            ) from None
        os.replace(tmp, target)


__all__ = ["check_target", "write_atomically"]
