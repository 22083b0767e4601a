"""Where python-can meets the codec: opening a bus by interface/channel, and CanFrame <-> can.Message.

Everything else in the transport sees :class:`~starterbus.transports.devicenet.frames.CanFrame` only.
"""

from __future__ import annotations

from typing import Any

import can

from starterbus.core.errors import ConfigurationError, TransportError
from starterbus.transports.devicenet.frames import CanFrame

#: interfaces that take no bitrate argument (software buses)
_NO_BITRATE = {"virtual", "remote", "udp_multicast"}


def open_bus(interface: str, channel: str, bitrate: int | None = None, **options: Any) -> can.BusABC:
    """A python-can bus; any failure becomes a :class:`TransportError` naming interface and channel."""
    if not interface or not channel:
        raise ConfigurationError(f"a CAN bus needs an interface and a channel (got {interface!r}, {channel!r})")
    if interface == "udp_multicast":
        raise ConfigurationError("the udp_multicast interface is not used: bridge processes over loopback (remote)")
    kwargs: dict[str, Any] = dict(options)
    if bitrate is not None and interface not in _NO_BITRATE:
        kwargs["bitrate"] = bitrate
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError, TypeError) as exc:
        raise TransportError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from exc
    except Exception as exc:  # e.g. python-can-remote's RemoteError, websocket errors
        raise TransportError(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}") from exc


def to_message(frame: CanFrame) -> can.Message:
    return can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=False)


def from_message(message: can.Message) -> CanFrame | None:
    """The frame of a received message, or None for what DeviceNet does not use (extended, remote, error, FD)."""
    if message.is_extended_id or message.is_remote_frame or message.is_error_frame or message.is_fd:
        return None
    if message.arbitration_id > 0x7FF or message.dlc > 8:
        return None
    return CanFrame(message.arbitration_id, bytes(message.data))


def shutdown(bus: can.BusABC) -> None:
    try:
        bus.shutdown()
    except Exception:
        pass
