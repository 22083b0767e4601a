"""The transport conformance kit: one set of tests every transport plugin passes, built-in or third-party.

Subclass :class:`TransportConformance` in your plugin's tests, name the transport and a model, and say how to
serve a :class:`~starterbus.core.simulator.SimulatedStarter` behind your protocol::

    class TestAcmeLoop(TransportConformance):
        transport = "acme-loop"
        model = "jjr5000"

        @contextlib.contextmanager
        def serve(self, starter):
            with AcmeSimulator(starter) as sim:
                yield f"acme-loop://{sim.address}"

Optional hooks make the kit check more (each check that needs one skips, saying so, without it):
``serve_units(starters)`` serves several starters on one link; ``faults(starter)`` is the fault hook
(:mod:`starterbus.testing.faults`) through which the kit sees the requests that reach the device and makes it
silent, slow, late, duplicating, busy or unreachable behind a gateway; ``refusal_code(profile, reason)`` and
``invalid_url_values(profile)`` tell what the simulator answers and which URL values the model refuses;
``url_timeout`` and ``url_retries`` name the URL parameters of the timeout and the retries. docs/plugins.md
shows them for a serial protocol.

The kit checks declared capabilities against behaviour (what is declared works, what is not is refused with
``UnsupportedOperationError``), read/write round trips against the simulator's own registers, the status,
every command through the guarded path (the state reached), validation before sending, typed device errors,
dry-run previews, the lifecycle (no thread or file descriptor left behind), a cross-check against the
reference transport (Modbus RTU on a pseudo-terminal) serving the same starter with the motor running, that no
read-only operation changes a running motor's state or sends it a control output
(:mod:`starterbus.testing.read_only`); the status and the measurements with the motor running (non-zero
currents) and after every command (a fault reset twice, the bus-control bit), the device's refusal codes and
the model's texts for them, several devices on one link, every URL parameter's validation
(:mod:`starterbus.testing.kit_running`); previews against what is then sent, writes sent exactly once, the poll
plan and the counters, and a faulty device (:mod:`starterbus.testing.kit_faults`).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    NotOpenError,
    RemoteDeviceError,
    StarterbusError,
    UnsupportedOperationError,
    ValidationError,
)
from starterbus.core.guarded import ConfirmationRefused, Proposal
from starterbus.core.model import Kind, PointDef
from starterbus.core.profile import Profile
from starterbus.core.registry import get_transport
from starterbus.core.sharing import leases
from starterbus.core.simulator import Phase, SimulatedStarter
from starterbus.core.status import Command, MotorState
from starterbus.core.transport import Capability, Transport
from starterbus.core.url import DeviceUrl
from starterbus.testing.faults import DeviceTap, Fault, FaultControl, FaultNotSupported
from starterbus.testing.kit_base import ConformanceNotice, is_open, open_fds, phase
from starterbus.testing.kit_faults import FaultChecks
from starterbus.testing.kit_running import RunningChecks
from starterbus.testing.read_only import check_reads_never_actuate, run_motor
from starterbus.testing.waits import wait_until

REFERENCE = "modbus-rtu"

__all__ = [
    "REFERENCE", "ConformanceNotice", "DeviceTap", "Fault", "FaultControl", "FaultNotSupported",
    "TransportConformance", "wait_until",
]  # fmt: skip


class TransportConformance(RunningChecks, FaultChecks):
    """Base class of a transport's conformance tests (pytest collects subclasses named ``Test*``)."""

    # -- the tests ------------------------------------------------------------------------------------------

    def test_plugin_is_registered(self) -> None:
        plugin = get_transport(self.transport)
        assert plugin.name == self.transport
        assert plugin.capabilities <= frozenset(Capability) and plugin.url_forms and plugin.summary

    def test_undeclared_capabilities_are_refused(self, device: Device, starter: SimulatedStarter) -> None:
        caps = device.capabilities
        before = dict(starter.params)
        calls: dict[Capability, Callable[[], object]] = {
            Capability.STATUS: device.status,
            Capability.READ_MEASUREMENTS: lambda: device.read(device.profile.measurements[0].key),
            Capability.READ_PARAMETERS: lambda: device.read(device.profile.parameters[0].key),
            Capability.WRITE_PARAMETERS: lambda: device.write(self._any_writable(device).key, self._other(device)),
            Capability.COMMANDS: device.start,
        }
        for capability, call in calls.items():
            if capability in caps:
                continue
            with pytest.raises(UnsupportedOperationError):
                call()
        assert starter.params == before and starter.phase is Phase.STOPPED

    def _any_writable(self, device: Device) -> PointDef:
        return next(p for p in device.profile.parameters if p.writable)

    def _other(self, device: Device) -> float | int:
        point = self._any_writable(device)
        return point.to_engineering(point.raw_min)

    def test_measurements_match_the_simulator(self, device: Device, starter: SimulatedStarter) -> None:
        if Capability.READ_MEASUREMENTS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.READ_MEASUREMENTS.value}")
        points = self.addressed(device, Kind.MEASUREMENT)
        try:
            values = device.read(*[p.key for p in points])
        except UnsupportedOperationError:  # some points refused (a transport may refuse per point): the others
            values = {}
            for point in points:
                with contextlib.suppress(UnsupportedOperationError):
                    values.update(device.read(point.key))
        assert values, f"{self.transport} declares {Capability.READ_MEASUREMENTS.value} but reads no measurement"
        for point in (p for p in points if p.key in values):
            value = values[point.key]
            expected = point.to_engineering(starter.read(point))
            assert abs(float(value.value) - float(expected)) <= value.resolution, point.key

    def test_parameters_match_the_simulator(self, device: Device, starter: SimulatedStarter) -> None:
        if Capability.READ_PARAMETERS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.READ_PARAMETERS.value}")
        points = self.addressed(device, Kind.PARAMETER)
        values = device.read(*[p.key for p in points])
        assert {k: v.raw for k, v in values.items()} == {p.key: starter.read(p) for p in points}

    def test_writes_round_trip_through_the_guarded_path(self, device: Device, starter: SimulatedStarter) -> None:
        if Capability.WRITE_PARAMETERS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.WRITE_PARAMETERS.value}")
        points, uncertain = self.write_targets(device)
        for point in points:
            raw = point.raw_max if starter.read(point) != point.raw_max else point.raw_min
            value = point.to_engineering(raw) if point.enum is None else raw
            outcome = device.write(point.key, value, accept_uncertain=uncertain)
            assert outcome.ok and starter.params[point.key] == raw, point.key
            assert outcome.read_back is None or outcome.read_back.raw == raw

    def test_invalid_or_unconfirmed_writes_send_nothing(
        self, url: str, profile: Profile, starter: SimulatedStarter
    ) -> None:
        def refuse(_: Proposal) -> bool:
            return False

        before = dict(starter.params)
        with open_device(url, profile, confirm=refuse) as device:
            point = self._any_writable(device)
            with pytest.raises(ValidationError):
                device.write(point.key, point.to_engineering(point.raw_max + 1) if point.enum is None else 10**6)
            if Capability.WRITE_PARAMETERS in device.capabilities:
                targets, uncertain = self.write_targets(device)
                with pytest.raises(ConfirmationRefused):
                    device.write(
                        targets[0].key, targets[0].to_engineering(targets[0].raw_min), accept_uncertain=uncertain
                    )
            if Capability.COMMANDS in device.capabilities:
                with pytest.raises(ConfirmationRefused):
                    device.start()
        assert starter.params == before and starter.phase is Phase.STOPPED

    def test_status_follows_the_starter(self, device: Device, starter: SimulatedStarter) -> None:
        if Capability.STATUS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.STATUS.value}")
        assert wait_until(lambda: device.status().state in (MotorState.READY, MotorState.STOPPED))
        starter.start()
        assert wait_until(lambda: device.status().state is MotorState.STARTING)
        starter.inject_fault(6)
        assert wait_until(lambda: device.status().fault)
        status = device.status()
        assert status.fault_code == 6 and status.fault_text == device.profile.faults.text(6)

    def test_every_command_reaches_its_state(self, device: Device, starter: SimulatedStarter) -> None:
        if Capability.COMMANDS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.COMMANDS.value}")
        started = device.start()
        assert started.ok and phase(starter) is Phase.STARTING
        stopped = device.stop()
        assert stopped.ok and phase(starter) in (Phase.STOPPING, Phase.STOPPED)
        starter.inject_fault(2)
        reset = device.reset()
        assert reset.ok and starter.fault_code is None

    def test_device_refusals_are_typed(self, device: Device, starter: SimulatedStarter) -> None:
        if Capability.WRITE_PARAMETERS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.WRITE_PARAMETERS.value}")
        control = device.profile.control
        if control.write_protect_key:
            starter.params[control.write_protect_key] = 0
            point = self.write_targets(device)[0][0]
        elif control.locked_while_running:
            starter.start()
            point = device.profile.point(sorted(control.locked_while_running)[0])
        else:
            pytest.skip(f"{device.profile.display_name} documents no refusal to provoke")
        with pytest.raises(RemoteDeviceError) as info:
            device.send_write(point, point.raw_min)  # past the guard: the device's own refusal
        assert info.value.meaning and info.value.protocol

    def test_dry_run_previews_send_nothing(self, device: Device, starter: SimulatedStarter) -> None:
        before = dict(starter.params)
        if Capability.WRITE_PARAMETERS in device.capabilities:
            point = self.write_targets(device)[0][0]
            frames = device.transport.preview_write(point, point.raw_min)
            assert frames and all(isinstance(f, str) and f for f in frames)
        if Capability.COMMANDS in device.capabilities:
            frames = device.transport.preview_command(Command.START)
            assert frames and all(isinstance(f, str) and f for f in frames)
        assert starter.params == before and starter.phase is Phase.STOPPED

    def test_lifecycle_leaves_nothing_behind(self, url: str, profile: Profile) -> None:
        with open_device(url, profile):
            pass  # the first open may start shared, process-wide services
        threads, fds, held = threading.active_count(), open_fds(), leases()
        for _ in range(3):
            device = open_device(url, profile)
            with device:
                if Capability.STATUS in device.capabilities:
                    device.status()
            with pytest.raises(StarterbusError):
                device.status()  # closed: a typed error, never a hang or an AttributeError
        assert wait_until(lambda: threading.active_count() <= threads), "threads left running after close"
        assert wait_until(lambda: open_fds() <= fds), "file descriptors left open after close"
        assert leases() == held, "a shared line, bus or gateway (SharedPool) was not released on close"

    def _transport(self, url: str, profile: Profile) -> Transport:
        return get_transport(self.transport).open(DeviceUrl.parse(url), profile)

    def _operations(self, transport: Transport, profile: Profile) -> dict[str, Callable[[], object]]:
        """Every operation that needs an open transport (none of them may reach the device here)."""
        point = (profile.measurements or profile.parameters)[0]
        return {
            "read_points": lambda: transport.read_points([point]),
            "read_status": transport.read_status,
            "send_command": lambda: transport.send_command(Command.SOFT_STOP),
            "write_parameter": lambda: transport.write_parameter(point, 0),  # the state is checked first
            "poll": lambda: transport.poll([point], True),
            "identify": transport.identify,
        }

    def test_a_transport_used_before_open_or_after_close_raises_not_open(
        self, url: str, profile: Profile, starter: SimulatedStarter
    ) -> None:
        transport = self._transport(url, profile)
        for name, call in self._operations(transport, profile).items():
            with pytest.raises(NotOpenError, match="not open") as info:
                call()
            assert self.transport in str(info.value) and transport.url.text in str(info.value), name
        transport.open()
        transport.open()  # idempotent: the second open does nothing
        assert is_open(transport)
        transport.close()
        transport.close()  # idempotent
        assert not is_open(transport)
        for name, call in self._operations(transport, profile).items():
            with pytest.raises(NotOpenError, match="closed"):
                call()
            assert not is_open(transport), name
        with transport:  # a closed transport opens again (a poller reconnects)
            assert is_open(transport)
        assert starter.phase is Phase.STOPPED

    def test_declared_capabilities_match_the_hooks(self, url: str, profile: Profile) -> None:
        plugin = get_transport(self.transport)
        transport = self._transport(url, profile)
        assert transport.capabilities <= plugin.capabilities, "a URL offers more than the plugin declares"
        assert type(transport).capability_problems(plugin.capabilities) == []

    def test_agrees_with_the_reference_transport(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        if self.transport == REFERENCE or not profile.supports(REFERENCE):
            pytest.skip("this is the reference transport, or the model has no reference interface")
        from starterbus.fleet.crosscheck import crosscheck
        from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

        run_motor(starter)  # currents are not zero
        with ModbusRtuSimulator({1: starter}, pty=True) as reference:
            report = crosscheck([url, reference.client_urls()[1]], profile)
        assert report.ok, [row.what for row in report.rows if row.agree is False] + [p.error for p in report.paths]

    def test_reads_never_actuate(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        """The motor runs (started from the keypad); every read-only operation of the transport runs against it;
        none may change its state or a parameter, or send it a control output (the failure names which)."""
        check_reads_never_actuate(url, profile, starter)
