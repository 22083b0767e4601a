"""The kit's checks against a live device: the motor running (non-zero currents), the status after every command,
the device's refusals against the model's texts, several devices on one link, and the URL's validation."""

from __future__ import annotations

from collections.abc import Mapping

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import ConfigurationError, Refusal, RemoteDeviceError
from starterbus.core.model import Kind, Label
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import CW_BUS_CONTROL, PHASE_NAMES, MotorState, Status, decode_status_word
from starterbus.core.transport import Capability
from starterbus.testing.faults import query_keys, with_query
from starterbus.testing.kit_base import KitBase, phase, raw_values
from starterbus.testing.read_only import run_motor
from starterbus.testing.waits import wait_until

#: the status fields compared with the simulator's own status word (where the path reports them)
COMPARED = ("fault", "fault_code", "starting", "running", "stopping", "ready")
#: values every URL parameter must refuse (beyond the test class's own)
BAD_VALUES = ("x", "-1", "")


def disagreement(status: Status, starter: SimulatedStarter) -> list[str]:
    """Where ``status`` differs from what the starter's status word says (fields the path does not report,
    None, are not compared)."""
    truth = decode_status_word(starter.status_word(), starter.profile.faults)
    return [
        f"{name}: read {getattr(status, name)!r}, the device says {getattr(truth, name)!r}"
        for name in COMPARED
        if getattr(status, name) is not None and getattr(status, name) != getattr(truth, name)
    ]


def current_problems(status: Status, starter: SimulatedStarter, required: bool) -> list[str]:
    """The status's phase currents against the starter's (within the path's resolution); ``required``: at least
    one (a path may carry L1 only)."""
    problems = []
    if required and not status.currents:
        problems.append("no phase current in the status (the motor runs)")
    for name, point in zip(PHASE_NAMES, starter.profile.phase_currents(), strict=False):
        expected = float(point.to_engineering(starter.read(point)))
        value = status.currents.get(name)
        if value is None:  # a path may carry L1 only
            continue
        if abs(float(value.value) - expected) > value.resolution + 1e-9:
            problems.append(f"current {name}: read {value.text()}, the device reads {expected:g} {point.unit}")
    return problems


def model_texts(profile: Profile, transport: str) -> Mapping[int, str]:
    """The model's texts of the device's refusal codes on this transport (its ``exceptions`` or ``errors``)."""
    settings = profile.transport_settings(transport)
    for key in ("exceptions", "errors"):
        table = settings.get(key)
        if isinstance(table, Mapping):
            return {int(code): label.en if isinstance(label, Label) else str(label) for code, label in table.items()}
    return {}


class RunningChecks(KitBase):
    def test_status_and_measurements_with_the_motor_running(self, device: Device, starter: SimulatedStarter) -> None:
        """Currents are not zero: a status without them, or scaled wrongly, fails."""
        run_motor(starter)
        if Capability.STATUS in device.capabilities:
            required = self.status_has_currents and bool(device.profile.phase_currents())
            assert wait_until(lambda: device.status().state is MotorState.RUNNING), "the status never said running"
            assert current_problems(device.status(), starter, required) == []
            polled = device.transport.poll([], True).status
            assert polled is not None and current_problems(polled, starter, required) == [], "poll's status"
        if Capability.READ_MEASUREMENTS in device.capabilities:
            for point in self.addressed(device, Kind.MEASUREMENT):
                if device.transport.read_refusal(point) is not None:
                    continue  # read only under control (refused, never read by taking it)
                value = device.read(point)[point.key]
                expected = point.to_engineering(starter.read(point))
                assert abs(float(value.value) - float(expected)) <= value.resolution + 1e-9, (point.key, value)

    def test_the_status_agrees_after_every_command(self, device: Device, starter: SimulatedStarter) -> None:
        """Start, run, stop, and a fault reset twice: after each, the status read says what the device says."""
        if not {Capability.COMMANDS, Capability.STATUS} <= device.capabilities:
            pytest.skip(f"{self.transport} does not declare both commands and status")
        clock = starter.clock
        assert isinstance(clock, ManualClock)

        def agreed(what: str) -> None:
            problems: list[str] = []

            def same() -> bool:
                problems[:] = disagreement(device.status(), starter)
                return not problems

            assert wait_until(same), f"after {what}: {problems}"

        assert device.start().ok and starter.phase is Phase.STARTING
        if self.takes_bus_control:
            assert starter.control_word & CW_BUS_CONTROL, (
                f"the start reached the device without the bus-control bit: control word 0x{starter.control_word:04X}"
            )
        agreed("start")
        while phase(starter) is Phase.STARTING:
            clock.advance(1.0)
        agreed("the ramp (running)")
        assert device.stop().ok
        agreed("stop")
        for code in (2, 3):  # twice: the second reset must act as the first did
            starter.inject_fault(code)
            agreed(f"fault {code}")
            assert device.reset().ok and starter.fault_code is None, f"fault {code} still set after the reset"
            agreed(f"the reset of fault {code}")
        clock.advance(3600.0)  # any soft stop is over
        assert device.start().ok and phase(starter) is Phase.STARTING, "no start after the resets"
        agreed("the start after the resets")

    def test_refusals_carry_the_models_codes_and_texts(self, device: Device, starter: SimulatedStarter) -> None:
        """The device's own refusals (past the guard): the code the device sent, the model's text for it."""
        if Capability.WRITE_PARAMETERS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.WRITE_PARAMETERS.value}")
        texts, control = model_texts(device.profile, self.transport), device.profile.control
        targets = self.write_targets(device)[0]
        provoked = 0

        def refused(reason: Refusal, key: str, raw: int) -> None:
            point = device.profile.point(key)
            before = dict(starter.params)
            with pytest.raises(RemoteDeviceError) as info:
                device.send_write(point, raw)
            assert starter.params == before, f"{reason.value}: the refused write changed the device"
            expected = self.refusal_code(device.profile, reason)
            code, meaning = info.value.code, info.value.meaning
            assert expected is None or code == expected, f"{reason.value}: code {code}, the device sent {expected}"
            if code in texts:
                assert texts[code] in meaning, f"{reason.value}: code {code} reads {meaning!r}, not {texts[code]!r}"

        point = targets[0]
        refused(Refusal.OUT_OF_RANGE, point.key, point.raw_max + 1)
        provoked += 1
        if control.write_protect_key:
            allowed, starter.params[control.write_protect_key] = starter.params[control.write_protect_key], 0
            raw = next(v for v in raw_values(point) if v != starter.params[point.key])
            refused(Refusal.WRITE_PROTECTED, point.key, raw)
            starter.params[control.write_protect_key] = allowed
            provoked += 1
        locked = sorted(control.locked_while_running)
        if locked:
            run_motor(starter)
            key = locked[0]
            raw = next(v for v in raw_values(device.profile.point(key)) if v != starter.params[key])
            refused(Refusal.WHILE_RUNNING, key, raw)
            provoked += 1
        assert provoked

    def test_several_devices_on_one_link(self, profile: Profile) -> None:
        """Two starters at two addresses on one line: each read, write and command reaches its own."""
        first = SimulatedStarter(profile, ManualClock(0.0), load=0.5)
        second = SimulatedStarter(profile, ManualClock(0.0), load=0.3)
        try:
            context = self.serve_units([first, second])
        except NotImplementedError:
            pytest.skip(f"{type(self).__name__} implements no serve_units(starters): one device per link only")
        with context as urls, open_device(urls[0], profile) as one, open_device(urls[1], profile) as two:
            assert len(urls) == 2 and urls[0] != urls[1]
            if Capability.READ_PARAMETERS in one.capabilities:
                p, q = self.two_parameters(one, first)
                for point in (p, q):  # each unit holds other values than the other
                    second.params[point.key] = next(v for v in raw_values(point) if v != first.params[point.key])
                for device, starter in ((one, first), (two, second)):
                    got = {k: v.raw for k, v in device.read(p, q).items()}
                    assert got == {p.key: starter.params[p.key], q.key: starter.params[q.key]}, device.describe()
            if Capability.WRITE_PARAMETERS in one.capabilities:
                targets, uncertain = self.write_targets(two)
                point = targets[0]
                raw = next(v for v in raw_values(point) if v != second.params[point.key])
                untouched = dict(first.params)
                value = point.to_engineering(raw) if point.enum is None else raw
                two.write(point.key, value, accept_uncertain=uncertain)
                assert second.params[point.key] == raw and first.params == untouched, "the write reached another unit"
            if Capability.COMMANDS in one.capabilities:
                assert two.start().ok and second.phase is Phase.STARTING
                assert first.phase is Phase.STOPPED, "the start reached another unit"
                if Capability.STATUS in one.capabilities:
                    assert wait_until(lambda: two.status().state is MotorState.STARTING), "the started unit"
                    assert one.status().state is not MotorState.STARTING, "the other unit's status"
                assert one.start().ok and phase(first) is Phase.STARTING
                assert two.stop().ok and phase(second) in (Phase.STOPPING, Phase.STOPPED)
                assert phase(first) is Phase.STARTING, "the stop reached another unit"
            elif Capability.STATUS in one.capabilities:
                run_motor(first)
                assert wait_until(lambda: one.status().state is MotorState.RUNNING), "the running unit"
                assert two.status().state is not MotorState.RUNNING, "the other unit's status"

    def test_every_url_parameter_is_validated(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        """Each parameter the URL gives, with a wrong value, and an unknown parameter: refused when the device is
        opened (ConfigurationError naming the parameter), before anything is sent."""
        extra = self.invalid_url_values(profile)
        before = dict(starter.params), starter.control_writes_total
        accepted = []
        for key in [*query_keys(url), *(k for k in extra if k not in query_keys(url)), "no_such_parameter"]:
            for bad in (*BAD_VALUES, *extra.get(key, ())) if key != "no_such_parameter" else ("1",):
                text = with_query(url, **{key: bad})
                try:
                    with open_device(text, profile):
                        pass
                except ConfigurationError as exc:
                    assert key in str(exc).replace(text, ""), f"{key}={bad!r}: the error does not name it: {exc}"
                    continue
                accepted.append(f"{key}={bad!r}")
        assert accepted == [], f"{self.transport} accepts URL parameters it should refuse: {', '.join(accepted)}"
        assert (dict(starter.params), starter.control_writes_total) == before
