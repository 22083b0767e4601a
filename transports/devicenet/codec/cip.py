"""CIP vocabulary used on DeviceNet: services, object classes, status codes and the typed errors built on them.

Every decode problem the DeviceNet codec finds is a :class:`DeviceNetDecodeError` (a core
:class:`~starterbus.core.errors.DecodeError`) that also names the CIP general/additional status a server
answers with (a slave simulator sends exactly that status back). An error response received from a device
becomes a core :class:`~starterbus.core.errors.RemoteDeviceError` with protocol ``"devicenet"``, the general
status as ``code``, its meaning, and the additional status.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from starterbus.core import DecodeError, RemoteDeviceError

PROTOCOL = "devicenet"
NO_ADDITIONAL = 0xFF  # "additional code: none"


class Service(enum.IntEnum):
    GET_ATTRIBUTES_ALL = 0x01
    RESET = 0x05
    GET_ATTRIBUTE_SINGLE = 0x0E
    SET_ATTRIBUTE_SINGLE = 0x10
    ERROR_RESPONSE = 0x14  # sent as 0x94 (response bit set)
    ALLOCATE = 0x4B  # Allocate_Master/Slave_Connection_Set (DeviceNet object)
    RELEASE = 0x4C  # Release_Master/Slave_Connection_Set


SERVICE_NAMES: dict[int, str] = {
    Service.GET_ATTRIBUTES_ALL: "Get_Attributes_All",
    Service.RESET: "Reset",
    Service.GET_ATTRIBUTE_SINGLE: "Get_Attribute_Single",
    Service.SET_ATTRIBUTE_SINGLE: "Set_Attribute_Single",
    Service.ERROR_RESPONSE: "Error_Response",
    Service.ALLOCATE: "Allocate_Master/Slave_Connection_Set",
    Service.RELEASE: "Release_Master/Slave_Connection_Set",
}

#: services whose request body carries an attribute id after class and instance
ATTRIBUTE_SERVICES = frozenset({Service.GET_ATTRIBUTE_SINGLE, Service.SET_ATTRIBUTE_SINGLE})


def service_name(code: int) -> str:
    return SERVICE_NAMES.get(code, f"unknown service 0x{code:02X}")


class ObjectClass(enum.IntEnum):
    IDENTITY = 0x01
    MESSAGE_ROUTER = 0x02
    DEVICENET = 0x03
    ASSEMBLY = 0x04
    CONNECTION = 0x05


CLASS_NAMES: dict[int, str] = {
    ObjectClass.IDENTITY: "Identity",
    ObjectClass.MESSAGE_ROUTER: "Message Router",
    ObjectClass.DEVICENET: "DeviceNet",
    ObjectClass.ASSEMBLY: "Assembly",
    ObjectClass.CONNECTION: "Connection",
}


def class_name(code: int) -> str:
    return CLASS_NAMES.get(code, f"class 0x{code:02X}")


class GeneralStatus(enum.IntEnum):
    SUCCESS = 0x00
    CONNECTION_FAILURE = 0x01
    RESOURCE_UNAVAILABLE = 0x02
    PATH_DESTINATION_UNKNOWN = 0x05
    PARTIAL_TRANSFER = 0x06
    SERVICE_NOT_SUPPORTED = 0x08
    INVALID_ATTRIBUTE_VALUE = 0x09
    ALREADY_IN_REQUESTED_MODE = 0x0B
    OBJECT_STATE_CONFLICT = 0x0C
    ATTRIBUTE_NOT_SETTABLE = 0x0E
    PRIVILEGE_VIOLATION = 0x0F
    DEVICE_STATE_CONFLICT = 0x10
    REPLY_TOO_LARGE = 0x11
    NOT_ENOUGH_DATA = 0x13
    ATTRIBUTE_NOT_SUPPORTED = 0x14
    TOO_MUCH_DATA = 0x15
    OBJECT_DOES_NOT_EXIST = 0x16
    VENDOR_SPECIFIC = 0x1F
    INVALID_PARAMETER = 0x20


#: general status texts (CIP common specification, appendix B; as in the DeviceNet manuals of the field)
GENERAL_STATUS_TEXTS: dict[int, str] = {
    0x00: "success",
    0x01: "connection failure",
    0x02: "resource unavailable",
    0x03: "invalid parameter value",
    0x04: "path segment error",
    0x05: "path destination unknown",
    0x06: "partial transfer",
    0x07: "connection lost",
    0x08: "service not supported",
    0x09: "invalid attribute value",
    0x0A: "attribute list error",
    0x0B: "already in requested mode/state",
    0x0C: "object state conflict",
    0x0D: "object already exists",
    0x0E: "attribute not settable",
    0x0F: "privilege violation",
    0x10: "device state conflict",
    0x11: "reply data too large",
    0x12: "fragmentation of a primitive value",
    0x13: "not enough data",
    0x14: "attribute not supported",
    0x15: "too much data",
    0x16: "object does not exist",
    0x17: "service fragmentation sequence not in progress",
    0x18: "no stored attribute data",
    0x19: "store operation failure",
    0x1A: "routing failure, request packet too large",
    0x1B: "routing failure, response packet too large",
    0x1C: "missing attribute list entry data",
    0x1D: "invalid attribute value list",
    0x1E: "embedded service error",
    0x1F: "vendor specific error",
    0x20: "invalid parameter",
    0x21: "write-once value or medium already written",
    0x22: "invalid reply received",
    0x25: "key failure in path",
    0x26: "path size invalid",
    0x27: "unexpected attribute in list",
    0x28: "invalid member ID",
    0x29: "member not settable",
    0x2A: "group 2 only server general failure",
}


class AllocationError(enum.IntEnum):
    """Additional codes of Allocate/Release error responses (DeviceNet object)."""

    ALLOCATED_TO_ANOTHER_MASTER = 0x01
    INVALID_CHOICE = 0x02
    INVALID_GROUP2_ONLY_SERVICE = 0x03
    RESOURCE_UNAVAILABLE = 0x04


ALLOCATION_ERROR_TEXTS: dict[int, str] = {
    0x01: "the connection set is already allocated to another master",
    0x02: "invalid allocation/release choice (unsupported, already allocated or not allocated)",
    0x03: "the group 2 only unconnected port accepts only Allocate/Release",
    0x04: "resource unavailable for the requested connections",
}


def general_status_text(code: int) -> str:
    if 0x2B <= code <= 0xCF:
        return f"reserved general status 0x{code:02X}"
    if 0xD0 <= code <= 0xFF:
        return f"object class specific status 0x{code:02X}"
    return GENERAL_STATUS_TEXTS.get(code, f"unknown general status 0x{code:02X}")


def additional_status_text(general: int, additional: int, service: int | None = None) -> str:
    """Text of an additional code: 0xFF is "none"; Allocate/Release codes are known (also when the service is
    not known, as for a lone error frame in a decoder); anything else is object specific."""
    if additional == NO_ADDITIONAL:
        return "none"
    if service is None or service in (Service.ALLOCATE, Service.RELEASE):
        text = ALLOCATION_ERROR_TEXTS.get(additional)
        if text:
            return text if service is not None else f"{text} (if it answers Allocate/Release)"
    return f"object specific code 0x{additional:02X}"


@dataclass(frozen=True, slots=True)
class CipStatus:
    """A general status with its additional code (0xFF = none)."""

    general: int
    additional: int = NO_ADDITIONAL

    @property
    def meaning(self) -> str:
        return general_status_text(self.general)

    def describe(self, service: int | None = None) -> str:
        text = f"0x{self.general:02X} {self.meaning}"
        if self.additional != NO_ADDITIONAL:
            extra = additional_status_text(self.general, self.additional, service)
            text += f", additional 0x{self.additional:02X}: {extra}"
        return text


# Statuses a slave answers with; named so that simulator and tests agree.
ALLOCATED_TO_ANOTHER_MASTER = CipStatus(
    GeneralStatus.OBJECT_STATE_CONFLICT, AllocationError.ALLOCATED_TO_ANOTHER_MASTER
)
ALREADY_ALLOCATED = CipStatus(GeneralStatus.ALREADY_IN_REQUESTED_MODE, AllocationError.INVALID_CHOICE)
NOT_ALLOCATED = CipStatus(GeneralStatus.ALREADY_IN_REQUESTED_MODE, AllocationError.INVALID_CHOICE)
UNSUPPORTED_CONNECTION = CipStatus(GeneralStatus.RESOURCE_UNAVAILABLE, AllocationError.INVALID_CHOICE)
INVALID_CHOICE = CipStatus(GeneralStatus.INVALID_PARAMETER, AllocationError.INVALID_CHOICE)
GROUP2_ONLY_SERVICE = CipStatus(GeneralStatus.SERVICE_NOT_SUPPORTED, AllocationError.INVALID_GROUP2_ONLY_SERVICE)


class DeviceNetDecodeError(DecodeError):
    """A DeviceNet frame or message could not be decoded; ``status`` is the CIP status a server answers with."""

    status: CipStatus = CipStatus(GeneralStatus.INVALID_PARAMETER)

    def __init__(
        self, message: str, data: bytes = b"", field: str | None = None, status: CipStatus | None = None
    ) -> None:
        if status is not None:
            self.status = status
        super().__init__(f"{message} (CIP {self.status.describe()})", data, field)

    @property
    def general_status(self) -> int:
        return self.status.general

    @property
    def additional_status(self) -> int:
        return self.status.additional

    @property
    def meaning(self) -> str:
        return self.status.meaning


class FrameTooShortError(DeviceNetDecodeError):
    """A frame or message body is shorter than its layout needs."""

    status = CipStatus(GeneralStatus.NOT_ENOUGH_DATA)


class FrameTooLongError(DeviceNetDecodeError):
    """A frame or message body carries more bytes than its layout allows."""

    status = CipStatus(GeneralStatus.TOO_MUCH_DATA)


class FragmentError(DeviceNetDecodeError):
    """A fragment arrived out of order (or without its first fragment), or a series grew too large."""

    status = CipStatus(GeneralStatus.PARTIAL_TRANSFER)


class UnknownServiceError(DeviceNetDecodeError):
    """A service code this codec does not know (or that does not answer the request it should answer)."""

    status = CipStatus(GeneralStatus.SERVICE_NOT_SUPPORTED)


class UnexpectedFrameError(DeviceNetDecodeError):
    """A well-formed frame that is not valid where it arrived (wrong identifier, request bit, MAC, XID)."""

    status = CipStatus(GeneralStatus.INVALID_PARAMETER)


def remote_error(
    status: CipStatus, service: int | None = None, detail: str = "", data: bytes = b""
) -> RemoteDeviceError:
    """The core error for an error response received from a device."""
    extra = ""
    if status.additional != NO_ADDITIONAL:
        extra = additional_status_text(status.general, status.additional, service)
    if service is not None:
        what = service_name(service)
        detail = f"{what}: {detail}" if detail else what
    if extra:
        detail = f"{detail}; {extra}" if detail else extra
    additional = None if status.additional == NO_ADDITIONAL else status.additional
    return RemoteDeviceError(PROTOCOL, status.general, status.meaning, detail, data, additional)
