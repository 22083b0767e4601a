"""A loopback-only bridge that lets other processes on this machine join a python-can bus of this process.

python-can's ``virtual`` bus lives inside one process. ``python-can-remote`` serves a bus over a WebSocket:
its :class:`can_remote.RemoteServer` opens, for every client that connects, a bus of the interface and channel
it was started with, and relays frames both ways; a client uses python-can's ``remote`` interface with the
server's address as channel. The simulator runs the server on its own virtual channel, so a master in another
process reaches the simulated slaves with ``devicenet://remote/127.0.0.1:PORT?mac=5``.

The server is bound to a loopback address only (127.0.0.0/8, ::1 or "localhost"); anything else is refused.
No multicast is involved.
"""

from __future__ import annotations

import ipaddress
import logging
import threading
from typing import Any

from starterbus.core.errors import ConfigurationError, TransportError
from starterbus.core.transport import RunningSimulator

DEFAULT_PORT = 54701  # python-can-remote's default


def parse_bridge_address(text: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[::1]:PORT``; the host must be a loopback address."""
    text = text.strip()
    host, port_text = "127.0.0.1", text
    if text.startswith("["):
        end = text.find("]")
        if end < 0 or text[end + 1 : end + 2] != ":":
            raise ConfigurationError(f"bridge address {text!r} is not [HOST]:PORT")
        host, port_text = text[1:end], text[end + 2 :]
    elif ":" in text:
        host, _, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        raise ConfigurationError(f"bridge address {text!r}: {port_text!r} is not a port number") from None
    if not 0 <= port <= 65535:
        raise ConfigurationError(f"bridge address {text!r}: port {port} is outside 0..65535")
    check_loopback(host)
    return host, port


def check_loopback(host: str) -> None:
    if host == "localhost":
        return
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        raise ConfigurationError(f"bridge host {host!r} is not an IP address or 'localhost'") from None
    if not address.is_loopback:
        raise ConfigurationError(
            f"bridge host {host} is not a loopback address: the DeviceNet bridge only serves this machine "
            "(use 127.0.0.1 or ::1)"
        )


class LoopbackBridge(RunningSimulator):
    """A python-can-remote server for ``interface``/``channel`` on a loopback address (port 0: any free one)."""

    def __init__(self, interface: str, channel: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> None:
        check_loopback(host)
        try:
            from can_remote import RemoteServer
        except ImportError as exc:  # pragma: no cover - installed with the "remote" extra
            raise TransportError("the loopback bridge needs python-can-remote (pip install python-can-remote)") from exc
        logging.getLogger("can_remote").setLevel(logging.WARNING)
        config: dict[str, Any] = {"interface": interface, "channel": channel}
        try:
            self.server = RemoteServer(host, port, **config)
        except OSError as exc:
            raise TransportError(f"cannot listen on {host}:{port} for the DeviceNet bridge: {exc}") from exc
        self.host = host
        self.port = int(self.server.server_port)
        self.interface = interface
        self.channel = channel
        self._thread = threading.Thread(target=self.server.serve_forever, name="devicenet-bridge", daemon=True)
        self._thread.start()

    @property
    def address(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def describe(self) -> list[str]:
        return [
            f"devicenet bridge: ws://{self.address}/ serves {self.interface}/{self.channel} to this machine only; "
            f"connect with devicenet://remote/{self.address}?mac=N"
        ]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(2.0)
