"""Host names looked up outside the I/O loop: a slow or dead name server never holds every line of the process.

:func:`address_of` looks a name up in the calling thread (a device's open, a blocking caller) and keeps the
answer. :func:`kept_address`, which the loop's connects and reconnects use (``tcp.start_connect``), never waits on
a name server: it gives the kept address, or looks the name up in a thread of its own (:func:`look_up_later`) and
says it has none yet. After a connection to a name fails, the name is looked up again the
same way, the kept address staying in use until the answer comes, so a device server given another address is
found again without a restart. A numeric address needs no name server and is taken at once.
"""

from __future__ import annotations

import ipaddress
import socket
import threading
from typing import Any

__all__ = ["Address", "address_of", "forget_addresses", "kept_address", "look_up_later"]

#: what a connect needs: family, socket type, protocol, socket address
Address = tuple[socket.AddressFamily, socket.SocketKind, int, Any]

_lock = threading.Lock()
_kept: dict[tuple[str, int], Address] = {}
_looking: set[tuple[str, int]] = set()
_failed: dict[tuple[str, int], str] = {}  # the last lookup's error, while nothing is kept


def _numeric(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def _look_up(host: str, port: int) -> Address:
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    return family, kind, proto, address


def address_of(host: str, port: int) -> Address:
    """The address to connect to for ``host:port``: the kept one, else looked up now (blocking) and kept. An
    :class:`OSError` if the name cannot be looked up."""
    key = (host, port)
    kept = _kept.get(key)
    if kept is not None:
        return kept
    address = _look_up(host, port)
    if not _numeric(host):
        _keep(key, address)
    return address


def _keep(key: tuple[str, int], address: Address) -> None:
    with _lock:
        _kept[key] = address
        _failed.pop(key, None)


def kept_address(host: str, port: int) -> Address:
    """The address to connect to, without waiting on a name server (the I/O loop's): the kept one, a numeric
    address at once, else an :class:`OSError` saying the name is being looked up (in a thread of its own)."""
    kept = _kept.get((host, port))
    if kept is not None:
        return kept
    if _numeric(host):
        return _look_up(host, port)
    look_up_later(host, port)
    why = _failed.get((host, port))
    raise OSError(f"looking up {host!r}" + (f" (the last lookup: {why})" if why else ""))


def look_up_later(host: str, port: int) -> None:
    """Look ``host`` up again in a thread of its own (one at a time per name); the kept address, if any, stays in
    use until the answer comes."""
    key = (host, port)
    if _numeric(host):
        return
    with _lock:
        if key in _looking:
            return
        _looking.add(key)
    threading.Thread(target=_look_up_now, args=key, name=f"starterbus-lookup {host}", daemon=True).start()


def _look_up_now(host: str, port: int) -> None:
    key = (host, port)
    try:
        address = _look_up(host, port)
    except OSError as exc:
        with _lock:
            _failed[key] = str(exc)
    else:
        _keep(key, address)
    finally:
        with _lock:
            _looking.discard(key)


def forget_addresses() -> None:
    """Forget every kept address (tests)."""
    with _lock:
        _kept.clear()
        _failed.clear()
