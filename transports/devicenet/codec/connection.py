"""Vocabulary of the Predefined Master/Slave Connection Set shared by master and slave.

Allocation choice bits, Connection object (class 0x05) instances, states, attributes and watchdog actions,
DeviceNet object (class 0x03) attributes, and the expected packet rate (EPR) arithmetic.
"""

from __future__ import annotations

import enum
import math
import struct

from starterbus.core import EncodeError


class AllocationChoice(enum.IntFlag):
    EXPLICIT = 0x01
    POLLED = 0x02
    BIT_STROBE = 0x04
    MULTICAST_POLL = 0x08
    CHANGE_OF_STATE = 0x10
    CYCLIC = 0x20
    ACK_SUPPRESSION = 0x40
    RESERVED = 0x80


#: what the JJR8000 supports (manual 3.2.3: Polled and Explicit Message only)
SUPPORTED_CHOICE = AllocationChoice.EXPLICIT | AllocationChoice.POLLED
EXPLICIT_AND_POLLED = int(SUPPORTED_CHOICE)
UNALLOCATED_MASTER = 0xFF

CHOICE_NAMES = {
    AllocationChoice.EXPLICIT: "explicit",
    AllocationChoice.POLLED: "polled",
    AllocationChoice.BIT_STROBE: "bit-strobe",
    AllocationChoice.MULTICAST_POLL: "multicast poll",
    AllocationChoice.CHANGE_OF_STATE: "change of state",
    AllocationChoice.CYCLIC: "cyclic",
    AllocationChoice.ACK_SUPPRESSION: "acknowledge suppression",
    AllocationChoice.RESERVED: "reserved bit 7",
}


def describe_choice(choice: int) -> str:
    names = [name for bit, name in CHOICE_NAMES.items() if choice & bit]
    return " + ".join(names) if names else "none"


class ConnectionInstance(enum.IntEnum):
    EXPLICIT = 1
    POLLED = 2
    BIT_STROBE = 3
    COS_CYCLIC = 4
    MULTICAST_POLL = 5


class ConnectionState(enum.IntEnum):
    NON_EXISTENT = 0
    CONFIGURING = 1
    WAITING_FOR_CONNECTION_ID = 2
    ESTABLISHED = 3
    TIMED_OUT = 4
    DEFERRED_DELETE = 5


class WatchdogAction(enum.IntEnum):
    TRANSITION_TO_TIMED_OUT = 0  # I/O default
    AUTO_DELETE = 1  # explicit default
    AUTO_RESET = 2
    DEFERRED_DELETE = 3


class ConnectionAttribute(enum.IntEnum):
    STATE = 1
    INSTANCE_TYPE = 2
    TRANSPORT_CLASS_TRIGGER = 3
    PRODUCED_CONNECTION_ID = 4
    CONSUMED_CONNECTION_ID = 5
    INITIAL_COMM_CHARACTERISTICS = 6
    PRODUCED_CONNECTION_SIZE = 7
    CONSUMED_CONNECTION_SIZE = 8
    EXPECTED_PACKET_RATE = 9
    WATCHDOG_TIMEOUT_ACTION = 12
    PRODUCED_CONNECTION_PATH_LENGTH = 13
    PRODUCED_CONNECTION_PATH = 14
    CONSUMED_CONNECTION_PATH_LENGTH = 15
    CONSUMED_CONNECTION_PATH = 16
    PRODUCTION_INHIBIT_TIME = 17


CONNECTION_ATTRIBUTE_NAMES = {a.value: a.name.lower() for a in ConnectionAttribute}


class DeviceNetAttribute(enum.IntEnum):
    MAC_ID = 1
    BAUD_RATE = 2
    BUS_OFF_INTERRUPT = 3
    BUS_OFF_COUNTER = 4
    ALLOCATION_INFORMATION = 5


DEVICENET_ATTRIBUTE_NAMES = {a.value: a.name.lower() for a in DeviceNetAttribute}

#: DeviceNet object attribute 2 codes
BAUD_CODES = {125000: 0, 250000: 1, 500000: 2}

DEFAULT_EXPLICIT_EPR_MS = 2500  # the explicit connection's EPR at allocation
WATCHDOG_MULTIPLIER = 4  # inactivity timeout = 4 x EPR
MAX_EPR_MS = 0xFFFF


def round_epr(requested_ms: int, tick_ms: int) -> int:
    """The EPR a device with a ``tick_ms`` timer uses for a request: rounded up to its tick (0 stays 0)."""
    if not 0 <= requested_ms <= MAX_EPR_MS:
        raise EncodeError(f"expected packet rate {requested_ms} ms is outside 0..65535", field="expected_packet_rate")
    if requested_ms == 0 or tick_ms <= 1:
        return requested_ms
    return min(MAX_EPR_MS - MAX_EPR_MS % tick_ms, math.ceil(requested_ms / tick_ms) * tick_ms)


def inactivity_timeout(epr_ms: int) -> float | None:
    """Seconds of silence after which a connection's watchdog fires (None: EPR 0 = no watchdog)."""
    return None if epr_ms == 0 else WATCHDOG_MULTIPLIER * epr_ms / 1000.0


def uint(value: int) -> bytes:
    return struct.pack("<H", value)


def assembly_path(instance: int) -> bytes:
    """The connection path of an assembly's data attribute: class 4, instance, attribute 3 (8-bit segments)."""
    return bytes((0x20, 0x04, 0x24, instance, 0x30, 0x03))
