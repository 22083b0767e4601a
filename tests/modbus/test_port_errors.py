"""A port pyserial cannot set up is one typed error naming it, whatever pyserial lets out."""

from __future__ import annotations

import os
import pty
import termios
from collections.abc import Iterator

import pytest

from starterbus.core.errors import TransportError
from starterbus.transports.modbus.driver.link import SerialSettings, open_pyserial


@pytest.fixture
def pty_path() -> Iterator[str]:
    master, slave = pty.openpty()
    try:
        yield os.ttyname(slave)
    finally:
        os.close(slave)
        os.close(master)


def test_a_termios_refusal_is_a_transport_error_naming_the_port(pty_path: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """pyserial lets termios.error (no OSError) out of its last tcsetattr: Linux refuses, for one, even parity
    on a pty reopened after no parity (EINVAL)."""

    def refuse(*_: object) -> None:
        raise termios.error(22, "Invalid argument")

    monkeypatch.setattr(termios, "tcsetattr", refuse)
    with pytest.raises(TransportError, match=f"cannot open serial port {pty_path} .*Invalid argument"):
        open_pyserial(pty_path, SerialSettings(baudrate=19200, parity="E", stopbits=1)).close()
