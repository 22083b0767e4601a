"""A fleet's DeviceNet poll as a PollTask (no thread per bus): monitoring reads the input assembly over explicit
messaging with no output data; a master that polls answers from a fresh sample and selects status parameters in
turn; taking control again (control=open after a loss) is a task too, refused while a motor runs from
elsewhere."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from starterbus.core import Device, ManualClock, MotorState, Phase, Profile, SimulatedStarter, open_device, run_task
from starterbus.transports.devicenet.codec.ids import poll_command_id
from starterbus.transports.devicenet.driver.scanner import SlaveLink
from starterbus.transports.devicenet.simulator import DeviceNetSlaveSimulator
from starterbus.transports.devicenet.transport import ControlConflictError, DeviceNetTransport

FAST = "dup_mac_wait=0.05&timeout=0.5&epr=50&poll=10"


@pytest.fixture
def simulated(channel: str, jjr8000: Profile) -> Iterator[SimulatedStarter]:
    starter = SimulatedStarter(jjr8000, ManualClock(0.0))
    with DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05):
        yield starter


def polls(link: SlaveLink) -> bool:
    return link.polling


def transport(device: Device) -> DeviceNetTransport:
    assert isinstance(device.transport, DeviceNetTransport)
    return device.transport


def test_a_monitoring_poll_is_a_task_that_sends_no_output_data(
    channel: str, simulated: SimulatedStarter, sniffer: object, jjr8000: Profile
) -> None:
    phase_a = jjr8000.phase_currents()[0]
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}", jjr8000) as device:
        before = {t.name for t in threading.enumerate()}
        task = transport(device).start_poll([phase_a], True)
        assert task is not None
        result = run_task(task, time.monotonic)
        assert result.status is not None and result.status.state is MotorState.STOPPED
        assert [r.point.key for r in result.readings] == [phase_a.key] and result.readings[0].scale == 1.0
        started = {t.name for t in threading.enumerate()} - before
        # the task started no thread; a poller outside the loop waits on the bus's descriptor: the reader's pipe
        assert started <= {f"can-reader virtual/{channel}"}
    commands = [t for t in sniffer.texts() if t.startswith(f"{poll_command_id(5):03X}#")]  # type: ignore[attr-defined]
    assert commands == []


def test_a_polling_master_answers_from_a_fresh_sample(channel: str, simulated: SimulatedStarter) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}&control=open", "jjr8000") as device:
        link = transport(device).link
        assert link is not None and link.polling
        polls = link.responses
        task = transport(device).start_poll([], True)
        assert task is not None
        result = run_task(task, time.monotonic)
        assert result.status is not None and result.status.state is MotorState.STOPPED
        assert result.status.raw["selected_address"] is not None  # from a poll answer, not the explicit read
        assert link.responses > polls


def test_status_parameters_are_selected_by_the_task(
    channel: str, simulated: SimulatedStarter, jjr8000: Profile
) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}&control=open", jjr8000) as device:
        points = [jjr8000.point("m3"), jjr8000.point("status_word")]
        task = transport(device).start_poll(points, True)
        assert task is not None
        result = run_task(task, time.monotonic)
        assert result.status is not None and result.status.state is MotorState.STOPPED
        by_key = {r.point.key: r.raw for r in result.readings}
        assert by_key["phase_b_current"] == simulated.read(jjr8000.point("m3"))
        assert by_key["status_word"] == simulated.read(jjr8000.point("status_word"))


def test_taking_control_again_is_a_poll_task(channel: str, simulated: SimulatedStarter) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}&control=open", "jjr8000") as device:
        link = transport(device).link
        assert link is not None
        transport(device).scanner.release_control(link)  # type: ignore[union-attr]  # as a loss would leave it
        mark = simulated.control_writes_total
        before = {t.name for t in threading.enumerate()}
        task = transport(device).start_poll([], True)
        assert task is not None and not link.polling  # nothing sent before the task's first advance
        result = run_task(task, time.monotonic)
        assert result.status is not None and result.status.state is MotorState.STOPPED
        assert transport(device).link is link and polls(link)  # the task took control again
        assert {t.name for t in threading.enumerate()} <= before  # the task started no thread
        assert all(not w.word & 0x0001 for w in simulated.control_writes_since(mark))  # never a run bit


def test_taking_control_again_in_a_task_never_stops_a_motor_run_from_elsewhere(
    channel: str, simulated: SimulatedStarter, jjr8000: Profile
) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}&control=open", jjr8000) as device:
        link = transport(device).link
        scanner = transport(device).scanner
        assert link is not None and scanner is not None
        scanner.release_control(link)  # as a loss would leave it
        assert simulated.start("keypad")
        mark, polls = simulated.control_writes_total, scanner.polls_sent
        task = transport(device).start_poll([], True)
        assert task is not None
        result = run_task(task, time.monotonic)  # the status monitors: control is not taken
        assert result.status is not None and result.status.state in (MotorState.STARTING, MotorState.RUNNING)
        points = transport(device).start_poll([jjr8000.point("status_word")], True)
        assert points is not None
        refused = r"under another control .*; taking control again \(control=open\)"
        with pytest.raises(ControlConflictError, match=refused):
            run_task(points, time.monotonic)  # a status parameter needs the polled connection: refused
        assert not link.polling and simulated.control_writes_since(mark) == []
        assert scanner.polls_sent == polls  # no poll (whose output would carry run = 0) went out
        assert simulated.phase is not Phase.STOPPED
