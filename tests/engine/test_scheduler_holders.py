"""The loop's own thread and its holders (``Scheduler.hold`` / ``unhold``): one count, the first holder starts the
thread, the last one to let go stops it whoever started it, and the loop failing is told to every holder."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import pytest

from starterbus.core.scheduler import THREAD_NAME, Holder, Scheduler, Waiter


def runs(loop: Scheduler) -> bool:
    """``loop.running`` (read again: not narrowed by an earlier assert)."""
    return loop.running


def test_the_first_holder_starts_the_thread_and_the_last_one_to_let_go_stops_it() -> None:
    loop = Scheduler()
    device, fleet = Holder("device"), Holder("fleet")
    thread = loop.hold(device)
    assert thread is not None and thread.name == THREAD_NAME and loop.thread is thread
    assert loop.hold(fleet) is thread and loop.hold(fleet) is thread, "holding twice is holding once"
    loop.unhold(device)  # the one that started it lets go first
    assert loop.running and loop.thread is thread and loop.holders == ["fleet"]
    loop.unhold(device)  # not holding any more: nothing
    assert loop.running
    loop.unhold(fleet)
    assert not runs(loop) and not thread.is_alive() and loop.holders == []
    again = loop.hold(fleet)
    assert again is not None and again is not thread, "a new first holder starts a new thread"
    loop.unhold(fleet)
    assert not loop.running


def test_a_thread_started_without_a_hold_is_left_to_its_starter() -> None:
    loop = Scheduler()
    assert loop.start()
    holder = Holder("device")
    try:
        assert loop.hold(holder) is loop.thread
        loop.unhold(holder)
        assert loop.running, "not the holders' to stop"
    finally:
        loop.stop()
    assert not loop.running


def test_the_loop_failing_is_told_to_every_holder_whoever_started_it(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    loop = Scheduler()
    told: list[tuple[str, str, str, int]] = []  # (holder, error, thread, what a call led by the holder gave)

    def on_failure(name: str) -> Callable[[Exception], None]:
        def tell(error: Exception) -> None:
            led = loop.wait(loop.call(lambda now: 7), 5.0, "led by the told")  # the loop was given up
            told.append((name, str(error), threading.current_thread().name, led))
            if name == "first":
                raise ValueError("a holder failing to take it")

        return tell

    first, silent, second = (
        Holder("first", on_failure("first")),
        Holder("silent"),
        Holder("second", on_failure("second")),
    )
    thread = loop.hold(first)  # the first holder starts it: the others use it as it is
    loop.hold(silent)
    assert loop.hold(second) is thread and thread is not None
    original = Waiter.wait

    def broken(self: Waiter[Any], timeout: float) -> list[Any]:
        if threading.current_thread() is thread:
            raise RuntimeError("the selector broke")
        return original(self, timeout)

    monkeypatch.setattr(Waiter, "wait", broken)
    with caplog.at_level(logging.ERROR, logger="starterbus.core.scheduler"):
        loop.wake()
        thread.join(10.0)
    monkeypatch.setattr(Waiter, "wait", original)
    assert not thread.is_alive() and not loop.running
    assert told == [("first", "the selector broke", THREAD_NAME, 7), ("second", "the selector broke", THREAD_NAME, 7)]
    logged = [r.getMessage() for r in caplog.records]
    assert len(logged) == 1, logged
    assert logged[0].startswith("first: told that the I/O loop failed: ValueError: a holder failing to take it (at ")
    for holder in (first, silent, second):
        loop.unhold(holder)
    assert loop.holders == [] and not loop.running


def test_the_loop_failing_with_no_holder_to_tell_is_logged(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    loop = Scheduler()
    holder = Holder("device")  # keep_running's kind: no on_failure
    thread = loop.hold(holder)
    assert thread is not None
    original = Waiter.wait

    def broken(self: Waiter[Any], timeout: float) -> list[Any]:
        if threading.current_thread() is thread:
            raise RuntimeError("the selector broke")
        return original(self, timeout)

    monkeypatch.setattr(Waiter, "wait", broken)
    with caplog.at_level(logging.ERROR, logger="starterbus.core.scheduler"):
        loop.wake()
        thread.join(10.0)
    monkeypatch.setattr(Waiter, "wait", original)
    messages = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(messages) == 1 and messages[0].startswith(f"{THREAD_NAME} failed: RuntimeError: the selector broke (at ")
    assert messages[0].endswith("(holders: device)")
    loop.unhold(holder)
    assert not loop.running
