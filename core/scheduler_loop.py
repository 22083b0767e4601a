"""The scheduler's loop: its drivers, the inbox and its wake pipe, the leadership (who runs a turn) and one turn.

:class:`SchedulerLoop` holds what every thread touches to reach the loop and the loop body, once; the
:class:`~starterbus.core.scheduler.Scheduler` built on it adds the jobs with futures (``call``, ``submit``,
``run``, ``wait``) and the loop's own thread with its holders. Only the leader ever calls a driver or an engine.
A driver whose step raises fails its own tickets (a :class:`TransportError` for anything not a
:class:`StarterbusError`); the other drivers go on. The loop waits on every driver's descriptor with one
``select``, or, when one driver can wait by itself (:class:`Blocking`) and no other has a descriptor, in that
driver's own wait (a wake-up then interrupts it).
"""

from __future__ import annotations

import operator
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any, Protocol, cast

from starterbus.core.engine import Ticket
from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media.driver import step_error
from starterbus.core.media.waiter import Waiter

__all__ = ["SchedulerLoop", "Served"]

_deadline = operator.attrgetter("deadline")


class Served(Protocol):
    """What the scheduler needs of a driver (:class:`starterbus.core.media.driver.Driver` is one)."""

    name: str

    @property
    def fd(self) -> int:
        """The descriptor to wait on; -1: none (deadline only)."""
        ...

    @property
    def writing(self) -> bool:
        """Wait for ``fd`` to be writable (a connection being made) rather than readable."""
        ...

    @property
    def deadline(self) -> float:
        """When the driver must be stepped even if ``fd`` stays quiet."""
        ...

    def step(self, now: float, ready: bool) -> None:
        """The loop body; ``ready``: ``fd`` was reported ready."""
        ...

    def submit(
        self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]
    ) -> list[Ticket[Any, Any]]:
        """Queue the requests on the engine as one batch (the first to fail withdraws the others); each future
        (None: its waiter leads) gets its ticket once the ticket ends."""
        ...

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        """Cancel those of the tickets that have not ended."""
        ...

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        """Cancel the tickets of these futures that have not ended."""
        ...

    def crash(self, error: StarterbusError, now: float) -> None:
        """A step raised: fail every ticket with ``error`` and drop the medium (made again on demand)."""
        ...


class Blocking(Served, Protocol):
    """A driver that can wait for its own input (``can_block``: a medium without a descriptor whose library
    offers a blocking wait, python-can's virtual bus). The loop waits in its :meth:`block` instead of a
    ``select`` when no other driver has a descriptor: no reader thread, no pipe, one thread hand-off less."""

    @property
    def can_block(self) -> bool:
        """Whether :meth:`block` may be used now."""
        ...

    def block(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for input or an :meth:`interrupt`; True: input is ready (step with ``ready``)."""
        ...

    def interrupt(self) -> None:
        """End the :meth:`block` under way, or the next one (any thread)."""
        ...


def _blocker(drivers: Sequence[Served]) -> Blocking | None:
    """The one driver that can wait by itself when no other has a descriptor to watch (else None: ``select``)."""
    blocker: Blocking | None = None
    for driver in drivers:
        if getattr(driver, "can_block", False):
            if blocker is not None:
                return None
            blocker = cast(Blocking, driver)
        elif driver.fd >= 0:
            return None
    return blocker


class SchedulerLoop:
    """The state of a scheduler's loop and its body (the base of :class:`~starterbus.core.scheduler.Scheduler`)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._lock = threading.Lock()  # the inbox, the leadership
        self._changed = threading.Condition(self._lock)  # a future ended or the leadership was given back
        self._waiting = 0  # threads waiting on _changed: only then is it notified (notify_all is Python code)
        self._inbox: list[Callable[[float], None]] = []
        self._leader: int | None = None  # the thread running the loop
        #: the loop's own thread while it runs (None: callers lead); read-only outside the scheduler (a plain
        #: attribute: a blocking RTU call reads it on every transaction)
        self.thread: threading.Thread | None = None
        self.drivers: list[Served] = []
        self._may_block = False  # a driver in ``drivers`` offers ``can_block`` (else no turn looks for a blocker)
        self._due: list[Served] = []  # to step at the next turn (a submission)
        self._watched: dict[Served, tuple[int, bool]] = {}
        #: the driver whose own wait the loop uses now (:class:`Blocking`; None: the waiter's select)
        self._blocker: Blocking | None = None
        self._waiter: Waiter[Served | None] = Waiter()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._waiter.register(self._wake_r, None)

    # -- the leadership, from any thread -----------------------------------------------------------------------

    def _post(self, item: Callable[[float], None]) -> None:
        with self._lock:
            self._inbox.append(item)
            leader = self._leader
        if leader is not None and leader != threading.get_ident():
            self.wake()

    def wake(self) -> None:
        """Interrupt the loop's wait (something was queued for it)."""
        blocker = self._blocker
        if blocker is not None:  # the loop waits (or is about to) in that driver's own wait
            blocker.interrupt()
            return
        try:
            os.write(self._wake_w, b"!")
        except (BlockingIOError, OSError):  # already woken (the pipe is full), or closed at exit
            pass

    def lead(self) -> bool:
        """Take the leadership without a turn, when no thread leads, the loop has no thread of its own and its
        inbox is empty. True: the caller is the leader and may step its own driver until :meth:`release` (a
        sync call's fast path: no lock beyond this one, no future)."""
        with self._lock:
            if self._leader is not None or self.thread is not None or self._inbox:
                return False
            self._leader = threading.get_ident()
        return True

    def release(self) -> None:
        """Give back the leadership taken with :meth:`lead` (the waiters, if any, are told)."""
        with self._lock:
            self._leader = None
            self._wake_waiters()

    def _wake_waiters(self) -> None:
        """Tell the threads waiting on ``_changed`` (holding ``_lock``); none waiting: nothing to do."""
        if self._waiting:
            self._changed.notify_all()

    def _await_change(self, timeout: float | None = None) -> None:
        """Wait (holding ``_lock``) until a future ends or the leadership is given back, counted in ``_waiting``."""
        self._waiting += 1
        try:
            self._changed.wait(timeout)
        finally:
            self._waiting -= 1

    def in_loop(self) -> bool:
        """Whether the calling thread runs the loop now (its own thread, or a leader): a blocking wait from here
        would be refused."""
        return self._leader == threading.get_ident()

    def due(self, driver: Served) -> None:
        """Step ``driver`` at the loop's next turn, without waiting (any thread; from the loop's own thread no
        system call). A driver no longer served is left alone."""
        if self._leader == threading.get_ident():
            self._due.append(driver)
            return

        def mark(now: float) -> None:
            if driver in self.drivers:
                self._due.append(driver)

        self._post(mark)

    def try_turn(self) -> bool:
        """One turn of the loop without waiting, if no other thread runs it now: for a poller that waits on the
        drivers' descriptors itself (``fleet/mux.py``). False: another thread leads and serves the inbox."""
        me = threading.get_ident()
        with self._lock:
            if self._leader is not None or self.thread is not None:
                return False
            self._leader = me
        try:
            now = self.clock()
            self._turn(now, now, None)
        finally:
            with self._lock:
                self._leader = None
                self._wake_waiters()
        return True

    # -- in the loop --------------------------------------------------------------------------------------------

    def add(self, driver: Served) -> None:
        """Serve ``driver`` from now on (called in the loop: from :meth:`call`)."""
        if driver not in self.drivers:
            self.drivers = [*self.drivers, driver]
            self._may_block = self._may_block or hasattr(driver, "can_block")

    def remove(self, driver: Served) -> None:
        """Stop serving ``driver`` (called in the loop, before it closes its descriptor)."""
        self._watch(driver, -1, False)
        self.drivers = [d for d in self.drivers if d is not driver]
        self._may_block = any(hasattr(d, "can_block") for d in self.drivers)
        self._due = [d for d in self._due if d is not driver]

    def _lead(self, done: Callable[[], bool], give_up: float) -> None:
        while not done() and self.thread is None:
            now = self.clock()
            if now >= give_up:
                return
            self._turn(now, give_up, done)

    def _turn(self, now: float, until: float, done: Callable[[], bool] | None) -> None:
        """One pass: the inbox, the drivers due, one wait on every descriptor, the drivers ready, then those whose
        deadline has come, the longest overdue first (no wait once what the leader waits for is ``done``)."""
        if self._inbox:
            with self._lock:
                items, self._inbox = self._inbox, []
            for item in items:
                item(now)
        if self._due:
            due, self._due = self._due, []
            for driver in due:
                self._step(driver, now, False)
        drivers = self.drivers
        blocker = _blocker(drivers) if self._may_block else None
        self._blocker = blocker  # before the inbox is looked at below: a post from now on interrupts the blocker
        wait_until = until
        watched = self._watched
        for driver in drivers:
            if driver is not blocker:
                fd, writing = driver.fd, driver.writing
                was = watched.get(driver)
                if (was[0] != fd or was[1] != writing) if was is not None else fd >= 0:
                    self._watch(driver, fd, writing)
            deadline = driver.deadline
            if deadline < wait_until:  # noqa: PLR1730 (min() is a call: this runs for every driver at every turn)
                wait_until = deadline
        if done is not None and done():
            return
        if self._inbox or self._due:
            wait_until = now
        timeout = wait_until - self.clock()
        if timeout < 0.0:  # noqa: PLR1730 (max() is a call)
            timeout = 0.0
        if blocker is not None:
            ready: list[Served | None] = [blocker] if blocker.block(timeout) else []
        else:
            try:
                ready = self._waiter.wait(timeout)
            except OSError:  # a descriptor closed under the wait: its driver is crashed, the others go on
                ready = []
                self._drop_closed()
        now = self.clock()
        for which in ready:
            if which is None:
                self._drain()
            else:
                self._step(which, now, True)
        due = [driver for driver in self.drivers if driver.deadline <= now and driver not in ready]  # (ready: stepped)
        if len(due) > 1:  # the longest overdue first, whatever its place among the drivers
            due.sort(key=_deadline)
        for driver in due:
            if driver.deadline <= now:  # (still: a step before it in this turn may have moved its deadline)
                self._step(driver, now, False)

    def _step(self, driver: Served, now: float, ready: bool) -> None:
        try:
            driver.step(now, ready)
        except Exception as exc:
            driver.crash(step_error(driver.name, exc), self.clock())

    def _watch(self, driver: Served, fd: int, writing: bool) -> None:
        """Watch ``fd`` for ``driver`` (-1: nothing). A descriptor has one watcher: two drivers may take turns on
        one (a line's poll and its blocking callers' tickets, the line's lock between them), and one that takes it
        in a turn before the other lets go has it; the other, if it still wants it, takes it at its next turn."""
        old = self._watched.pop(driver, None)
        waiter = self._waiter
        if old is not None:
            waiter.unregister(old[0])
        if fd >= 0:
            other = waiter.watcher(fd)
            if other is not None:
                self._watched.pop(other, None)
            waiter.register(fd, driver, writing)
            self._watched[driver] = (fd, writing)

    def _drop_closed(self) -> None:
        for driver, (fd, _) in list(self._watched.items()):
            try:
                os.fstat(fd)
            except OSError as exc:
                self._watch(driver, -1, False)
                error = TransportError(f"{driver.name}: the descriptor was closed under the wait: {exc}")
                driver.crash(error, self.clock())

    def _drain(self) -> None:
        try:
            while os.read(self._wake_r, 512):
                pass
        except (BlockingIOError, OSError):
            pass
