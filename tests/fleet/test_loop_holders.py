"""A fleet and a device kept running (``keep_running``: a DeviceNet master with a polled connection, an open
CANopen device) share the process loop's own thread in any order: one count of holders, the thread stopped only
when the last one lets go, and the loop failing seen by the fleet whoever started the thread."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pytest

from starterbus.core.media.keeper import keep_running, let_go
from starterbus.core.scheduler import THREAD_NAME, Scheduler, Waiter, scheduler
from starterbus.core.supervision import Backoff, Supervisor
from starterbus.fleet.poller import FleetPoller
from starterbus.testing import wait_until

if TYPE_CHECKING:
    from starterbus.tests.fleet.conftest import Lines, Samples


@pytest.fixture
def loop() -> Iterator[Scheduler]:
    """The process's scheduler, with no holder and no thread of its own before and after the test."""
    loop = scheduler()
    assert not loop.running, "a thread of the loop left running by another test"
    yield loop
    assert wait_until(lambda: not loop.running, 10.0)


def runs(loop: Scheduler) -> bool:
    """``loop.running`` (read again: not narrowed by an earlier assert)."""
    return loop.running


def served_by_its_own_thread(loop: Scheduler) -> bool:
    """Whether a call into the loop now runs in the loop's own thread (not led by this caller)."""
    name = loop.wait(loop.call(lambda now: threading.current_thread().name), 5.0, "which thread")
    return name == THREAD_NAME


def polls_on(samples: Samples, more: int = 6) -> None:
    mark = samples.mark()
    samples.wait_for(lambda ss: len(ss) >= mark + more, timeout=10.0)


def test_a_device_kept_running_first_then_a_fleet_the_device_letting_go_leaves_the_fleet_polling(
    lines: Lines, samples: Samples, loop: Scheduler
) -> None:
    keep_running(loop)  # a device opened before the fleet: it starts the loop's thread
    kept = True
    thread = loop.thread
    poller = FleetPoller(lines.fleet(buses=1), samples)
    assert poller.mux is not None
    try:
        poller.start()
        polls_on(samples)
        let_go(loop)
        kept = False
        polls_on(samples)  # the fleet still polls: the thread was not stopped under it
        assert loop.thread is thread and thread is not None and thread.is_alive()
        assert poller.mux.thread is thread
    finally:
        poller.stop()
        if kept:
            let_go(loop)
    assert not poller.running and poller.failure is None
    assert not loop.running, "the fleet, the last holder, stopped the thread"


def test_a_fleet_first_then_a_device_kept_running_and_let_go_leaves_the_fleet_alone(
    lines: Lines, samples: Samples, loop: Scheduler
) -> None:
    poller = FleetPoller(lines.fleet(buses=1), samples)
    assert poller.mux is not None
    with poller:
        polls_on(samples)
        thread = loop.thread
        keep_running(loop)  # a device opened and closed while the fleet polls (a script, a fleet job)
        assert loop.holders == ["fleet (1 buses)", "keep_running"]
        let_go(loop)
        polls_on(samples)
        assert loop.thread is thread and poller.mux.thread is thread and thread is not None
    assert not poller.running and poller.failure is None and not loop.running


def test_a_fleet_ending_while_a_device_is_kept_running_leaves_the_thread_to_the_device(
    lines: Lines, samples: Samples, loop: Scheduler
) -> None:
    poller = FleetPoller(lines.fleet(buses=1), samples)
    assert poller.mux is not None
    poller.start()
    kept = False
    try:
        polls_on(samples, 3)
        keep_running(loop)
        kept = True
        thread = poller.mux.thread
        poller.stop()
        assert not poller.running and poller.failure is None
        assert loop.running and loop.thread is thread and served_by_its_own_thread(loop), "the device still served"
        let_go(loop)
        kept = False
        assert not runs(loop) and not thread.is_alive(), "the last holder let go: the thread ended"
    finally:
        poller.stop()
        if kept:
            let_go(loop)


def test_the_loop_failing_is_the_fleet_s_failure_when_a_device_started_the_thread(
    lines: Lines, samples: Samples, loop: Scheduler, monkeypatch: pytest.MonkeyPatch
) -> None:
    supervisor = Supervisor(Backoff(first=0.01, longest=0.05))
    poller = FleetPoller(lines.fleet(buses=1), samples, supervisor=supervisor)
    keep_running(loop)  # the device starts the loop's thread, not the fleet
    try:
        poller.start()
        polls_on(samples, 3)
        broken = threading.Event()
        original = Waiter.wait

        def wait(self: Waiter[Any], timeout: float) -> list[Any]:
            if threading.current_thread() is loop.thread and not broken.is_set():
                broken.set()
                raise RuntimeError("the selector broke")
            return original(self, timeout)

        monkeypatch.setattr(Waiter, "wait", wait)
        assert wait_until(lambda: poller.failure is not None, 10.0), "the fleet did not see its loop fail"
        poller.join(30.0)
        assert not poller.running, "the fleet stopped (no quiet stall)"
        assert poller.failure is not None and poller.failure.worker == THREAD_NAME
        assert str(poller.failure).startswith(f"{THREAD_NAME} failed: RuntimeError: the selector broke (at ")
        assert supervisor.failures == {THREAD_NAME: 1}
        assert not loop.running and loop.holders == ["keep_running"]
    finally:
        monkeypatch.undo()
        poller.stop()
        let_go(loop)
    assert loop.holders == [] and not loop.running
