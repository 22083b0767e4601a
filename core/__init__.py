"""The protocol-neutral core: model, profiles, registry, transport contract, Device facade, simulated starter.

Names are imported on first use (PEP 562), so that ``import starterbus`` and the command line start fast.
"""

from __future__ import annotations

import importlib

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (mypy knows the name)
if TYPE_CHECKING:
    from typing import Any

    from starterbus.core.audit import AuditLog
    from starterbus.core.device import Device, open_device
    from starterbus.core.errors import (
        ChecksumError,
        CodecError,
        ConfigurationError,
        DecodeError,
        EncodeError,
        NotOpenError,
        PluginError,
        ProfileError,
        RemoteDeviceError,
        StarterbusError,
        TimeoutError,
        TransportError,
        UnknownPointError,
        UnsupportedOperationError,
        ValidationError,
    )
    from starterbus.core.guarded import (
        CommandNotReached,
        ConfirmationRefused,
        GuardedOperationError,
        Outcome,
        Proposal,
        ReadBackMismatch,
        StateRuleError,
        UncertainValueError,
    )
    from starterbus.core.model import Access, EnumTable, Kind, Label, PointDef, Reading, Value
    from starterbus.core.profile import Profile, load_profile_file
    from starterbus.core.registry import get_profile, get_transport
    from starterbus.core.simulator import ManualClock, SimulatedStarter
    from starterbus.core.status import Command, ControlWordState, FaultTable, MotorState, Status
    from starterbus.core.transport import Annotation, Capability, RunningSimulator, Transport, TransportPlugin
    from starterbus.core.url import DeviceUrl

    load_profile = get_profile

#: public name -> the module that defines it ("module:attribute" where the name differs)
_LAZY = {
    "Device": "starterbus.core.device",
    "open_device": "starterbus.core.device",
    "ChecksumError": "starterbus.core.errors",
    "CodecError": "starterbus.core.errors",
    "ConfigurationError": "starterbus.core.errors",
    "DecodeError": "starterbus.core.errors",
    "EncodeError": "starterbus.core.errors",
    "PluginError": "starterbus.core.errors",
    "ProfileError": "starterbus.core.errors",
    "RemoteDeviceError": "starterbus.core.errors",
    "StarterbusError": "starterbus.core.errors",
    "TimeoutError": "starterbus.core.errors",
    "TransportError": "starterbus.core.errors",
    "UnknownPointError": "starterbus.core.errors",
    "UnsupportedOperationError": "starterbus.core.errors",
    "ValidationError": "starterbus.core.errors",
    "NotOpenError": "starterbus.core.errors",
    "CommandNotReached": "starterbus.core.guarded",
    "ConfirmationRefused": "starterbus.core.guarded",
    "GuardedOperationError": "starterbus.core.guarded",
    "Outcome": "starterbus.core.guarded",
    "Proposal": "starterbus.core.guarded",
    "ReadBackMismatch": "starterbus.core.guarded",
    "StateRuleError": "starterbus.core.guarded",
    "UncertainValueError": "starterbus.core.guarded",
    "AuditLog": "starterbus.core.audit",
    "Access": "starterbus.core.model",
    "EnumTable": "starterbus.core.model",
    "Kind": "starterbus.core.model",
    "Label": "starterbus.core.model",
    "PointDef": "starterbus.core.model",
    "Reading": "starterbus.core.model",
    "Value": "starterbus.core.model",
    "Profile": "starterbus.core.profile",
    "load_profile_file": "starterbus.core.profile",
    "get_profile": "starterbus.core.registry",
    "get_transport": "starterbus.core.registry",
    "ManualClock": "starterbus.core.simulator",
    "SimulatedStarter": "starterbus.core.simulator",
    "Command": "starterbus.core.status",
    "ControlWordState": "starterbus.core.status",
    "FaultTable": "starterbus.core.status",
    "MotorState": "starterbus.core.status",
    "Status": "starterbus.core.status",
    "Annotation": "starterbus.core.transport",
    "Capability": "starterbus.core.transport",
    "RunningSimulator": "starterbus.core.transport",
    "Transport": "starterbus.core.transport",
    "TransportPlugin": "starterbus.core.transport",
    "DeviceUrl": "starterbus.core.url",
    "load_profile": "starterbus.core.registry:get_profile",
}


def __getattr__(name: str) -> Any:
    where = _LAZY.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, _, attribute = where.partition(":")
    value = getattr(importlib.import_module(module), attribute or name)
    globals()[name] = value
    return value


__all__ = [
    "Access",
    "Annotation",
    "AuditLog",
    "Capability",
    "ChecksumError",
    "CodecError",
    "Command",
    "CommandNotReached",
    "ConfigurationError",
    "ConfirmationRefused",
    "ControlWordState",
    "DecodeError",
    "Device",
    "DeviceUrl",
    "EncodeError",
    "EnumTable",
    "FaultTable",
    "GuardedOperationError",
    "Kind",
    "Label",
    "ManualClock",
    "MotorState",
    "NotOpenError",
    "Outcome",
    "PluginError",
    "PointDef",
    "Profile",
    "ProfileError",
    "Proposal",
    "ReadBackMismatch",
    "Reading",
    "RemoteDeviceError",
    "RunningSimulator",
    "SimulatedStarter",
    "StarterbusError",
    "StateRuleError",
    "Status",
    "TimeoutError",
    "Transport",
    "TransportError",
    "TransportPlugin",
    "UncertainValueError",
    "UnknownPointError",
    "UnsupportedOperationError",
    "ValidationError",
    "Value",
    "get_profile",
    "get_transport",
    "load_profile",
    "load_profile_file",
    "open_device",
]
