"""A fleet's poll of a CANopen device as a PollTask (no thread per bus): the same result as the blocking poll,
driven by its own descriptor or told by ``on_progress``; an SDO error ends it typed; a cancel leaves the node
quiet (a late answer is never the next poll's value)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import can
import pytest
from starterbus_canopen.poll import SdoPoll
from starterbus_canopen.simulator import CanopenSimulator
from starterbus_canopen.transport import CanopenTransport

from starterbus.core import (
    ManualClock,
    PollResult,
    RemoteDeviceError,
    SimulatedStarter,
    TransportError,
    get_profile,
    open_device,
    run_task,
)
from starterbus.testing import wait_until

MODEL = "example_canopen_starter"


@pytest.fixture
def transport(channel: str) -> Iterator[CanopenTransport]:
    starter = SimulatedStarter(get_profile(MODEL), ManualClock(0.0))
    starter.params["current_limit"] = 420
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5&max_age=0", MODEL) as device:
            assert isinstance(device.transport, CanopenTransport)
            yield device.transport


def values(result: PollResult) -> dict[str, int]:
    return {reading.point.key: reading.raw for reading in result.readings}


def test_a_poll_task_gives_what_the_blocking_poll_gives(transport: CanopenTransport) -> None:
    points = [transport.profile.point(key) for key in ("current_limit", "phase_a_current")]
    task = transport.start_poll(points, status=True)
    assert isinstance(task, SdoPoll)
    result = run_task(task, time.monotonic)
    blocking = transport.poll(points, status=True)
    assert values(result) == values(blocking) == {"current_limit": 420, "phase_a_current": 0}
    assert result.status is not None and result.status.source == "canopen SDO"
    assert result.status.state == blocking.status.state  # type: ignore[union-attr]


def test_a_poll_task_told_by_on_progress_needs_no_descriptor(transport: CanopenTransport) -> None:
    task = transport.start_poll([transport.profile.point("current_limit")], status=True)
    assert isinstance(task, SdoPoll)
    told = threading.Event()
    task.on_progress = told.set
    task.advance(time.monotonic())
    while not task.done:
        assert task.fd == -1
        assert wait_until(told.is_set)
        told.clear()
        task.advance(time.monotonic())
    assert values(task.result()) == {"current_limit": 420}


def test_an_sdo_abort_ends_the_poll_with_its_error(
    transport: CanopenTransport, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(transport, "_address", lambda point, what: (0x2FFF, 0))  # an object the node lacks
    task = transport.start_poll([transport.profile.point("current_limit")], status=False)
    assert task is not None
    with pytest.raises(RemoteDeviceError) as info:
        run_task(task, time.monotonic)
    assert info.value.code == 0x06020000 and task.done


def test_a_cancelled_poll_leaves_the_node_quiet_and_fails_typed(transport: CanopenTransport, channel: str) -> None:
    """Node 9 is not served: the poll's transfer stays out until it is cancelled; its answer, coming after the
    cancel, is dropped (counted) and answers nothing."""
    with open_device(f"canopen://virtual/{channel}?node=9&heartbeat=0&timeout=2", MODEL) as device:
        silent = device.transport
        assert isinstance(silent, CanopenTransport)
        engine = silent.engine
        task = silent.start_poll([silent.profile.point("current_limit")], status=False)
        assert task is not None
        task.advance(time.monotonic())
        assert wait_until(lambda: engine.transfers == 1)
        task.cancel()
        assert task.done and wait_until(lambda: engine.quiet_until > 0)  # withdrawn in the loop, at its next turn
        with pytest.raises(TransportError, match="cancelled"):
            task.result()
        with can.Bus(interface="virtual", channel=channel) as bystander:  # the late answer: 0x2103:00 = 420
            bystander.send(
                can.Message(arbitration_id=0x589, data=bytes.fromhex("4B032100A4010000"), is_extended_id=False)
            )
            assert wait_until(lambda: engine.stale == 1)
        assert engine.pending == 0


def test_a_fleet_polls_a_canopen_bus_from_the_scheduler_without_a_thread_of_its_own(channel: str) -> None:
    from starterbus.fleet.config import parse_fleet
    from starterbus.fleet.poller import FleetPoller, Sample

    starter = SimulatedStarter(get_profile(MODEL), ManualClock(0.0))
    starter.params["current_limit"] = 410
    config = parse_fleet(
        f"""
[poll]
period = 0.05

[[bus]]
name = "can"
url = "canopen://virtual/{channel}?heartbeat=50"

  [[bus.device]]
  name = "fan"
  model = "{MODEL}"
  address = 5
  parameters = ["current_limit"]
""",
        "fleet.toml",
    )
    samples: list[tuple[str, Sample]] = []
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(starter, 5)
        poller = FleetPoller(config, lambda s: samples.append((threading.current_thread().name, s)), rounds=3)
        poller.start()
        poller.join(30)
        assert not poller.running
    assert len(samples) == 3 and all(s.online and s.values["current_limit"].raw == 410 for _, s in samples)
    assert {thread for thread, _ in samples} == {"starterbus-io"}  # the loop's thread: no bus-can thread polled
