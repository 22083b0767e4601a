"""Opening a python-can bus: the one place a CAN transport or simulator meets python-can's constructors.

Any failure becomes a :class:`~starterbus.core.errors.TransportError` naming the interface and the channel;
software buses (``virtual``, ``remote``) get no bitrate. Importing this module imports python-can.

A ``virtual`` channel exists only inside one process: a master opening one that no other bus of this process
is on would wait for peers that cannot exist, so :func:`check_peer` refuses it at once with the caller's hint.
"""

from __future__ import annotations

from typing import Any

import can

from starterbus.core.errors import ConfigurationError, TransportError

#: interfaces that take no bitrate argument (software buses)
_NO_BITRATE = {"virtual", "remote", "udp_multicast"}


def check_peer(interface: str, channel: str, hint: str) -> None:
    """Refuse a ``virtual`` channel no other bus of this process is on (its peers could be nowhere else).

    Reads python-can's registry of virtual channels; without it (another python-can), nothing is checked.
    """
    if interface != "virtual":
        return
    try:
        from can.interfaces import virtual
    except ImportError:  # pragma: no cover - python-can without the virtual interface
        return
    channels = getattr(virtual, "channels", None)
    lock = getattr(virtual, "channels_lock", None)
    if not isinstance(channels, dict) or lock is None:
        return
    with lock:
        if channels.get(channel):
            return
    raise ConfigurationError(
        f"no other bus of this process is on virtual channel {channel!r}: a python-can virtual channel "
        f"exists only inside one process; {hint}"
    )


def open_bus(
    interface: str, channel: str, bitrate: int | None = None, needs_peer: str | None = None, **options: Any
) -> can.BusABC:
    """A python-can bus; any failure becomes a :class:`TransportError` naming interface and channel.

    ``needs_peer`` (a hint saying what to use instead): refuse a ``virtual`` channel with no other bus on it in
    this process (:func:`check_peer`).
    """
    if not interface or not channel:
        raise ConfigurationError(f"a CAN bus needs an interface and a channel (got {interface!r}, {channel!r})")
    if needs_peer is not None:
        check_peer(interface, channel, needs_peer)
    if interface == "udp_multicast":
        raise ConfigurationError("the udp_multicast interface is not used: bridge processes over loopback (remote)")
    kwargs: dict[str, Any] = dict(options)
    if bitrate is not None and interface not in _NO_BITRATE:
        kwargs["bitrate"] = bitrate
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except Exception as exc:  # CanError, OSError, ImportError, python-can-remote's RemoteError, websocket errors
        raise TransportError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from exc


def parse_bus_spec(text: str, option: str = "") -> tuple[str, str]:
    """``INTERFACE:CHANNEL`` (``virtual:bus0``, ``socketcan:can0``) -> (interface, channel)."""
    interface, sep, channel = str(text).partition(":")
    if not sep or not interface or not channel:
        where = f"{option} {text!r}" if option else repr(text)
        raise ConfigurationError(f"{where}: expected INTERFACE:CHANNEL, e.g. virtual:bus0")
    return interface, channel


def shutdown(bus: can.BusABC) -> None:
    """Shut a bus down, ignoring what a bus that is already gone raises."""
    try:
        bus.shutdown()
    except Exception:
        pass


__all__ = ["check_peer", "open_bus", "parse_bus_spec", "shutdown"]
