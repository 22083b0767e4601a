"""DeviceNet CAN identifiers: message groups 1-4, their message ids and MAC ids (build and parse).

Layout (11-bit identifier)::

    group 1  0 MMMM SSSSSS    (message id << 6) | source MAC            0x000-0x3FF
    group 2  10 SSSSSS MMM    0x400 | (MAC << 3) | message id           0x400-0x5FF
    group 3  11 MMM SSSSSS    0x600 | (message id << 6) | source MAC    0x600-0x7BF (message id 0-6)
    group 4  11111 MMMMMM     0x7C0 | message id                        0x7C0-0x7EF (0x7F0-0x7FF invalid)

In the Predefined Master/Slave Connection Set the MAC field of every group 1 and group 2 identifier is the
slave's (the master addresses a slave through the identifier and names itself in the explicit header).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from starterbus.core import DecodeError, EncodeError

MAX_MAC = 63


class Group(enum.IntEnum):
    GROUP_1 = 1
    GROUP_2 = 2
    GROUP_3 = 3
    GROUP_4 = 4


class Group1(enum.IntEnum):
    """Group 1 message ids used by the Predefined Master/Slave Connection Set (the rest are free)."""

    MULTICAST_POLL_RESPONSE = 12
    COS_CYCLIC = 13
    BIT_STROBE_RESPONSE = 14
    POLL_RESPONSE = 15


class Group2(enum.IntEnum):
    """Group 2 message ids (all of them are predefined)."""

    BIT_STROBE_COMMAND = 0
    MULTICAST_POLL_COMMAND = 1
    COS_CYCLIC_ACK = 2
    SLAVE_EXPLICIT_RESPONSE = 3  # also the unconnected response
    MASTER_EXPLICIT_REQUEST = 4
    POLL_COMMAND = 5
    UNCONNECTED_REQUEST = 6  # group 2 only unconnected explicit request port
    DUPLICATE_MAC_CHECK = 7


GROUP1_NAMES = {
    Group1.MULTICAST_POLL_RESPONSE: "slave multicast poll response",
    Group1.COS_CYCLIC: "slave change-of-state/cyclic message",
    Group1.BIT_STROBE_RESPONSE: "slave bit-strobe response",
    Group1.POLL_RESPONSE: "slave poll response (input assembly)",
}
GROUP2_NAMES = {
    Group2.BIT_STROBE_COMMAND: "master bit-strobe command",
    Group2.MULTICAST_POLL_COMMAND: "master multicast poll command",
    Group2.COS_CYCLIC_ACK: "master change-of-state/cyclic acknowledge",
    Group2.SLAVE_EXPLICIT_RESPONSE: "slave explicit/unconnected response",
    Group2.MASTER_EXPLICIT_REQUEST: "master explicit request",
    Group2.POLL_COMMAND: "master poll command (output assembly)",
    Group2.UNCONNECTED_REQUEST: "group 2 only unconnected explicit request",
    Group2.DUPLICATE_MAC_CHECK: "duplicate MAC ID check",
}

_MESSAGE_ID_LIMITS = {Group.GROUP_1: 15, Group.GROUP_2: 7, Group.GROUP_3: 6, Group.GROUP_4: 0x2F}


@dataclass(frozen=True, slots=True)
class DeviceNetId:
    """A parsed identifier. ``mac`` is None for group 4 (no MAC field)."""

    group: Group
    message_id: int
    mac: int | None

    @property
    def can_id(self) -> int:
        return build_id(self.group, self.message_id, self.mac)

    def describe(self) -> str:
        if self.group is Group.GROUP_1:
            name = GROUP1_NAMES.get(Group1(self.message_id)) if self.message_id in Group1._value2member_map_ else None
        elif self.group is Group.GROUP_2:
            name = GROUP2_NAMES[Group2(self.message_id)]
        else:
            name = None
        where = f", MAC {self.mac}" if self.mac is not None else ""
        text = f"group {int(self.group)} message id {self.message_id}{where}"
        return f"{text}: {name}" if name else text


def _check(name: str, value: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
        raise EncodeError(f"{value!r} is outside 0..{hi}", field=name)


def build_id(group: Group | int, message_id: int, mac: int | None = None) -> int:
    """The 11-bit identifier of a group, message id and (groups 1-3) MAC id."""
    group = Group(group)
    _check("message_id", message_id, _MESSAGE_ID_LIMITS[group])
    if group is Group.GROUP_4:
        if mac is not None:
            raise EncodeError("group 4 identifiers carry no MAC id", field="mac")
        return 0x7C0 | message_id
    if mac is None:
        raise EncodeError(f"group {int(group)} identifiers need a MAC id", field="mac")
    _check("mac", mac, MAX_MAC)
    if group is Group.GROUP_1:
        return (message_id << 6) | mac
    if group is Group.GROUP_2:
        return 0x400 | (mac << 3) | message_id
    return 0x600 | (message_id << 6) | mac


def parse_id(can_id: int) -> DeviceNetId:
    """Split an identifier into group, message id and MAC; 0x7F0-0x7FF and non-11-bit values are refused."""
    if isinstance(can_id, bool) or not isinstance(can_id, int) or not 0 <= can_id <= 0x7FF:
        raise DecodeError(f"{can_id!r} is not an 11-bit CAN identifier", field="can_id")
    if can_id < 0x400:
        return DeviceNetId(Group.GROUP_1, can_id >> 6, can_id & 0x3F)
    if can_id < 0x600:
        return DeviceNetId(Group.GROUP_2, can_id & 0x07, (can_id >> 3) & 0x3F)
    if can_id < 0x7C0:
        return DeviceNetId(Group.GROUP_3, (can_id >> 6) & 0x07, can_id & 0x3F)
    if can_id < 0x7F0:
        return DeviceNetId(Group.GROUP_4, can_id & 0x3F, None)
    raise DecodeError(f"identifier 0x{can_id:03X} is in the invalid range 0x7F0-0x7FF", field="can_id")


# -- the Predefined Master/Slave Connection Set, by slave MAC -------------------------------------------------


def poll_response_id(slave: int) -> int:
    return build_id(Group.GROUP_1, Group1.POLL_RESPONSE, slave)


def poll_command_id(slave: int) -> int:
    return build_id(Group.GROUP_2, Group2.POLL_COMMAND, slave)


def explicit_request_id(slave: int) -> int:
    return build_id(Group.GROUP_2, Group2.MASTER_EXPLICIT_REQUEST, slave)


def explicit_response_id(slave: int) -> int:
    return build_id(Group.GROUP_2, Group2.SLAVE_EXPLICIT_RESPONSE, slave)


def unconnected_request_id(slave: int) -> int:
    return build_id(Group.GROUP_2, Group2.UNCONNECTED_REQUEST, slave)


def duplicate_mac_id(mac: int) -> int:
    return build_id(Group.GROUP_2, Group2.DUPLICATE_MAC_CHECK, mac)
