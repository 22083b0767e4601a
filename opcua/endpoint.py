"""The OPC UA endpoint a server listens on: ``opc.tcp://HOST:PORT[/PATH]`` checked, and a busy port said in one
line (asyncua logs its own traceback of a failed start; that record is dropped, the error is raised typed).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from urllib.parse import urlsplit

from starterbus.core.errors import ConfigurationError
from starterbus.core.textinput import listen_error

_ASYNCUA_SERVER_LOG = "asyncua.server.server"


def parse_endpoint(text: str) -> tuple[str, int]:
    """HOST and PORT of ``opc.tcp://HOST:PORT`` (a path after it is allowed); anything else is refused."""
    example = "e.g. opc.tcp://0.0.0.0:4840/starterbus; PORT 0 = any free port"
    wrong = ConfigurationError(f"OPC UA endpoint {text!r} is not opc.tcp://HOST:PORT ({example})")
    parts = urlsplit(text)
    if parts.scheme.lower() != "opc.tcp" or not parts.hostname or parts.query or parts.fragment:
        raise wrong
    try:
        port = parts.port
    except ValueError:
        raise wrong from None
    if port is None:
        raise wrong
    return parts.hostname, port


class _DropStartFailure(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.exc_info and "error starting server" in str(record.msg))


@contextmanager
def listening(host: str, port: int) -> Iterator[None]:
    """Around asyncua's ``Server.start()``: a port it cannot listen on is one :class:`ConfigurationError`."""
    logger = logging.getLogger(_ASYNCUA_SERVER_LOG)
    quiet = _DropStartFailure()
    logger.addFilter(quiet)
    try:
        yield
    except OSError as exc:
        raise listen_error("OPC UA endpoint", host, port, exc) from None
    finally:
        logger.removeFilter(quiet)


__all__ = ["listening", "parse_endpoint"]
