"""The LineTask on real descriptors: the issue-11 property (every value answers the last request sent) with a
misbehaving scripted slave on a pty and over TCP, the task driven by ``run_task`` or by a poller that looks late;
and ``start_poll`` against the simulator, equal to ``poll``."""

from __future__ import annotations

import dataclasses
import random
import select
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core.device import open_device
from starterbus.core.errors import RemoteDeviceError, TimeoutError
from starterbus.core.polling import PollResult, run_task
from starterbus.tests.modbus.fault_peer import Step
from starterbus.tests.modbus.test_answer_belongs import (
    ATTEMPTS,
    FEW,
    PARAMS,
    Reader,
    pty_peer,
    read_and_check,
    rtu_transport,
    run,
    schedules,
    tcp_peer,
)
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse, Response
from starterbus.transports.modbus.driver.line_task import LineTask
from starterbus.transports.modbus.master.exchange import Exchange
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import SimFactory

#: how late the busy poller looks at a task, at most: more than the silent interval (2 ms at 19200 baud),
#: more than half the timeout
LATE = 0.003

Driver = Callable[[LineTask], PollResult]


def on_time(task: LineTask) -> PollResult:
    return run_task(task, time.monotonic)


def late_by_up_to(most: float, seed: int) -> Driver:
    """A poller busy with other lines: it gets to the task a random while after its input or its time came."""
    rng = random.Random(seed)

    def drive(task: LineTask) -> PollResult:
        try:
            while True:
                task.advance(time.monotonic())
                if task.done:
                    return task.result()
                wait = task.wake_at - time.monotonic()
                if wait > 0:
                    select.select([task.fd] if task.fd >= 0 else [], [], [], wait)
                select.select([], [], [], rng.random() * most)  # the other lines' work
        finally:
            task.cancel()

    return drive


def task_read(drive: Driver) -> Reader:
    """The registers read by one LineTask built as ``start_poll`` builds one (the transport's check)."""

    def read(transport: ModbusRtuTransport, address: int, count: int) -> tuple[int, ...]:
        line = transport.line
        exchange = Exchange(ReadRequest(transport.unit, address, count), transport.config.policy, line.char_time)
        answers: list[Response] = []

        def finish(responses: list[Response]) -> PollResult:
            answers.extend(responses)
            return PollResult(None, [])

        drive(LineTask(line, [exchange], transport.counters(), transport._refuse_exceptions, finish))
        (response,) = answers
        assert isinstance(response, ReadResponse)
        return response.values

    return read


@FEW
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_a_task_on_a_pty_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with pty_peer(schedule, seed) as (path, peer):
        run(f"modbus-rtu://{path}?{PARAMS}&retries=1", peer, 40, seed, task_read(on_time))


@FEW
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_a_task_advanced_late_on_a_pty_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with pty_peer(schedule, seed) as (path, peer):
        run(f"modbus-rtu://{path}?{PARAMS}&retries=1", peer, 40, seed, task_read(late_by_up_to(LATE, seed)))


@FEW
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_a_task_advanced_late_over_tcp_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with tcp_peer(schedule, seed) as (address, peer):
        run(f"modbus-rtu+tcp://{address}?{PARAMS}&retries=1", peer, 40, seed, task_read(late_by_up_to(LATE, seed)))


@pytest.mark.parametrize("late", [0.0, LATE])
def test_one_late_answer_is_not_the_next_tasks_value(late: float) -> None:
    """Issue 11's measured bug, through tasks: after one late answer the next read got its values."""
    late_then_ok: list[Step] = [("late", 0.99), ("ok", 0.0)]
    read = task_read(late_by_up_to(late, 2) if late else on_time)
    for _ in range(ATTEMPTS):  # until the peer keeps its script (a loaded machine may hold it up)
        with pty_peer(late_then_ok, 2) as (path, peer), rtu_transport(f"modbus-rtu://{path}?{PARAMS}&retries=0") as t:
            tally = read_and_check(t, peer, 2, 2, (2,), read)
        if not peer.off_script:
            break
    else:
        pytest.fail(f"the peer was held up in each of {ATTEMPTS} attempts: the case never ran as scripted")
    # a task that looked late took the late answer as its own: it answers request #0; request #1 gets its own
    # answer (on failure: what the peer wrote about both, when)
    assert tally.of(0) in ("TimeoutError", "value") and tally.of(1) == "value", (tally, peer.describe(0, 1))


def test_an_exception_answer_ends_start_poll_with_the_device_refusal() -> None:
    for _ in range(ATTEMPTS):  # until the peer answers in time (a loaded machine may hold it up)
        timed_out: TimeoutError | None = None
        with pty_peer([("exception", 0.0)], 0) as (path, peer), rtu_transport(f"modbus-rtu://{path}?{PARAMS}") as t:
            peer.watch(t.line.link, lambda: t.line.guard.started)
            task = t.start_poll([], True)
            assert task is not None
            try:
                run_task(task, time.monotonic)
            except RemoteDeviceError as refused:
                assert refused.code == 2 and refused.protocol == "modbus-rtu" and not t.line.lock.locked()
                if not peer.off_script:  # (else answered after the deadline: retried, the late answer a stray)
                    assert not t.line.guard.quarantined
                    assert (t.counters().requests, t.counters().errors) == (1, 0) and len(peer.requests) == 1
                    break
            except TimeoutError as exc:
                timed_out = exc
            else:
                pytest.fail("the exception answer ended the poll without an error")
        if timed_out is not None:  # held up past every attempt's deadline, or a bug: the closed peer's record tells
            in_time = [w for w in peer.writes if w.after <= peer.deadlines[w.seq]]
            seqs = range(len(peer.requests))
            assert not in_time, f"{timed_out}, though an answer came in time: {peer.describe(*seqs)}"
    else:
        pytest.fail(f"the peer was held up in each of {ATTEMPTS} attempts: the case never ran as scripted")


# -- against the simulator ------------------------------------------------------------------------------------


def test_start_poll_is_none_where_only_blocking_reads_work(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000", baudrate=19200)
    with open_device(sim.url(2, timeout=0.5, io="pyserial"), "jjr5000") as device:
        assert device.transport.start_poll([], True) is None
        assert device.transport.poll([], True).status is not None  # poll() is the way there


@pytest.mark.parametrize("model", ["jjr5000"])
def test_a_polls_task_gives_what_poll_gives_with_the_same_requests(model: str, make_sim: SimFactory) -> None:
    sim = make_sim(model, baudrate=19200)
    with open_device(sim.url(2, timeout=0.5), model) as device:
        transport = device.transport
        assert isinstance(transport, ModbusRtuTransport)
        points = [p for p in device.profile.points.values() if "modbus-rtu" in p.addresses]
        results, requests, counted = [], [], []
        for drive in (on_time, late_by_up_to(LATE, 1), None):
            before, sim_before = transport.counters().copy(), sim.counters.requests
            if drive is None:
                results.append(transport.poll(points, True))
            else:
                task = transport.start_poll(points, True)
                assert isinstance(task, LineTask)
                results.append(drive(task))
            requests.append(sim.counters.requests - sim_before)
            counted.append(transport.counters().minus(before))
        status = [dataclasses.replace(r.status, timestamp=0.0) for r in results if r.status is not None]
        assert len(status) == 3 and status[0] == status[1] == status[2]  # the same but for when it was read
        assert results[0].readings == results[1].readings == results[2].readings
        assert len(results[0].readings) == len(points)
        assert requests[0] == requests[1] == requests[2] == len(transport.plan(points, True)) > 1
        for c in counted:
            assert (c.transactions, c.requests, c.errors, c.timeouts) == (requests[0], requests[0], 0, 0)
            assert (c.bytes_sent, c.bytes_received) == (counted[2].bytes_sent, counted[2].bytes_received)
            assert c.wire_time == pytest.approx(counted[2].wire_time)


def test_a_poll_task_prepares_its_requests_once_for_each_policy(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000", baudrate=19200)
    with open_device(sim.url(2, timeout=0.5), "jjr5000") as device:
        transport = device.transport
        points = [p for p in device.profile.points.values() if "modbus-rtu" in p.addresses][:5]
        tasks = [transport.start_poll(points, True) for _ in range(2)]
        with transport.probe_policy(0.05):
            tasks.append(transport.start_poll(points, True))
        tasks.append(transport.start_poll(points, True))
        first, again, probe, after = (t._exchanges for t in tasks if isinstance(t, LineTask))
        assert again is first and after is first  # the same plan: the same prepared requests
        assert {e.policy.timeout for e in first} == {0.5} and {e.policy.timeout for e in probe} == {0.05}
        assert {e.attempts for e in probe} == {1}
        assert [e.request for e in probe] == [e.request for e in first]
        for task in tasks:
            assert task is not None
            task.cancel()
