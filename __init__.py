"""starterbus: one protocol-neutral model for RENLE soft starters over Modbus RTU, Profibus DP and DeviceNet.

The names below are imported on first use (PEP 562), so that the command line starts fast.
"""

from __future__ import annotations

import importlib

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (mypy knows the name)
if TYPE_CHECKING:
    from typing import Any

    from starterbus.core import (
        AuditLog,
        ChecksumError,
        CodecError,
        Command,
        CommandNotReached,
        ConfigurationError,
        ConfirmationRefused,
        ControlSourceError,
        DecodeError,
        Device,
        EncodeError,
        GuardedOperationError,
        MotorState,
        NotOpenError,
        Outcome,
        PluginError,
        Profile,
        ProfileError,
        ReadBackMismatch,
        RemoteDeviceError,
        StarterbusError,
        StateRuleError,
        Status,
        TimeoutError,
        TransportError,
        UncertainValueError,
        UnknownPointError,
        UnsupportedOperationError,
        ValidationError,
        Value,
        get_profile,
        load_profile,
        open_device,
    )

__all__ = [
    "AuditLog",
    "ChecksumError",
    "CodecError",
    "Command",
    "CommandNotReached",
    "ConfigurationError",
    "ConfirmationRefused",
    "ControlSourceError",
    "DecodeError",
    "Device",
    "EncodeError",
    "GuardedOperationError",
    "MotorState",
    "NotOpenError",
    "Outcome",
    "PluginError",
    "Profile",
    "ProfileError",
    "ReadBackMismatch",
    "RemoteDeviceError",
    "StarterbusError",
    "StateRuleError",
    "Status",
    "TimeoutError",
    "TransportError",
    "UncertainValueError",
    "UnknownPointError",
    "UnsupportedOperationError",
    "ValidationError",
    "Value",
    "get_profile",
    "load_profile",
    "open_device",
]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module("starterbus.core"), name)
    globals()[name] = value
    return value
