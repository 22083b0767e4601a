"""StationPoll's outer bound: the requests' own time limits end them, so only a stalled loop leaves a poll with
tickets that never end; the poll then ends with a TransportError at its bound, on either path, and withdraws them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any, cast

import pytest

from starterbus.core import PollResult, TransportError
from starterbus.transports.profibus_pkw.driver.link import STALL
from starterbus.transports.profibus_pkw.driver.poll import StationPoll


class StalledDriver:
    name = "station 4"

    def __init__(self) -> None:
        self.cancelled: list[Future[Any]] = []

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        self.cancelled += futures


class StalledLoop:
    """A loop that takes requests and never ends their tickets."""

    def __init__(self, driver: StalledDriver) -> None:
        self.driver = driver

    def submit_all(self, driver: StalledDriver, requests: Sequence[object]) -> list[Future[Any]]:
        return [Future() for _ in requests]

    def try_turn(self) -> bool:
        return True

    def call(self, fn: Callable[[float], None]) -> None:
        fn(0.0)


class FakeLink:
    def __init__(self) -> None:
        self.driver = StalledDriver()
        self.loop = StalledLoop(self.driver)

    def waits_on(self) -> tuple[int, float]:
        return -1, float("inf")  # nothing due: the engine waits for the loop


def ended(poll: StationPoll) -> bool:
    return poll.done


def finish(_: object) -> PollResult:
    raise AssertionError("no ticket ended: nothing to finish")


@pytest.mark.parametrize("in_the_loop", [True, False])
def test_a_stalled_loop_ends_the_poll_at_its_bound(in_the_loop: bool) -> None:
    link = FakeLink()
    poll = StationPoll(cast(Any, link), cast(Any, [object(), object()]), finish, bound=2.0)
    if in_the_loop:
        poll.on_progress = lambda: None
    poll.advance(100.0)
    assert not ended(poll) and poll.wake_at == 100.0 + 2.0 + STALL  # not later: the bound is woken for
    poll.advance(101.0)
    assert not ended(poll) and poll.wake_at == 100.0 + 2.0 + STALL  # fixed at the submission, never moved on
    poll.advance(100.0 + 2.0 + STALL)
    assert ended(poll)
    with pytest.raises(TransportError, match="station 4: the poll's exchanges did not end .*the loop stalled"):
        poll.result()
    assert len(link.driver.cancelled) == 2  # both withdrawn
