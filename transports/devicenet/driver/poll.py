"""A DeviceNet poll as a :class:`~starterbus.core.PollTask` for the fleet's multiplexer: no thread per bus.

The poll is written as a generator of the master's tickets (:class:`Steps`): it yields a request, is sent the
ticket's result (or thrown its error) and returns the :class:`~starterbus.core.PollResult`. The task submits
each request to the master's engine on the bus's driver, then each :meth:`~DeviceNetPoll.advance` runs one turn
of the scheduler without waiting (the poller waits on the driver's descriptor and deadline for it). Run by the
fleet inside the loop (``on_progress`` set: docs/engine.md, step 4), the ticket's future calls ``on_progress``
when it ends and the task waits on nothing else. Run outside it while another thread leads (a master that
keeps the loop's own thread for its polled I/O connection), the task waits on a pipe of its own that the
ticket's future writes to when it ends, rather than looking again every millisecond.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Generator
from concurrent.futures import Future
from typing import Any

from starterbus.core import PollResult, PollTask, StarterbusError, ToEngine, TransportError
from starterbus.transports.devicenet.driver.scanner import STALL, Scanner
from starterbus.transports.devicenet.master.requests import MasterRequest

__all__ = ["DeviceNetPoll", "Steps"]

#: a poll: requests out, their results in, the poll's result at the end
Steps = Generator[MasterRequest, Any, PollResult]


class DeviceNetPoll(PollTask):
    """The poll ``steps`` on ``scanner``'s bus, one ticket at a time."""

    def __init__(self, scanner: Scanner, steps: Steps) -> None:
        self.scanner, self.steps = scanner, steps
        self._future: Future[Any] | None = None
        self._started = False
        self._result: PollResult | None = None
        self._error: StarterbusError | None = None
        self._pipe: tuple[int, int] | None = None
        self._notified: Future[Any] | None = None
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
        loop, driver = self.scanner.loop, self.scanner.driver
        while not self.done:
            future = self._future
            assert future is not None
            if not future.done():
                if self.on_progress is not None:  # the fleet's loop runs this task: the future's end wakes it
                    self._notify_on(future)
                    return
                if loop.try_turn():
                    self.fd, self.wake_at = driver.fd, driver.deadline
                    if not future.done():
                        return
                else:
                    self._wait_on(future, now)
                    return
            try:
                value = future.result().outcome()  # the ticket's result; a refused submission raises too
            except StarterbusError as exc:
                self._next(functools.partial(self.steps.throw, exc), now)
            else:
                self._next(functools.partial(self.steps.send, value), now)

    def _next(self, step: Any, now: float) -> None:
        """Run the poll to its next request and submit it (or end it)."""
        try:
            request: MasterRequest = step()
        except StopIteration as stop:
            self._end(result=stop.value)
            return
        except StarterbusError as exc:
            self._end(error=exc)
            return
        scanner = self.scanner
        self._future = scanner.loop.submit(scanner.driver, ToEngine(scanner.engine, request))
        self._until = now + request.timeout + STALL

    def _notify_on(self, future: Future[Any]) -> None:
        """In the loop's own thread (a fleet on the scheduler): the ticket's end calls ``on_progress`` (the task
        is advanced at the loop's next turn); meanwhile only the outer bound is watched."""
        if self._notified is not future:
            self._notified = future
            progress = self.on_progress

            def ended(_: Future[Any]) -> None:
                if progress is not None and not self.done:
                    progress()

            future.add_done_callback(ended)
        self.fd, self.wake_at = -1, self._until

    def _wait_on(self, future: Future[Any], now: float) -> None:
        """Another thread leads: wake when the ticket's future ends (or at the outer bound: a stalled loop)."""
        if now >= self._until:
            self._end(error=TransportError(f"{self.scanner.where}: the poll's ticket did not end: the loop stalled"))
            return
        if self._pipe is None:
            self._pipe = os.pipe()
            os.set_blocking(self._pipe[0], False)
            os.set_blocking(self._pipe[1], False)
        pipe = self._pipe
        read, write = pipe

        def ended(_: Future[Any]) -> None:
            if self._pipe is pipe:  # not closed (its number reused) since
                try:
                    os.write(write, b"!")
                except OSError:
                    pass

        future.add_done_callback(ended)
        self.fd, self.wake_at = read, self._until

    def _end(self, result: PollResult | None = None, error: StarterbusError | None = None) -> None:
        self._result, self._error = result, error
        self.done = True
        self.fd = -1
        pipe, self._pipe = self._pipe, None
        if pipe is not None:
            os.close(pipe[0])
            os.close(pipe[1])

    def result(self) -> PollResult:
        if self._error is not None:
            raise self._error
        if self._result is None:
            raise TransportError(f"{self.scanner.where}: the poll was cancelled")
        return self._result

    def cancel(self) -> None:
        if self.done:
            return
        future = self._future
        if future is not None and not future.done():
            scanner = self.scanner
            future.cancel()
            scanner.loop.call(lambda now: scanner.driver.cancel([future], now))
        self.steps.close()
        self._end(error=TransportError(f"{self.scanner.where}: the poll was cancelled"))
