"""What the fleet (and a sync caller's fast path) use of the scheduler: a driver marked due is stepped at the
next turn from any thread, the leadership taken and given back without a turn, the loop's own thread given by
the caller, the loop failing raised out of ``serve``, and drivers overdue in one turn stepped the longest overdue
first."""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Sequence
from concurrent.futures import Future
from typing import Any

import pytest

from starterbus.core.engine import Ticket
from starterbus.core.errors import StarterbusError
from starterbus.core.scheduler import Scheduler, Waiter
from starterbus.testing import wait_until


class Counting:
    """A driver with no descriptor and no deadline: stepped only when marked due; ``again`` times it marks
    itself due from inside its own step."""

    def __init__(self, loop: Scheduler, again: int = 0) -> None:
        self.name = "counting"
        self.loop, self.again = loop, again
        self.steps = 0
        self.in_loop: list[bool] = []
        self.fd, self.writing, self.deadline = -1, False, math.inf

    def step(self, now: float, ready: bool) -> None:
        self.steps += 1
        self.in_loop.append(self.loop.in_loop())
        if self.again:
            self.again -= 1
            self.loop.due(self)

    def submit(
        self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]
    ) -> list[Ticket[Any, Any]]:
        raise AssertionError("no requests")

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        pass

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        pass

    def crash(self, error: StarterbusError, now: float) -> None:
        raise AssertionError(f"crashed: {error}")


def state(loop: Scheduler) -> tuple[bool, threading.Thread | None]:
    return loop.running, loop.thread


def test_a_driver_marked_due_is_stepped_at_the_next_turn_and_one_not_served_is_left_alone() -> None:
    loop = Scheduler()
    served, other = Counting(loop, again=2), Counting(loop)
    assert loop.start()
    try:
        loop.wait(loop.call(lambda now: loop.add(served)), 5.0, "add")
        loop.due(served)  # from this thread: through the inbox
        loop.due(other)  # never added
        assert wait_until(lambda: served.steps == 3, 5.0), served.steps  # twice more, marked due from its step
        loop.wait(loop.call(lambda now: None), 5.0, "one more turn")
        assert served.steps == 3 and other.steps == 0
        assert served.in_loop == [True, True, True] and not loop.in_loop()
    finally:
        loop.stop()


def test_the_leadership_is_taken_and_given_back_without_a_turn() -> None:
    loop = Scheduler()
    assert loop.lead() and loop.in_loop()
    elsewhere: list[bool] = []
    thread = threading.Thread(target=lambda: elsewhere.append(loop.lead()))
    thread.start()
    thread.join(5.0)
    assert elsewhere == [False], "another thread leads"
    loop.release()
    assert not loop.in_loop()
    loop.call(lambda now: None)  # queued, not served: the next leader must serve it first
    assert not loop.lead()
    loop.wait(loop.call(lambda now: None), 5.0, "served")  # the caller led a turn and served both
    assert loop.lead()
    loop.release()
    assert loop.start()
    try:
        assert not loop.lead(), "the loop's own thread leads"
        assert not loop.start(), "already running"
    finally:
        loop.stop()


def test_the_loop_s_own_thread_may_be_the_caller_s_and_a_failing_loop_raises_out_of_serve(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    loop = Scheduler()
    raised: list[BaseException] = []

    def run() -> None:
        try:
            loop.serve()
        except RuntimeError as exc:
            raised.append(exc)

    thread = threading.Thread(target=run, name="given")
    assert loop.start(thread)
    assert state(loop) == (True, thread)
    original = Waiter.wait

    def broken(self: Waiter[Any], timeout: float) -> list[Any]:
        if threading.current_thread() is thread:
            raise RuntimeError("the selector broke")
        return original(self, timeout)

    monkeypatch.setattr(Waiter, "wait", broken)
    loop.wake()
    thread.join(5.0)
    assert [str(e) for e in raised] == ["the selector broke"]
    assert state(loop) == (False, None)
    monkeypatch.setattr(Waiter, "wait", original)
    assert loop.wait(loop.call(lambda now: 7), 5.0, "led again") == 7, "callers lead again"


class Watching(Counting):
    """A driver watching ``fd`` (set by the test); its steps with the descriptor ready are counted and drain it."""

    def __init__(self, loop: Scheduler, name: str) -> None:
        super().__init__(loop)
        self.name = name
        self.ready = 0

    def step(self, now: float, ready: bool) -> None:
        super().step(now, ready)
        if ready:
            self.ready += 1
            os.read(self.fd, 64)


def test_a_descriptor_taken_over_in_the_turn_before_its_watcher_lets_go_stays_watched() -> None:
    """A line's poll and its blocking callers' tickets take turns on the line's descriptor: whichever order the
    loop reads them in, the driver that has it now is woken by input."""
    loop = Scheduler()
    r, w = os.pipe()
    try:
        later, first = Watching(loop, "later"), Watching(loop, "first")

        def add_both(now: float) -> None:  # read in this order at every turn
            loop.add(later)
            loop.add(first)

        loop.call(add_both)
        first.fd = r
        assert loop.try_turn()
        later.fd, first.fd = r, -1  # the one read first takes it before the other lets go
        assert loop.try_turn()
        os.write(w, b"!")
        assert loop.try_turn()
        assert (later.ready, first.ready) == (1, 0)
        later.fd, first.fd = -1, r  # and back
        assert loop.try_turn()
        os.write(w, b"!")
        assert loop.try_turn()
        assert (later.ready, first.ready) == (1, 1)
    finally:
        os.close(r)
        os.close(w)


class Timed(Counting):
    """A driver due at ``deadline`` (set by the test); its steps are logged, by name, in ``log``; once stepped it is
    never due again."""

    def __init__(self, loop: Scheduler, name: str, log: list[str]) -> None:
        super().__init__(loop)
        self.name, self.log = name, log

    def step(self, now: float, ready: bool) -> None:
        super().step(now, ready)
        self.log.append(self.name)
        self.deadline = math.inf


def test_drivers_overdue_in_one_turn_are_stepped_the_longest_overdue_first() -> None:
    """Whatever their places among the drivers: the last added (a line added last, a CAN bus after sixteen RTU
    lines) waits for no other because of its place."""
    loop = Scheduler()
    log: list[str] = []
    drivers = [Timed(loop, name, log) for name in ("a", "b", "c", "d")]

    def add_all(now: float) -> None:
        for driver in drivers:
            loop.add(driver)

    loop.call(add_all)
    assert loop.try_turn()
    now = loop.clock()
    for driver, overdue in zip(drivers, (0.001, 0.004, 0.003, 0.002), strict=True):
        driver.deadline = now - overdue
    assert loop.try_turn()
    assert log == ["b", "c", "d", "a"]
    assert loop.try_turn()
    assert log == ["b", "c", "d", "a"], "each stepped once: nothing due since"


def test_a_driver_whose_deadline_a_step_before_it_moved_is_not_stepped_in_that_turn() -> None:
    """A step may serve another driver (a line's poll and its blocking callers' tickets share the line): the other,
    overdue when the turn began, is stepped only if it still is."""
    loop = Scheduler()
    log: list[str] = []
    first, second = Timed(loop, "first", log), Timed(loop, "second", log)
    serve = first.step

    def step_serving_second(now: float, ready: bool) -> None:
        serve(now, ready)
        second.deadline = math.inf

    first.step = step_serving_second  # type: ignore[method-assign]

    def add_both(now: float) -> None:
        loop.add(second)
        loop.add(first)

    loop.call(add_both)
    assert loop.try_turn()
    now = loop.clock()
    first.deadline, second.deadline = now - 0.002, now - 0.001
    assert loop.try_turn()
    assert log == ["first"]
