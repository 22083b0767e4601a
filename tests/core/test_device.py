"""The Device facade validates before anything reaches a transport.

The transport here is a minimal implementation of the public Transport contract that records what it was
asked to send (the contract is what is under test, not a mock of starterbus internals). Line-level
"nothing was sent" checks over a real pseudo-terminal live in tests/modbus.
"""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    NotOpenError,
    PluginError,
    UnknownPointError,
    UnsupportedOperationError,
    ValidationError,
)
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile
from starterbus.core.transport import Capability
from starterbus.core.url import DeviceUrl
from starterbus.tests.stub_transport import StubTransport


class RecordingTransport(StubTransport):
    name = "recording"

    def __init__(self, profile: Profile, caps: frozenset[Capability]) -> None:
        super().__init__(DeviceUrl.parse("recording://test"), profile)
        self.caps = caps
        self.sent: list[tuple[str, int]] = []
        self.memory: dict[str, int] = {}

    @property
    def capabilities(self) -> frozenset[Capability]:
        return self.caps

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        return [Reading(p, self.memory.get(p.key, p.default if p.default is not None else p.raw_min)) for p in points]

    def _write_parameter(self, point: PointDef, raw: int) -> None:
        self.sent.append((point.key, raw))
        self.memory[point.key] = raw


def test_out_of_range_write_sends_nothing(jjr5000: Profile) -> None:
    transport = RecordingTransport(jjr5000, frozenset(Capability))
    device = Device(transport, jjr5000).open()
    with pytest.raises(ValidationError, match="149 % is out of range 150..500 %"):
        device.write("current_limit", 149)
    with pytest.raises(ValidationError):
        device.write("0x0103", 501)
    assert transport.sent == []
    device.write("0x0103", 380)
    assert transport.sent == [("current_limit", 380)]


def test_write_many_is_all_or_nothing(jjr5000: Profile) -> None:
    transport = RecordingTransport(jjr5000, frozenset(Capability))
    device = Device(transport, jjr5000).open()
    with pytest.raises(ValidationError):
        device.write_many({"current_limit": 300, "ramp_time": 999})
    assert transport.sent == []


def test_read_only_and_measurements_refused(jjr5000: Profile) -> None:
    device = Device(RecordingTransport(jjr5000, frozenset(Capability)), jjr5000).open()
    with pytest.raises(ValidationError, match="measurement"):
        device.write("phase_a_current", 1)
    with pytest.raises(UnknownPointError, match="no parameter or measurement 'warp'"):
        device.write("warp", 1)


def test_missing_capability_is_unsupported_and_sends_nothing(jjr8000: Profile) -> None:
    transport = RecordingTransport(jjr8000, frozenset({Capability.STATUS, Capability.READ_MEASUREMENTS}))
    device = Device(transport, jjr8000).open()
    with pytest.raises(UnsupportedOperationError, match="cannot write parameters"):
        device.write("p7", 3.5)
    with pytest.raises(UnsupportedOperationError, match="cannot read parameters"):
        device.read("p7")
    with pytest.raises(UnsupportedOperationError, match="cannot send the command 'start'"):
        device.start()
    assert transport.sent == []
    assert device.read("m2")["phase_a_current"].unit == "A"


def test_open_device_errors() -> None:
    with pytest.raises(PluginError, match="no starterbus.transports plugin named 'nope'"):
        open_device("nope://x", "jjr5000")
    with pytest.raises(PluginError, match="no starterbus.profiles plugin named 'jjr9999'"):
        open_device("modbus-rtu:///dev/null", "jjr9999")
    with pytest.raises(UnsupportedOperationError, match="has no devicenet interface"):
        open_device("devicenet://virtual/x?mac=5", "jjr5000")


class OtherTransport(RecordingTransport):
    name = "other"


def test_a_kept_resolution_is_never_used_for_another_profile_transport_or_capabilities(
    jjr5000: Profile, jjr8000: Profile
) -> None:
    everything = frozenset(Capability)
    transport = RecordingTransport(jjr5000, everything)
    device = Device(transport, jjr5000).open()
    assert device.read("current_limit")["current_limit"].point is jjr5000.point("current_limit")
    assert device.read("current_limit")["current_limit"].point is jjr5000.point("current_limit")  # kept
    device.profile = jjr8000  # the same key is another point (another address) in another model
    value = device.read("current_limit")["current_limit"]
    assert value.point is jjr8000.point("current_limit") and value.point.address != "0x0103"
    transport.caps = frozenset({Capability.READ_MEASUREMENTS})
    with pytest.raises(UnsupportedOperationError, match="read parameters such as current_limit"):
        device.read("current_limit")
    assert device.read("phase_a_current")["phase_a_current"].point is jjr8000.point("phase_a_current")
    transport.caps = everything
    assert device.read("current_limit")["current_limit"].point is jjr8000.point("current_limit")
    other = OtherTransport(jjr8000, everything)  # the same raw values, another source
    other.open()
    assert device.read("current_limit")["current_limit"].source == "recording"
    device.transport = other
    assert device.read("current_limit")["current_limit"].source == "other"
    other.memory["current_limit"] = 300
    assert device.read("current_limit")["current_limit"].raw == 300


def test_repeated_reads_give_fresh_dicts_and_follow_every_change(jjr5000: Profile) -> None:
    transport = RecordingTransport(jjr5000, frozenset(Capability))
    device = Device(transport, jjr5000).open()
    first = device.read("current_limit", "ramp_time")
    first["current_limit"] = first["ramp_time"]  # the caller's dict is the caller's
    second = device.read("current_limit", "ramp_time")
    assert second["current_limit"].key == "current_limit" and second is not first
    transport.memory["current_limit"] = 420
    assert device.read("current_limit", "ramp_time")["current_limit"].value == 420
    point = jjr5000.point("ramp_time")  # PointDef keys are not hashable: resolved each time, never refused
    assert device.read(point, "0x0103")["current_limit"].value == 420
    device.close()
    with pytest.raises(NotOpenError):
        device.read("current_limit", "ramp_time")  # kept, but the closed device is still refused
