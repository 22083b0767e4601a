"""The protocol-neutral core: model, profiles, registry, transport contract, Device facade, simulated starter."""

from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    ChecksumError,
    CodecError,
    ConfigurationError,
    DecodeError,
    EncodeError,
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
from starterbus.core.model import Access, EnumTable, Kind, Label, PointDef, Reading, Value
from starterbus.core.profile import Profile, load_profile_file
from starterbus.core.registry import get_profile, get_transport
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.core.status import Command, ControlWordState, FaultTable, MotorState, Status
from starterbus.core.transport import Annotation, Capability, RunningSimulator, Transport, TransportPlugin
from starterbus.core.url import DeviceUrl

load_profile = get_profile

__all__ = [
    "Access",
    "Annotation",
    "Capability",
    "ChecksumError",
    "CodecError",
    "Command",
    "ConfigurationError",
    "ControlWordState",
    "DecodeError",
    "Device",
    "DeviceUrl",
    "EncodeError",
    "EnumTable",
    "FaultTable",
    "Kind",
    "Label",
    "ManualClock",
    "MotorState",
    "PluginError",
    "PointDef",
    "Profile",
    "ProfileError",
    "Reading",
    "RemoteDeviceError",
    "RunningSimulator",
    "SimulatedStarter",
    "StarterbusError",
    "Status",
    "TimeoutError",
    "Transport",
    "TransportError",
    "TransportPlugin",
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
