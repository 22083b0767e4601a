"""A loopback-only bridge that lets other processes on this machine join a python-can bus of this process.

python-can's ``virtual`` bus lives inside one process. ``python-can-remote`` serves a bus over a WebSocket:
its :class:`can_remote.RemoteServer` opens, for every client that connects, a bus of the interface and channel
it was started with, and relays frames both ways; a client uses python-can's ``remote`` interface with the
server's address as channel. A simulator runs the server on its own virtual channel, so a master in another
process reaches the simulated nodes through ``remote`` on ``127.0.0.1:PORT``.

The server is bound to a loopback address only (127.0.0.0/8, ::1 or "localhost"); anything else is refused.
No multicast is involved.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from starterbus.core.errors import TransportError
from starterbus.core.plugin import RunningSimulator
from starterbus.core.textinput import check_loopback, parse_host_port

DEFAULT_PORT = 54701  # python-can-remote's default


def parse_bridge_address(text: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[::1]:PORT``; the host must be a loopback address."""
    host, port = parse_host_port(text, option="bridge address", bare_port=True)
    check_loopback(host, "the CAN bridge")
    return host, port


class LoopbackBridge(RunningSimulator):
    """A python-can-remote server for ``interface``/``channel`` on a loopback address (port 0: any free one).

    ``label`` starts the line :meth:`describe` prints; ``client_url`` (with ``{address}``) says how a client
    of the plugin using the bridge connects.
    """

    def __init__(
        self,
        interface: str,
        channel: str,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        *,
        label: str = "CAN bridge",
        client_url: str = "remote/{address}",
    ) -> None:
        check_loopback(host, "the CAN bridge")
        try:
            from can_remote import RemoteServer
        except ImportError as exc:  # pragma: no cover - installed with the "remote" extra
            raise TransportError("the loopback bridge needs python-can-remote (pip install python-can-remote)") from exc
        logging.getLogger("can_remote").setLevel(logging.WARNING)
        config: dict[str, Any] = {"interface": interface, "channel": channel}
        try:
            self.server = RemoteServer(host, port, **config)
        except OSError as exc:
            raise TransportError(f"cannot listen on {host}:{port} for the {label}: {exc}") from exc
        self.host = host
        self.port = int(self.server.server_port)
        self.interface = interface
        self.channel = channel
        self.label = label
        self.client_url = client_url
        self._thread = threading.Thread(target=self.server.serve_forever, name="can-bridge", daemon=True)
        self._thread.start()

    @property
    def address(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def describe(self) -> list[str]:
        return [
            f"{self.label}: ws://{self.address}/ serves {self.interface}/{self.channel} to this machine only; "
            f"connect with {self.client_url.format(address=self.address)}"
        ]

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(2.0)


__all__ = ["DEFAULT_PORT", "LoopbackBridge", "parse_bridge_address"]
