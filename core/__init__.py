"""The protocol-neutral core: model, profiles, registry, transport contract, Device facade, simulated starter.

Names are imported on first use (PEP 562), so that ``import starterbus`` and the command line start fast.
"""

from __future__ import annotations

import importlib

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (mypy knows the name)
if TYPE_CHECKING:
    from typing import Any

    from starterbus.core.address_space import AddressSpace
    from starterbus.core.audit import AuditLog
    from starterbus.core.canbridge import LoopbackBridge, parse_bridge_address
    from starterbus.core.canbus import check_peer, open_bus, parse_bus_spec
    from starterbus.core.canbus import shutdown as shutdown_bus
    from starterbus.core.canframe import CanFrame, annotate_candump, parse_candump
    from starterbus.core.control_log import ControlWrite
    from starterbus.core.device import Device, open_device
    from starterbus.core.engine import Engine, StreamEngine, Ticket, TicketState, TicketStateError
    from starterbus.core.errors import (
        ChecksumError,
        CodecError,
        ConfigurationError,
        ControlSourceError,
        DecodeError,
        EncodeError,
        NotOpenError,
        PluginError,
        ProfileError,
        Refusal,
        RemoteDeviceError,
        SimulatorRefusal,
        StarterbusError,
        StateRuleError,
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
        UncertainValueError,
    )
    from starterbus.core.media import Driver, StreamDriver, TcpDriver
    from starterbus.core.model import Access, EnumTable, Kind, Label, PointDef, Reading, Value
    from starterbus.core.plugin_options import OptionValues, PluginOption, SimOption, resolve_options
    from starterbus.core.polling import PlannedRequest, PollResult, PollTask, TransportCounters, run_task
    from starterbus.core.profile import Profile, load_profile_file
    from starterbus.core.registry import get_profile, get_transport
    from starterbus.core.scheduler import Scheduler, SchedulerReentryError
    from starterbus.core.sharing import SharedPool
    from starterbus.core.simulator import ManualClock, SimulatedStarter
    from starterbus.core.status import (
        PHASE_NAMES,
        Command,
        ControlWordState,
        FaultTable,
        MotorState,
        Status,
        decode_status_word,
        describe_control_word,
        encode_status_word,
        status_with_currents,
    )
    from starterbus.core.textinput import check_loopback, parse_hex, parse_host_port
    from starterbus.core.transport import (
        ALL_CAPABILITIES,
        Annotation,
        Capability,
        RunningSimulator,
        Transport,
        TransportPlugin,
    )
    from starterbus.core.url import DeviceUrl

    load_profile = get_profile

#: public name -> the module that defines it ("module:attribute" where the name differs)
_LAZY = {
    "Device": "starterbus.core.device",
    "open_device": "starterbus.core.device",
    "ChecksumError": "starterbus.core.errors",
    "CodecError": "starterbus.core.errors",
    "ConfigurationError": "starterbus.core.errors",
    "ControlSourceError": "starterbus.core.errors",
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
    "StateRuleError": "starterbus.core.errors",
    "UncertainValueError": "starterbus.core.guarded",
    "AuditLog": "starterbus.core.audit",
    "Access": "starterbus.core.model",
    "AddressSpace": "starterbus.core.address_space",
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
    "ControlWrite": "starterbus.core.control_log",
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
    "PluginOption": "starterbus.core.plugin_options",
    "SimOption": "starterbus.core.plugin_options",
    "OptionValues": "starterbus.core.plugin_options",
    "resolve_options": "starterbus.core.plugin_options",
    "parse_hex": "starterbus.core.textinput",
    "parse_host_port": "starterbus.core.textinput",
    "check_loopback": "starterbus.core.textinput",
    "open_bus": "starterbus.core.canbus",
    "check_peer": "starterbus.core.canbus",
    "CanFrame": "starterbus.core.canframe",
    "annotate_candump": "starterbus.core.canframe",
    "parse_candump": "starterbus.core.canframe",
    "parse_bus_spec": "starterbus.core.canbus",
    "shutdown_bus": "starterbus.core.canbus:shutdown",
    "LoopbackBridge": "starterbus.core.canbridge",
    "parse_bridge_address": "starterbus.core.canbridge",
    "decode_status_word": "starterbus.core.status",
    "describe_control_word": "starterbus.core.status",
    "encode_status_word": "starterbus.core.status",
    "status_with_currents": "starterbus.core.status",
    "PHASE_NAMES": "starterbus.core.status",
    "Refusal": "starterbus.core.errors",
    "SimulatorRefusal": "starterbus.core.errors",
    "SharedPool": "starterbus.core.sharing",
    "ALL_CAPABILITIES": "starterbus.core.transport",
    "PollResult": "starterbus.core.polling",
    "PollTask": "starterbus.core.polling",
    "run_task": "starterbus.core.polling",
    "PlannedRequest": "starterbus.core.polling",
    "TransportCounters": "starterbus.core.polling",
    "Engine": "starterbus.core.engine",
    "StreamEngine": "starterbus.core.engine",
    "Ticket": "starterbus.core.engine",
    "TicketState": "starterbus.core.engine",
    "TicketStateError": "starterbus.core.engine",
    "Driver": "starterbus.core.media",
    "StreamDriver": "starterbus.core.media",
    "TcpDriver": "starterbus.core.media",
    "Scheduler": "starterbus.core.scheduler",
    "SchedulerReentryError": "starterbus.core.scheduler",
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
    "ALL_CAPABILITIES",
    "PHASE_NAMES",
    "Access",
    "AddressSpace",
    "Annotation",
    "AuditLog",
    "CanFrame",
    "Capability",
    "ChecksumError",
    "CodecError",
    "Command",
    "CommandNotReached",
    "ConfigurationError",
    "ConfirmationRefused",
    "ControlSourceError",
    "ControlWordState",
    "ControlWrite",
    "DecodeError",
    "Device",
    "DeviceUrl",
    "Driver",
    "EncodeError",
    "Engine",
    "EnumTable",
    "FaultTable",
    "GuardedOperationError",
    "Kind",
    "Label",
    "LoopbackBridge",
    "ManualClock",
    "MotorState",
    "NotOpenError",
    "OptionValues",
    "Outcome",
    "PlannedRequest",
    "PluginError",
    "PluginOption",
    "PointDef",
    "PollResult",
    "PollTask",
    "Profile",
    "ProfileError",
    "Proposal",
    "ReadBackMismatch",
    "Reading",
    "Refusal",
    "RemoteDeviceError",
    "RunningSimulator",
    "Scheduler",
    "SchedulerReentryError",
    "SharedPool",
    "SimOption",
    "SimulatedStarter",
    "SimulatorRefusal",
    "StarterbusError",
    "StateRuleError",
    "Status",
    "StreamDriver",
    "StreamEngine",
    "TcpDriver",
    "Ticket",
    "TicketState",
    "TicketStateError",
    "TimeoutError",
    "Transport",
    "TransportCounters",
    "TransportError",
    "TransportPlugin",
    "UncertainValueError",
    "UnknownPointError",
    "UnsupportedOperationError",
    "ValidationError",
    "Value",
    "annotate_candump",
    "check_loopback",
    "check_peer",
    "decode_status_word",
    "describe_control_word",
    "encode_status_word",
    "get_profile",
    "get_transport",
    "load_profile",
    "load_profile_file",
    "open_bus",
    "open_device",
    "parse_bridge_address",
    "parse_bus_spec",
    "parse_candump",
    "parse_hex",
    "parse_host_port",
    "resolve_options",
    "run_task",
    "shutdown_bus",
    "status_with_currents",
]
