"""Where python-can meets the codec: CanFrame <-> can.Message (buses are opened by starterbus.core.canbus).

Everything else in the transport sees :class:`~starterbus.core.CanFrame` only.
"""

from __future__ import annotations

import can

from starterbus.core import CanFrame


def to_message(frame: CanFrame) -> can.Message:
    return can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=False)


def from_message(message: can.Message) -> CanFrame | None:
    """The frame of a received message, or None for what DeviceNet does not use (extended, remote, error, FD)."""
    if message.is_extended_id or message.is_remote_frame or message.is_error_frame or message.is_fd:
        return None
    if message.arbitration_id > 0x7FF or message.dlc > 8:
        return None
    return CanFrame(message.arbitration_id, bytes(message.data))
