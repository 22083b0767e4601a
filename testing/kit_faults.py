"""The kit's checks through the fault hook (:mod:`starterbus.testing.faults`): what is sent (previews, writes sent
once, the poll plan and the counters) and a device that is silent, slow, late, duplicating, busy or unreachable
behind a gateway. Each check that needs the hook skips, saying so, when the test class has none."""

from __future__ import annotations

import time

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import RemoteDeviceError, StarterbusError, TimeoutError
from starterbus.core.model import Kind, PointDef
from starterbus.core.polling import run_task
from starterbus.core.profile import Profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.status import Command
from starterbus.core.transport import Capability, TransportCounters
from starterbus.testing.faults import Fault, FaultControl, FaultsNotProvided, preview_text, same_frames
from starterbus.testing.kit_base import KitBase, raw_values
from starterbus.testing.waits import wait_until

#: the probe timeout the kit asks for (seconds)
PROBE_TIMEOUT = 0.1
#: how long a request that was sent may take to reach a held-up device's record (seconds)
RECORDED = 10.0


def sent_during(control: FaultControl, mark: int) -> list[str]:
    return preview_text(control.requests[mark:])


def counted(device: Device) -> TransportCounters | None:
    counters = device.transport.counters()
    return None if counters is None else counters.copy()


def raw_of(device: Device, point: PointDef) -> int:
    return device.read(point)[point.key].raw


class FaultChecks(KitBase):
    def test_previews_are_what_is_sent_and_writes_go_once(self, device: Device, starter: SimulatedStarter) -> None:
        """A write's and a command's preview are the frames then sent, once each."""
        with self.tap(starter) as tap:
            compared = 0
            if Capability.WRITE_PARAMETERS in device.capabilities:
                for point in self.write_targets(device)[0][:2]:
                    raw = next(v for v in reversed(raw_values(point)) if v != starter.params[point.key])
                    preview = preview_text(device.transport.preview_write(point, raw))
                    mark = len(tap.requests)
                    device.send_write(point, raw)
                    sent = sent_during(tap, mark)
                    assert same_frames(sent, preview), f"{point.key}={raw}: sent {sent}, the preview {preview}"
                    assert starter.params[point.key] == raw
                    compared += 1
            if Capability.COMMANDS in device.capabilities:
                for command in (Command.START, Command.SOFT_STOP, Command.FAULT_RESET):
                    preview = preview_text(device.transport.preview_command(command))
                    mark = len(tap.requests)
                    device.send_command(command)
                    sent = sent_during(tap, mark)
                    assert same_frames(sent, preview), f"{command.value}: sent {sent}, the preview {preview}"
                    compared += 1
            if not compared:
                pytest.skip(f"{self.transport} neither writes nor commands")

    def test_plan_and_counters_tell_what_a_poll_sends(self, device: Device, starter: SimulatedStarter) -> None:
        transport = device.transport
        status = Capability.STATUS in device.capabilities
        reads = Capability.READ_MEASUREMENTS in transport.capabilities
        points = (
            [p for p in self.addressed(device, Kind.MEASUREMENT) if transport.read_refusal(p) is None] if reads else []
        )
        if not points and not status:
            pytest.skip(f"{self.transport} polls nothing")
        plan = transport.plan(points, status)
        assert plan, "an empty plan for a poll that asks for something"
        if self.merges_requests and len(points) > 1:
            assert len(plan) < len(points), f"no request merged: {len(points)} points, {[p.text for p in plan]}"
        try:
            context = self.faults(starter)
        except FaultsNotProvided:  # no hook: the counters are still checked
            context = None
        before = counted(device)
        if context is None:
            transport.poll(points, status)
            sent = None
        else:
            with context as tap:
                mark = len(tap.requests)
                transport.poll(points, status)
                sent = len(tap.requests) - mark
                planned = sum(request.frames for request in plan)
                assert sent == planned, f"the poll sent {sent} requests, its plan says {planned}"
                task = transport.start_poll(points, status)
                if task is not None:
                    plan = transport.plan(points, status)  # what the session has done may change it (PKW's fences)
                    mark = len(tap.requests)
                    run_task(task, time.monotonic)
                    assert len(tap.requests) - mark == sum(r.frames for r in plan), "a poll task sent another plan"
        after = counted(device)
        if before is not None and after is not None:
            grown = after.minus(before)
            assert grown.transactions > 0 and grown.bytes_sent > 0 and grown.bytes_received > 0, grown
            assert sent is None or grown.requests >= sent, f"counted {grown.requests} requests, {sent} were sent"

    def test_a_silent_device(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        """No answer: a read times out after exactly the URL's retries, counted; a write is sent once; a probe
        tries once; the fleet says offline. The device answers again: the right values."""
        faulty = self.url_with(url, timeout=self.fault_timeout, retries=1)
        with self.tap(starter) as tap, open_device(faulty, profile) as device:
            p, q = self.two_parameters(device, starter)
            mark = len(tap.requests)
            assert raw_of(device, p) == starter.params[p.key]
            per_attempt = len(tap.requests) - mark
            of_p = tap.requests[mark:]
            mark = len(tap.requests)
            assert raw_of(device, q) == starter.params[q.key]
            marker = tap.requests[mark]  # the first request of a read of q: it ends a record (unanswered_since)
            assert marker not in of_p, f"the device records reads of {p.key} and {q.key} alike: {marker}"
            before = counted(device)
            self.set_fault(tap, Fault.SILENT)
            mark = len(tap.requests)
            with pytest.raises(TimeoutError):
                device.read(p)
            sent = self.unanswered_since(device, tap, mark, q, marker)
            assert len(sent) == 2 * per_attempt, f"requests for one read with one retry: {sent}"
            after = counted(device)
            if before is not None and after is not None:
                grown = after.minus(before)
                assert grown.timeouts >= 1 and grown.retries >= 1 and grown.requests >= 2 * per_attempt, grown
            for name, probe in (
                ("read", device.transport.read_points),
                ("poll", lambda ps: device.transport.poll(ps, False)),
            ):
                mark = len(tap.requests)
                with device.transport.probe_policy(PROBE_TIMEOUT), pytest.raises(TimeoutError):
                    probe([p])
                sent = self.unanswered_since(device, tap, mark, q, marker)
                assert len(sent) == per_attempt, f"a probe ({name}) retried: probe_policy is one attempt: {sent}"
            if Capability.WRITE_PARAMETERS in device.capabilities:
                point = self.write_targets(device)[0][0]
                raw = next(v for v in raw_values(point) if v != starter.params[point.key])
                preview = preview_text(device.transport.preview_write(point, raw))
                mark = len(tap.requests)
                with pytest.raises(TimeoutError):
                    device.send_write(point, raw)
                # the device answers a read only after every request sent before it: then its record is complete
                # (a device held up on a loaded machine records a write, or its repeat, after the master gave up)
                tap.set(None)
                assert raw_of(device, p) == starter.params[p.key]
                sent = sent_during(tap, mark)
                assert same_frames(sent[: len(preview)], preview), f"a write whose answer was lost: sent {sent}"
                later = sent[len(preview) :]
                repeated = [frame for frame in later if any(same_frames([frame], [each]) for each in preview)]
                assert not repeated, f"a write whose answer was lost was sent again: {repeated}"
                self.set_fault(tap, Fault.SILENT)
            self.fleet_offline(faulty, profile)
            tap.set(None)
            assert raw_of(device, p) == starter.params[p.key]

    def unanswered_since(self, device: Device, tap: FaultControl, mark: int, other: PointDef, marker: str) -> list[str]:
        """Every request that reached the silent device since ``mark``, the record complete. A device held up on
        a loaded machine records a request after the master gave up on it, so one more read follows (of
        ``other``, one attempt, unanswered), and the record is taken once that read's first request
        (``marker``) is in it: the device records requests in the order they were sent."""
        with device.transport.probe_policy(PROBE_TIMEOUT), pytest.raises(TimeoutError):
            device.transport.read_points([other])
        if not wait_until(lambda: marker in tap.requests[mark:], RECORDED):
            pytest.fail(f"the device did not record the read of {other.key} ({marker}) within {RECORDED:g} s")
        sent = list(tap.requests[mark:])
        return sent[: sent.index(marker)]

    def fleet_offline(self, url: str, profile: Profile) -> None:
        from starterbus.fleet.config import build_fleet
        from starterbus.fleet.poller import FleetPoller
        from starterbus.fleet.sample import Sample

        config = build_fleet(
            {"bus": [{"name": "kit", "url": url, "device": [{"name": "dut", "model": profile.name}]}]}, "<kit>"
        )
        samples: list[Sample] = []
        poller = FleetPoller(config, samples.append, rounds=1).start()
        try:
            poller.join(30.0)
        finally:
            poller.stop()
        assert samples and not samples[0].online and samples[0].error, "a device that does not answer is online"

    def test_a_slow_device_is_waited_for(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        """An answer later than the default timeout, within the URL's: a value (the URL's timeout is used)."""
        slow = self.url_with(url, timeout=2 * self.slow_answer, retries=0)
        with self.tap(starter) as tap, open_device(slow, profile) as device:
            p, q = self.two_parameters(device, starter)
            assert raw_of(device, q) == starter.params[q.key]  # it answered in time before (a session is set up)
            self.set_fault(tap, Fault.SLOW, self.slow_answer)
            assert raw_of(device, p) == starter.params[p.key]
            tap.set(None)
            assert raw_of(device, q) == starter.params[q.key]

    def _one_fault(self, url: str, profile: Profile, starter: SimulatedStarter, fault: Fault) -> StarterbusError | None:
        """Read p under ``fault`` (a value must be right; an error must be typed), then q and p without it. After
        a late answer, q is read again and again until that answer has come and gone: a transport whose reads take
        longer than the delay (several frames each) still has a read of q waiting when it comes."""
        faulty = self.url_with(url, timeout=self.fault_timeout, retries=0)
        error: StarterbusError | None = None
        delay = 1.75 * self.fault_timeout if fault is Fault.LATE else 0.0
        with self.tap(starter) as tap, open_device(faulty, profile) as device:
            p, q = self.two_parameters(device, starter)
            self.set_fault(tap, fault, delay)
            asked = time.monotonic()
            try:
                assert raw_of(device, p) == starter.params[p.key], f"{fault.value}: a wrong value"
            except StarterbusError as exc:
                error = exc
            tap.set(None)
            while True:
                got = raw_of(device, q)
                assert got == starter.params[q.key], f"after a {fault.value} answer to {p.key}, {q.key} read {got}"
                if time.monotonic() > asked + 2 * delay:
                    break
            assert raw_of(device, p) == starter.params[p.key]
        return error

    def test_a_late_answer_is_never_a_value(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        error = self._one_fault(url, profile, starter, Fault.LATE)
        assert isinstance(error, TimeoutError), f"an answer after the timeout: {error!r}"

    def test_a_duplicated_answer_is_never_a_value(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        self._one_fault(url, profile, starter, Fault.DUPLICATE)

    def test_a_busy_device_gives_no_value(self, url: str, profile: Profile, starter: SimulatedStarter) -> None:
        error = self._one_fault(url, profile, starter, Fault.BUSY)
        assert isinstance(error, RemoteDeviceError), f"a busy device's refusal: {error!r}"

    def test_an_unreachable_device_is_no_answer_not_a_refusal(
        self, url: str, profile: Profile, starter: SimulatedStarter
    ) -> None:
        """A gateway's "target device failed to respond": the device is offline (probed), it refused nothing."""
        error = self._one_fault(url, profile, starter, Fault.UNREACHABLE)
        assert isinstance(error, TimeoutError) and not isinstance(error, RemoteDeviceError), (
            f"a gateway's 'no answer from the device' was taken as {error!r}"
        )
