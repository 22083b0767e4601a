"""A poll written once as a generator of requests on one driver of the scheduler, run blocking
(:func:`run_steps`) or as the fleet's :class:`~starterbus.core.polling.PollTask` (:class:`TicketPoll`).

The generator yields a request, is sent its ticket's result (or thrown its error, a ``StarterbusError``) and
returns its own result. Each request carries its time limit (``timeout``, kept by the engine); a wait's outer
bound adds ``stall``, which only a stalled loop reaches.

:class:`TicketPoll` submits one request at a time to the driver and never blocks. Advanced by the fleet from the
loop's thread (``on_progress`` set: docs/engine.md, step 4), the ticket's future calls ``on_progress`` when it
ends and the task waits for nothing else. Advanced from elsewhere, each :meth:`~TicketPoll.advance` runs one turn
of the scheduler (``try_turn``; the caller waits on the driver's descriptor and deadline) or, while another thread
leads, waits on a pipe of its own that the future's done callback writes to.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Generator
from concurrent.futures import Future
from typing import Any, Generic, Protocol, TypeVar

from starterbus.core.engine import Ticket
from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.polling import PollResult, PollTask
from starterbus.core.scheduler import Scheduler, Served

__all__ = ["STALL", "TicketPoll", "TimedRequest", "follow_steps", "run_steps", "wait_ticket"]

#: the default outer bound of a wait beyond the request's own timeout: only a stalled loop gets there
STALL = 30.0


class TimedRequest(Protocol):
    """A request with its own time limit (seconds), which its engine keeps."""

    @property
    def timeout(self) -> float: ...


R = TypeVar("R", bound=TimedRequest)
T = TypeVar("T")


def wait_ticket(
    loop: Scheduler,
    driver: Served,
    request: TimedRequest,
    what: str,
    *,
    wrap: Callable[[Any], object] | None = None,
    stall: float = STALL,
) -> Ticket[Any, Any]:
    """Submit ``request`` (``wrap(request)`` when given: e.g. a ``ToEngine``) and wait for its ticket, leading the
    loop while no other thread does; past ``timeout + stall`` a TimeoutError names ``what``."""
    # submit + wait, not Scheduler.run: a caller leading when another one makes the loop's own thread start
    # follows it from then on, where run would end its lead as a stall
    future = loop.submit(driver, request if wrap is None else wrap(request))
    try:
        ticket: Ticket[Any, Any] = loop.wait(future, request.timeout + stall, what)
    except BaseException:  # a stalled loop, an interrupt: the ticket is withdrawn at the loop's next turn
        if not future.cancel():
            loop.call(lambda now: driver.cancel([future], now))
        raise
    return ticket


def run_steps(
    loop: Scheduler,
    driver: Served,
    steps: Generator[R, Any, T],
    what: str | Callable[[R], str],
    *,
    wrap: Callable[[R], object] | None = None,
    stall: float = STALL,
) -> T:
    """Run ``steps`` to its end in the calling thread, each request's ticket waited for in turn
    (:func:`wait_ticket`); ``what``: the text of a stall's error, or a function of the request giving it."""

    def answer(request: R) -> Any:
        text = what if isinstance(what, str) else what(request)
        return wait_ticket(loop, driver, request, text, wrap=wrap, stall=stall).outcome()

    return follow_steps(steps, answer)


def follow_steps(steps: Generator[R, Any, T], answer: Callable[[R], Any]) -> T:
    """Run ``steps`` to its end: each request it yields gets ``answer(request)`` back, or the
    :class:`StarterbusError` that raised thrown in."""
    try:
        request = next(steps)
        while True:
            try:
                value = answer(request)
            except StarterbusError as exc:
                request = steps.throw(exc)
            else:
                request = steps.send(value)
    except StopIteration as stop:
        result: T = stop.value
        return result


class TicketPoll(PollTask, Generic[R]):
    """The poll ``steps`` on ``driver``, one ticket at a time. ``where`` begins its errors, ``what`` names a
    request in the stall's error ("ticket", "SDO transfer"); ``wrap`` makes what is submitted of a request."""

    def __init__(
        self,
        loop: Scheduler,
        driver: Served,
        steps: Generator[R, Any, PollResult],
        *,
        where: str,
        what: str = "ticket",
        wrap: Callable[[R], object] | None = None,
        stall: float = STALL,
    ) -> None:
        self.loop, self.driver, self.steps = loop, driver, steps
        self.where, self.what, self.wrap, self.stall = where, what, wrap, stall
        self._future: Future[Any] | None = None
        self._started = False
        self._result: PollResult | None = None
        self._error: StarterbusError | None = None
        self._pipe: tuple[int, int] | None = None  # made, closed and replaced by None in the advancing thread only
        self._pipe_lock = threading.Lock()  # the future's callback (the loop's thread) against closing the pipe
        self._watched: Future[Any] | None = None  # the future a callback was added to
        self._until = 0.0

    def advance(self, now: float) -> None:
        if self.done:
            return
        if self._pipe is not None:
            try:
                while os.read(self._pipe[0], 64):
                    pass
            except (BlockingIOError, OSError):
                pass
        if not self._started:
            self._started = True
            self._next(self.steps.__next__, now)
        while not self.done:
            future = self._future
            assert future is not None
            if not future.done():
                if now >= self._until:
                    self._stalled()
                    return
                if self.on_progress is not None:  # advanced from the loop: woken by the ticket's end
                    if self._watched is not future:
                        self._watched = future
                        future.add_done_callback(self._progress)
                    self.fd, self.wake_at = -1, self._until
                    if not future.done():
                        return
                elif self.loop.try_turn():
                    driver = self.driver
                    self.fd, self.wake_at = driver.fd, min(driver.deadline, self._until)
                    if not future.done():
                        return
                else:
                    self._wait_on(future)
                    return
            try:
                value = future.result().outcome()  # the ticket's result; a refused submission raises too
            except StarterbusError as exc:
                self._next(functools.partial(self.steps.throw, exc), now)
            else:
                self._next(functools.partial(self.steps.send, value), now)

    def _next(self, step: Callable[[], R], now: float) -> None:
        """Run the poll to its next request and submit it (or end the poll)."""
        try:
            request = step()
        except StopIteration as stop:
            self._end(result=stop.value)
            return
        except StarterbusError as exc:
            self._end(error=exc)
            return
        wrap = self.wrap
        self._future = self.loop.submit(self.driver, request if wrap is None else wrap(request))
        self._until = now + request.timeout + self.stall

    def _progress(self, _: Future[Any]) -> None:
        progress = self.on_progress
        if progress is not None and not self.done:
            progress()

    def _wait_on(self, future: Future[Any]) -> None:
        """Another thread leads: wake when the ticket's future ends (or at the outer bound: a stalled loop)."""
        pipe = self._pipe
        if pipe is None:
            pipe = self._pipe = os.pipe()
            os.set_blocking(pipe[0], False)
            os.set_blocking(pipe[1], False)
        self.fd, self.wake_at = pipe[0], self._until
        if self._watched is not future:
            self._watched = future
            future.add_done_callback(self._ring)

    def _ring(self, _: Future[Any]) -> None:
        with self._pipe_lock:
            pipe = self._pipe
            if pipe is not None:  # not closed (its number perhaps reused) since
                try:
                    os.write(pipe[1], b"!")
                except OSError:
                    pass

    def _stalled(self) -> None:
        self._withdraw()
        self.steps.close()
        self._end(error=TransportError(f"{self.where}: the poll's {self.what} did not end: the loop stalled"))

    def _withdraw(self) -> None:
        """Cancel the ticket under way (at the loop's next turn, without waiting)."""
        future = self._future
        if future is not None and not future.done():
            driver = self.driver
            future.cancel()
            self.loop.call(lambda now: driver.cancel([future], now))

    def _end(self, result: PollResult | None = None, error: StarterbusError | None = None) -> None:
        self._result, self._error = result, error
        self.done = True
        self.fd = -1
        if self._pipe is not None:
            with self._pipe_lock:
                pipe, self._pipe = self._pipe, None
            os.close(pipe[0])
            os.close(pipe[1])

    def result(self) -> PollResult:
        if self._error is not None:
            raise self._error
        if self._result is None:
            raise TransportError(f"{self.where}: the poll was cancelled")
        return self._result

    def cancel(self) -> None:
        if self.done:
            return
        self._withdraw()
        self.steps.close()
        self._end(error=TransportError(f"{self.where}: the poll was cancelled"))
