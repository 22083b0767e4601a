"""Parsers of what users type that every transport needs: ``HOST:PORT`` addresses and hex bytes.

Both raise only the project's typed errors, naming the text (and the option, when given).
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence

from starterbus.core.errors import ConfigurationError, DecodeError


def parse_host_port(
    text: str, *, default_host: str = "127.0.0.1", option: str = "", bare_port: bool = False
) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT`` or ``:PORT`` (the default host); with ``bare_port`` also ``PORT`` alone.

    PORT 0 means any free port. ``option`` names the flag or key in the error.
    """
    raw = text.strip()
    where = f"{option} {text!r}" if option else repr(text)
    host, port_text = default_host, raw
    if raw.startswith("["):
        end = raw.find("]")
        if end < 0 or raw[end + 1 : end + 2] != ":":
            raise ConfigurationError(f"{where} is not [HOST]:PORT")
        host, port_text = raw[1:end], raw[end + 2 :]
    elif ":" in raw:
        host, _, port_text = raw.rpartition(":")
        host = host or default_host
    elif not bare_port:
        raise ConfigurationError(f"{where} is not HOST:PORT (e.g. 127.0.0.1:5020; PORT 0 = any free port)")
    if not port_text.isdigit():
        raise ConfigurationError(f"{where}: {port_text!r} is not a port number")
    port = int(port_text)
    if not 0 <= port <= 0xFFFF:
        raise ConfigurationError(f"{where}: port {port} is outside 0..65535")
    return host, port


def check_loopback(host: str, what: str = "this service") -> None:
    """Refuse a host that is not a loopback address (127.0.0.0/8, ::1 or ``localhost``)."""
    if host == "localhost":
        return
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        raise ConfigurationError(f"{what}: host {host!r} is not an IP address or 'localhost'") from None
    if not address.is_loopback:
        raise ConfigurationError(
            f"{what}: host {host} is not a loopback address: it only serves this machine (use 127.0.0.1 or ::1)"
        )


def parse_hex(tokens: Sequence[str]) -> bytes:
    """``["02", "03 01", "0x00"]`` -> bytes; spaces, commas, colons and 0x prefixes are allowed."""
    text = " ".join(tokens).replace(",", " ").replace(":", " ")
    digits = "".join(t[2:] if t.lower().startswith("0x") else t for t in text.split())
    if len(digits) % 2:
        raise DecodeError(f"{len(digits)} hex digits is not a whole number of bytes: {' '.join(tokens)!r}")
    try:
        return bytes.fromhex(digits)
    except ValueError:
        raise DecodeError(f"not hex bytes: {' '.join(tokens)!r}") from None


__all__ = ["check_loopback", "parse_hex", "parse_host_port"]
