"""systemd's service notification protocol (``sd_notify(3)``), without a dependency: each message is one datagram of
``KEY=VALUE`` lines sent to the unix socket named by ``$NOTIFY_SOCKET`` (a path, or ``@NAME`` in the abstract
namespace). Outside systemd (no ``$NOTIFY_SOCKET``) every call does nothing.

``$WATCHDOG_USEC`` (with ``WatchdogSec=`` in the unit) asks for ``WATCHDOG=1`` at least that often;
``$WATCHDOG_PID``, when set, names the process it is meant for.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger("starterbus.service")


class SystemdNotifier:
    def __init__(self, address: str | None, watchdog_usec: int | None = None) -> None:
        self.address = address or None
        #: seconds within which systemd wants a ``WATCHDOG=1`` (None: no watchdog asked for)
        self.watchdog: float | None = watchdog_usec / 1e6 if watchdog_usec else None
        self._socket: socket.socket | None = None
        self._failed = False

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> SystemdNotifier:
        env = os.environ if environ is None else environ
        usec: int | None = None
        pid = env.get("WATCHDOG_PID", "")
        if not pid or pid == str(os.getpid()):
            try:
                usec = int(env.get("WATCHDOG_USEC", "")) or None
            except ValueError:
                usec = None
        return cls(env.get("NOTIFY_SOCKET"), usec)

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def notify(self, *lines: str) -> bool:
        """Send ``lines`` (``READY=1``, ``STATUS=...``) as one message; False when not sent. A failure is logged
        once and never raised: a supervisor that went away must not stop the service."""
        if self.address is None:
            return False
        target = "\0" + self.address[1:] if self.address.startswith("@") else self.address
        try:
            if self._socket is None:
                self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._socket.sendto("\n".join(lines).encode("utf-8", "replace"), target)
        except OSError as exc:
            if not self._failed:
                log.warning("cannot notify systemd at %s: %s", self.address, exc)
                self._failed = True
            return False
        return True

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None
