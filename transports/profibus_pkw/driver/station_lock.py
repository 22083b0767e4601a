"""One master per station on this machine: a lock file per gateway station, held while a channel is open.

A PKW request carries no master id, and its answer does not say which data area it answers: a second program
writing the same station's output words (a `starterbus read` beside a running `serve`) gets the answer to the
other's task, e.g. a measurement for the parameter of the same number (seen: `current_limit` read as 0 % while
`serve` polled the currents). Nothing on the wire can tell, so programs on one machine keep out of each other's
way: the first to open a station holds an exclusive ``flock`` on ``pkw-HOST-PORT-uUNIT-oOUT.lock`` in
:func:`lock_dir`, and another program's open is refused with one line naming the holder's pid. Channels in one
process share the hold (the fleet and its jobs share a device; a process that opens one station twice is its
own business). A master on another machine (a PLC, a second gateway client) is not seen; see docs/profibus.md.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import tempfile
import threading
from pathlib import Path

from starterbus.core import TransportError

LOCK_DIR_ENV = "STARTERBUS_LOCK_DIR"

log = logging.getLogger("starterbus.transports.profibus_pkw")

_held: dict[str, tuple[int, int]] = {}  # lock file -> (descriptor, channels of this process holding it)
_guard = threading.Lock()


def lock_dir() -> Path:
    """``$STARTERBUS_LOCK_DIR``, else ``/dev/shm/starterbus-stations`` (one place for every user and service: a
    systemd unit's ``PrivateTmp`` hides /tmp, not /dev/shm), else ``$TMPDIR/starterbus-stations``."""
    if os.environ.get(LOCK_DIR_ENV):
        return Path(os.environ[LOCK_DIR_ENV])
    shm = Path("/dev/shm")
    return (shm if shm.is_dir() else Path(tempfile.gettempdir())) / "starterbus-stations"


def station_name(host: str, port: int, unit: int, out: int) -> str:
    return f"pkw-{re.sub(r'[^A-Za-z0-9.-]', '_', host)}-{port}-u{unit}-o{out}.lock"


def hold_station(host: str, port: int, unit: int, out: int, what: str) -> str | None:
    """Hold the station for this process (again: one more holder); returns the key for :func:`release_station`,
    or None where no lock can be taken (no ``fcntl``, a lock folder this user cannot write: logged). Raises
    :class:`TransportError` when another program holds it."""
    if sys.platform == "win32":
        return None
    import fcntl

    path = lock_dir() / station_name(host, port, unit, out)
    key = str(path)
    with _guard:
        if key in _held:
            fd, count = _held[key]
            _held[key] = (fd, count + 1)
            return key
        try:
            _shared_folder(path.parent)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            if os.fstat(fd).st_uid == os.getuid():
                os.fchmod(fd, 0o666)  # another user's program must be able to open it to ask (the umask took w)
        except OSError as exc:
            log.warning("%s: cannot check that no other program on this machine uses it (%s: %s)", what, path, exc)
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "a process"
            os.close(fd)
            raise TransportError(
                f"{what} is in use by another program on this machine ({holder}): one master per station, "
                "as a PKW answer does not say whose request it answers; ask that program (serve's web page, OPC UA "
                "or MQTT) or stop it first"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}".encode(), 0)
        _held[key] = (fd, 1)
        return key


def _shared_folder(folder: Path) -> None:
    """The lock folder, made for every user (mode 1777 whatever the umask) if it is not there."""
    try:
        folder.mkdir(parents=True)
    except FileExistsError:
        return
    os.chmod(folder, 0o1777)


def release_station(key: str | None) -> None:
    if key is None:
        return
    with _guard:
        fd, count = _held.pop(key, (-1, 0))
        if count > 1:
            _held[key] = (fd, count - 1)
        elif fd >= 0:
            os.close(fd)  # the lock goes with the descriptor
