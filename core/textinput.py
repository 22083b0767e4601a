"""What users type or write: ``HOST:PORT`` addresses, hex bytes, and the text files they edit.

Each raises only the project's typed errors, naming the text (and the option, when given) or the file, line and
byte.
"""

from __future__ import annotations

import codecs
import errno
import ipaddress
from collections.abc import Callable, Sequence
from pathlib import Path

from starterbus.core.errors import ConfigurationError, DecodeError, StarterbusError

#: the error a text file's problem raises: (file, what is wrong) -> the error
TextError = Callable[[str, str], StarterbusError]


def _configuration_error(source: str, detail: str) -> StarterbusError:
    return ConfigurationError(f"{source}: {detail}")


def read_text_file(path: str | Path, what: str = "file", *, error: TextError = _configuration_error) -> str:
    """The text of a file a user edits (fleet, backup, users, config, profile, script): UTF-8, a UTF-8 byte-order
    mark (as Windows editors write) dropped.

    Anything else raises ``error(file, detail)`` (a :class:`ConfigurationError` unless told) in one line: the
    file could not be read, or it is UTF-16, or the first byte that is not UTF-8 with its line, column and offset
    (a GBK or other ANSI code-page file is refused there, not guessed at).
    """
    source = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise error(source, f"cannot read the {what}: {exc.strerror or exc}") from None
    return decode_text(data, source, what, error=error)


def decode_text(data: bytes, source: str, what: str = "file", *, error: TextError = _configuration_error) -> str:
    """``data`` as :func:`read_text_file` decodes a file's bytes; ``source`` names the file in the error."""
    bom = 0
    if data.startswith(codecs.BOM_UTF8):
        bom = len(codecs.BOM_UTF8)
    elif data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        raise error(source, f"the {what} is UTF-16 (it starts with a UTF-16 byte-order mark): save it as UTF-8")
    try:
        return data[bom:].decode("utf-8")
    except UnicodeDecodeError as exc:
        offset = bom + exc.start
    line_start = data.rfind(b"\n", 0, offset) + 1
    line = data.count(b"\n", 0, offset) + 1
    column = len(data[max(line_start, bom) : offset].decode("utf-8")) + 1  # all before the bad byte is UTF-8
    raise error(
        source,
        f"line {line}, column {column} (byte offset {offset}): byte 0x{data[offset]:02X} is not UTF-8: save the "
        f"{what} as UTF-8 (with or without a byte-order mark; GBK and other code pages are not read)",
    ) from None


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


def listen_error(what: str, host: str, port: int, exc: OSError) -> ConfigurationError:
    """The one line for a server that cannot listen on ``host:port`` (``what`` names the server or option)."""
    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    if exc.errno == errno.EADDRINUSE:
        return ConfigurationError(
            f"{what} {where} is already in use (another program listens there): choose another port"
        )
    return ConfigurationError(f"{what} {where}: cannot listen there: {exc.strerror or exc}")


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


__all__ = [
    "TextError",
    "check_loopback",
    "decode_text",
    "listen_error",
    "parse_hex",
    "parse_host_port",
    "read_text_file",
]
