"""A CANopen poll as a :class:`~starterbus.core.PollTask` for the fleet's poller: no thread per bus.

A poll is written once as a generator of SDO requests (:data:`Steps`): it yields an
:class:`~starterbus_canopen.sdo.Upload` or :class:`~starterbus_canopen.sdo.Download`, is sent the transfer's
bytes (or thrown its error) and returns its result. :func:`drive` runs it blocking (the sync API: each transfer a
ticket on the scheduler, waited for as leader or follower); :class:`SdoPoll` runs it without blocking: each
transfer is submitted to the node's engine on the bus's driver, then each :meth:`~SdoPoll.advance` runs one turn
of the scheduler without waiting (the poller waits on the driver's descriptor and deadline for it), as Modbus TCP's
``MbapPoll`` does. Advanced from inside the loop (the fleet on the scheduler), it is told when a transfer ends
through its ``on_progress``. While another thread runs the loop (the loop's own thread, kept running while a
CANopen device is open for its heartbeat and TPDO times), the task waits on a pipe of its own that the ticket's
future writes to when it ends, rather than looking again every millisecond.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Generator
from concurrent.futures import Future
from typing import Any, TypeVar

from starterbus.core import PollResult, PollTask, StarterbusError, Ticket, ToEngine, TransportError
from starterbus_canopen.bus import CanBus
from starterbus_canopen.sdo import SdoEngine, SdoRequest

__all__ = ["STALL", "SdoPoll", "Steps", "drive", "transfer"]

T = TypeVar("T")

#: SDO requests out, the transfers' bytes in, a result at the end
Steps = Generator[SdoRequest, bytes, T]

#: the outer bound of a wait beyond the transfer's own timeout: only a stalled loop gets there
STALL = 30.0


def transfer(bus: CanBus, engine: SdoEngine, request: SdoRequest) -> bytes:
    """One SDO transfer, waited for (leading the loop while no other thread does); its bytes, or its error."""
    loop, driver = bus.loop, bus.driver
    # submit + wait, not Scheduler.run: a caller leading when the loop's own thread starts follows it from then on
    future = loop.submit(driver, ToEngine(engine, request))
    try:
        ticket: Ticket[SdoRequest, bytes] = loop.wait(future, request.timeout + STALL, f"{bus.name}: SDO")
    except BaseException:  # a stalled loop, an interrupt: the ticket is withdrawn at the loop's next turn
        if not future.cancel():
            loop.call(lambda now: driver.cancel([future], now))
        raise
    return ticket.outcome()


def drive(bus: CanBus, engine: SdoEngine, steps: Steps[T]) -> T:
    """Run ``steps`` to its end, each transfer waited for in turn."""
    try:
        request = next(steps)
        while True:
            try:
                data = transfer(bus, engine, request)
            except StarterbusError as exc:
                request = steps.throw(exc)
            else:
                request = steps.send(data)
    except StopIteration as stop:
        result: T = stop.value
        return result


def _told(progress: Callable[[], None]) -> Callable[[Future[Any]], None]:
    return lambda _: progress()


class SdoPoll(PollTask):
    """The poll ``steps`` on ``engine``'s node of ``bus``, one transfer at a time. ``on_progress`` (set by a
    poller that advances the task from the scheduler's loop): called when a transfer ends, so the task is advanced
    again without a descriptor; without it the task turns the loop itself, or waits on a pipe of its own."""

    def __init__(self, bus: CanBus, engine: SdoEngine, steps: Steps[PollResult]) -> None:
        self.bus, self.engine, self.steps = bus, engine, steps
        self._future: Future[Any] | None = None
        self._started = False
        self._result: PollResult | None = None
        self._error: StarterbusError | None = None
        self._pipe: tuple[int, int] | None = None
        self._pipe_lock = threading.Lock()  # the future's callback (the loop's thread) against closing the pipe
        self._watched: Future[Any] | None = None
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
            self._next(lambda: next(self.steps), now)
        loop, driver = self.bus.loop, self.bus.driver
        while not self.done:
            future = self._future
            assert future is not None
            if not future.done():
                progress = self.on_progress
                if progress is not None:  # advanced from the loop: woken by the ticket's end
                    if now >= self._until:
                        self._stalled()
                        return
                    if self._watched is not future:
                        self._watched = future
                        future.add_done_callback(_told(progress))
                    self.fd, self.wake_at = -1, self._until
                    if not future.done():
                        return
                elif loop.try_turn():
                    self.fd, self.wake_at = driver.fd, driver.deadline
                    if not future.done():
                        return
                else:
                    self._wait_on(future, now)
                    return
            try:
                data = future.result().outcome()  # the transfer's bytes; a refused submission raises too
            except StarterbusError as exc:
                self._next(functools.partial(self.steps.throw, exc), now)
            else:
                self._next(functools.partial(self.steps.send, data), now)

    def _next(self, step: Callable[[], SdoRequest], now: float) -> None:
        """Run the poll to its next transfer and submit it (or end the poll)."""
        try:
            request = step()
        except StopIteration as stop:
            self._end(result=stop.value)
            return
        except StarterbusError as exc:
            self._end(error=exc)
            return
        bus = self.bus
        self._future = bus.loop.submit(bus.driver, ToEngine(self.engine, request))
        self._until = now + request.timeout + STALL

    def _wait_on(self, future: Future[Any], now: float) -> None:
        """Another thread leads: wake when the ticket's future ends (or at the outer bound: a stalled loop)."""
        if now >= self._until:
            self._stalled()
            return
        if self._pipe is None:
            self._pipe = os.pipe()
            os.set_blocking(self._pipe[0], False)
            os.set_blocking(self._pipe[1], False)
        pipe = self._pipe
        self.fd, self.wake_at = pipe[0], self._until
        if self._watched is future:
            return
        self._watched = future

        def ended(_: Future[Any]) -> None:
            with self._pipe_lock:
                if self._pipe is pipe:  # not closed (its number reused) since
                    try:
                        os.write(pipe[1], b"!")
                    except OSError:
                        pass

        future.add_done_callback(ended)

    def _stalled(self) -> None:
        self.cancel()
        self._error = TransportError(f"{self.bus.name}: the poll's SDO transfer did not end: the loop stalled")

    def _end(self, result: PollResult | None = None, error: StarterbusError | None = None) -> None:
        self._result, self._error = result, error
        self.done = True
        self.fd = -1
        with self._pipe_lock:
            pipe, self._pipe = self._pipe, None
            if pipe is not None:
                os.close(pipe[0])
                os.close(pipe[1])

    def result(self) -> PollResult:
        if self._error is not None:
            raise self._error
        if self._result is None:
            raise TransportError(f"{self.bus.name}: the poll was cancelled")
        return self._result

    def cancel(self) -> None:
        if self.done:
            return
        future = self._future
        if future is not None and not future.done():
            loop, driver = self.bus.loop, self.bus.driver
            future.cancel()
            loop.call(lambda now: driver.cancel([future], now))
        self.steps.close()
        self._end(error=TransportError(f"{self.bus.name}: the poll was cancelled"))
