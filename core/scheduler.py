"""One per-process scheduler: every driver's descriptor and deadline waited on at once, requests from any thread.

Other threads reach the loop only through its inbox (:meth:`Scheduler.call`, :meth:`Scheduler.submit`; a wake
pipe interrupts the wait). Whoever waits drives: a thread waiting on a future (:meth:`Scheduler.wait`) while no
thread runs the loop becomes its leader and runs it in its own thread until its future is done, then hands over
to the next waiter. A CLI ``read`` or a script thus starts no thread. A service starts the scheduler's own
thread (named ``starterbus-io``), and every other thread waits as a follower. Only the leader ever calls a driver
or an engine: that is the lock rule, once.

The loop's own thread has one set of owners: its :class:`Holder` s (:meth:`Scheduler.hold` / :meth:`Scheduler.unhold`;
fleets, devices that must be served while nobody waits). The first holder starts it, the last one to let go stops
it, and the loop itself failing (not a driver: those are contained) is told to every holder, whoever started it.

The loop's state and body (drivers, inbox, leadership, one turn: a driver whose step raises fails its own
tickets, the others go on) are its base's, :class:`~starterbus.core.scheduler_loop.SchedulerLoop`; this module
adds the jobs with futures, the waits and the loop's own thread. A wait has an outer bound only (timeouts belong to the
engines): past it, a :class:`TimeoutError` says the loop stalled. A blocking wait from inside the loop (a
callback calling the sync API) would wait on itself and is refused at once (:class:`SchedulerReentryError`).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any, TypeVar

from starterbus.core.engine import Ticket, TicketState
from starterbus.core.errors import StarterbusError, TimeoutError, TransportError
from starterbus.core.media.keeper import Holder
from starterbus.core.media.waiter import FD_SETSIZE, Waiter, precise_timers
from starterbus.core.scheduler_loop import SchedulerLoop, Served
from starterbus.core.supervision import describe

__all__ = [
    "FD_SETSIZE", "THREAD_NAME", "Holder", "Scheduler", "SchedulerReentryError", "Served", "Waiter",
    "precise_timers", "scheduler",
]  # fmt: skip

log = logging.getLogger(__name__)

T = TypeVar("T")

#: the longest wait of the scheduler's own thread when nothing is due (a submission wakes it at once anyway)
IDLE = 1.0
#: the name of the loop's own thread
THREAD_NAME = "starterbus-io"


class SchedulerReentryError(StarterbusError):
    """A blocking call made from inside the scheduler's loop (its thread, or a leader's callback): it would wait
    on the loop that has to finish it."""


class Scheduler(SchedulerLoop):
    """The loop of every driver of the process (:func:`scheduler` gives the process's one): jobs with futures
    from any thread, waits that lead the loop, and the loop's own thread with its holders."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(clock)
        self._stopping = False
        self._serving = threading.Event()  # the loop's own thread leads
        self._holders: tuple[Holder, ...] = ()  # replaced whole under _holding: read without a lock
        self._holding = threading.Lock()  # hold/unhold: the thread's start and stop decided and done in turn
        self._held_thread = False  # the thread running was started by a holder (the last one stops it)

    # -- from any thread ----------------------------------------------------------------------------------------

    def call(self, fn: Callable[[float], T]) -> Future[T]:
        """Run ``fn(now)`` in the loop; its result (or exception) in the future."""
        future: Future[T] = Future()

        def run(now: float) -> None:
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(now))
                except BaseException as exc:  # the caller's to see, in its own thread
                    future.set_exception(exc)

        self._post(run)
        return future

    def submit(self, driver: Served, request: object) -> Future[Any]:
        """Queue ``request`` on the driver's engine; the future gets the ended ticket."""
        return self.submit_all(driver, [request])[0]

    def submit_all(self, driver: Served, requests: Sequence[object]) -> list[Future[Any]]:
        """Queue the requests as one batch (the first to fail withdraws the others); a future per request."""
        futures: list[Future[Any]] = [Future() for _ in requests]

        def run(now: float) -> None:
            live = [f for f in futures if f.set_running_or_notify_cancel()]  # not withdrawn before the loop
            if len(live) < len(futures):
                for future in live:
                    future.set_exception(TransportError(f"{driver.name}: withdrawn before it was sent"))
                return
            try:
                driver.submit(requests, now, futures)
            except Exception as exc:  # a defect: the callers' to see
                for future in futures:
                    future.set_exception(exc)
            self._due.append(driver)

        self._post(run)
        return futures

    def run(self, driver: Served, requests: Sequence[object], bound: float, what: str) -> list[Ticket[Any, Any]]:
        """Submit the requests to the driver and wait until each ticket has ended, or one has ended other than
        DONE: those after it are then withdrawn (cancelled, or never sent). The tickets, in the order of the
        requests (up to the first that failed, when the caller followed another thread's lead). Led by the caller
        when it can (no inbox, no future: the sync API's usual case)."""
        if not requests:
            return []
        me = threading.get_ident()
        with self._lock:
            lead = self._leader is None and self.thread is None
            if lead:
                self._leader = me
        if not lead:
            return self._follow(driver, requests, bound, what)
        try:
            now = self.clock()
            tickets = driver.submit(requests, now, [None] * len(requests))
            if len(tickets) == 1:
                ticket = tickets[0]

                def over() -> bool:
                    return ticket.ended

            else:

                def over() -> bool:
                    return all(t.ended for t in tickets)

            if self._inbox or self._due:
                self._due.append(driver)
            else:  # nothing else queued: the first turn's whole work (a call to an in-process peer often ends here)
                self._step(driver, now, False)
                if over():
                    return tickets
            self._lead(over, now + bound)
            if not over():
                driver.withdraw(tickets, self.clock())
                raise self._stalled(what, bound)
        finally:
            with self._lock:
                self._leader = None
                self._wake_waiters()
        return tickets

    def _follow(self, driver: Served, requests: Sequence[object], bound: float, what: str) -> list[Ticket[Any, Any]]:
        futures = self.submit_all(driver, requests)
        tickets: list[Ticket[Any, Any]] = []
        for index, future in enumerate(futures):
            try:
                ticket: Ticket[Any, Any] = self.wait(future, bound, what)
            except BaseException:
                self._withdraw(driver, futures[index:])
                raise
            tickets.append(ticket)
            if ticket.state is not TicketState.DONE:
                break  # the loop has withdrawn the batch's others
        return tickets

    def _withdraw(self, driver: Served, futures: Sequence[Future[Any]]) -> None:
        """Cancel the tickets of these futures (without waiting: the loop does it at its next turn)."""

        if futures:
            for future in futures:  # not yet submitted: never will be
                future.cancel()
            self.call(lambda now: driver.cancel(futures, now))

    def wait(self, future: Future[T], bound: float, what: str) -> T:
        """The future's result, driving the loop while no other thread does. ``bound``: the outer limit (the
        engines keep the real timeouts); past it a TimeoutError names ``what`` and the stall."""
        me = threading.get_ident()
        if self._leader == me:
            raise SchedulerReentryError(
                f"{what}: a blocking call from inside the I/O loop would wait on itself (run it in another thread)"
            )
        give_up = self.clock() + bound
        watching = False
        while not future.done():
            remaining = give_up - self.clock()
            if remaining <= 0:
                raise self._stalled(what, bound)
            with self._lock:
                lead = self._leader is None and self.thread is None
                if lead:
                    self._leader = me
                elif watching and not future.done():  # not done: its callback notifies after this wait began
                    self._await_change(remaining)
            if not lead and not watching:
                watching = True
                future.add_done_callback(self._notify)  # outside the lock: a done future calls it at once
            if lead:
                try:
                    self._lead(future.done, give_up)
                finally:
                    with self._lock:
                        self._leader = None
                        self._wake_waiters()
        return future.result()

    def _stalled(self, what: str, bound: float) -> TimeoutError:
        names = ", ".join(d.name for d in self.drivers) or "none"
        return TimeoutError(f"{what}: not done within {bound:g} s: the I/O loop stalled (drivers: {names})")

    def _notify(self, _: Future[Any]) -> None:
        with self._lock:
            self._wake_waiters()

    def hold(self, holder: Holder) -> threading.Thread | None:
        """The loop's own thread runs at least until ``holder`` lets go (:meth:`unhold`); started now if it does
        not run. The thread it runs in (None: it failed already). Holding twice is holding once."""
        with self._holding:
            if holder not in self._holders:
                self._holders = (*self._holders, holder)
            if self.thread is None:
                if self.in_loop():  # the new thread would wait for this caller's lead to end
                    raise SchedulerReentryError(f"{holder.name}: the I/O loop's thread started from inside the loop")
                self._held_thread = self.start()
            return self.thread

    def unhold(self, holder: Holder) -> None:
        """``holder`` lets go; the last one stops the thread a holder started (and waits for its end, unless it is
        the calling thread). A holder not holding: nothing."""
        with self._holding:
            if holder not in self._holders:
                return
            self._holders = tuple(h for h in self._holders if h is not holder)
            if not self._holders and self._held_thread:
                self._held_thread = False
                self.stop()

    @property
    def holders(self) -> list[str]:
        """The names of the loop thread's holders now."""
        return [h.name for h in self._holders]

    def start(self, thread: threading.Thread | None = None) -> bool:
        """Run the loop in a thread of its own (``starterbus-io``) until :meth:`stop`; waiters are followers.
        ``thread``: a thread not yet started whose target calls :meth:`serve`. False: the loop's own thread runs
        already (``thread`` is not started). A thread started here is not held: its starter stops it
        (:meth:`hold` is how the owners of a shared loop share its thread)."""
        with self._lock:
            if self.thread is not None:
                return False
            self._stopping = False
            self.thread = thread or threading.Thread(target=self._serve_own, name=THREAD_NAME, daemon=True)
            self._serving.clear()
        self.thread.start()
        self.wake()  # a caller leading now hands over at its next turn
        self._serving.wait()
        return True

    def stop(self) -> None:
        """End the loop's own thread (the drivers stay; waiters lead again)."""
        thread = self.thread
        if thread is None:
            return
        self._stopping = True
        self.wake()
        if thread is not threading.current_thread():
            thread.join()

    @property
    def running(self) -> bool:
        """The loop's own thread runs."""
        return self.thread is not None and self.thread.is_alive()

    def serve(self) -> None:
        """The loop, in the calling thread, until :meth:`stop` (the target of the thread :meth:`start` runs); an
        exception out of the loop itself (not a driver's: those are contained) ends it, is told to every holder
        (logged when none has an ``on_failure``) and is raised."""
        precise_timers()
        with self._lock:
            while self._leader is not None:  # a caller leading now hands over at its next check
                self._await_change()
            self._leader = threading.get_ident()
        self._serving.set()
        failure: Exception | None = None
        try:
            clock = self.clock
            while not self._stopping:
                now = clock()
                self._turn(now, now + IDLE, None)
        except Exception as exc:
            failure = exc
            raise
        finally:
            holders = self._holders  # those who held it while it ran (before another holder may start one anew)
            with self._lock:
                self._leader = None
                self._held_thread = False  # (before the thread is gone: a holder starting one anew sets it)
                self.thread = None
                self._stopping = False
                self._wake_waiters()
            if failure is not None:
                self._tell(holders, failure)

    def _tell(self, holders: Sequence[Holder], failure: Exception) -> None:
        told = [h for h in holders if h.on_failure is not None]
        for holder in told:
            assert holder.on_failure is not None
            try:
                holder.on_failure(failure)
            except Exception as exc:  # one holder failing to take it must not keep it from the others
                log.error("%s: told that the I/O loop failed: %s", holder.name, describe(exc))
        if not told:
            names = ", ".join(h.name for h in holders) or "none"
            log.error("%s failed: %s (holders: %s)", THREAD_NAME, describe(failure), names)

    def _serve_own(self) -> None:
        """The target of the loop's own thread when :meth:`start` made it: a failure was told or logged there."""
        try:
            self.serve()
        except Exception:
            log.debug("%s: the traceback", THREAD_NAME, exc_info=True)


_default: list[Scheduler] = []  # the process's one, once made
_default_lock = threading.Lock()


def scheduler() -> Scheduler:
    """The process's scheduler (made at first use)."""
    if not _default:
        with _default_lock:
            if not _default:
                _default.append(Scheduler())
    return _default[0]


os.register_at_fork(after_in_child=_default.clear)  # a child has no loop thread and must not share the pipe
