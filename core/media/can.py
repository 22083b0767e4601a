"""A CAN bus as a medium: one python-can bus per (interface, channel), shared by every engine on it.

:class:`CanDriver` is the scheduler's driver of one bus. Engines (:class:`CanEngine`: an :class:`Engine` of
:class:`CanFrame` with the identifiers it ``wanted``) are added to it, a DeviceNet master and CANopen clients
side by side. Each received classic frame goes to the engines whose ``wanted`` hold its identifier (one dict
lookup, after the bus's own filters: the union of the engines' ``filters``); the others are counted as
``dropped``. What the engines give to send is written at once; their deadlines are the driver's.

A bus with a descriptor (SocketCAN) is selected directly and read until empty when it is ready. A bus without
one (python-can's ``virtual``, ``remote``, some vendor interfaces) gets ONE reader thread (``can-reader
IFACE/CH``): it puts the frames in a queue and writes one wake byte to a pipe when the queue was empty (a burst
costs one wake-up); the driver's descriptor is that pipe.

Requests reach an engine through the scheduler as :class:`ToEngine` (``Scheduler.run(driver, [ToEngine(engine,
request)], ...)``); the ticket is the engine's own. While the loop waits in a virtual bus's own queue, a caller may
give its request to the engine in its own thread instead (:meth:`CanDriver.submit_here`: no thread hand-off before
the frame goes out). An engine that raises is not dropped (a malformed frame or a
bug must not silence a bus that others share): the error is kept in :attr:`CanDriver.errors` and its
``advance`` is held back :data:`BUG_BACKOFF`.

Periodic outputs (:meth:`CanDriver.periodic`): python-can's ``send_periodic`` where the interface sends them
itself (SocketCAN's broadcast manager, hardware), else the driver's own deadlines, never a thread.

An engine that must be served while no caller waits keeps the loop's own thread running
(:func:`starterbus.core.media.keeper.keep_running`).

Everything but :meth:`CanDriver.acquire` / :meth:`CanDriver.release` runs in the scheduler's loop (through
``Scheduler.call`` or ``run``): only the leader touches the driver, the bus's writes and its engines.

This module is the bus; the engines' half (routing, loop-back, tickets) is ``can_engines.py``, what is written
(the engines' frames, one-off frames, the periodic ones at their deadlines) ``can_writes.py``, the periodic
frames ``can_periodic.py``, reading a bus without a descriptor ``can_reader.py``.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

import can

from starterbus.core.canbus import open_bus, shutdown
from starterbus.core.canframe import CanFrame
from starterbus.core.engine import Ticket
from starterbus.core.errors import ConfigurationError, TransportError
from starterbus.core.media.can_engines import CanEngine, Handoff, Loop, ToEngine
from starterbus.core.media.can_periodic import Periodic
from starterbus.core.media.can_reader import CanReader, QueueWait
from starterbus.core.media.can_writes import MESSAGE_CACHE, BusWrites
from starterbus.core.sharing import SharedPool

__all__ = [
    "BUG_BACKOFF",
    "CAN_BUSES",
    "MESSAGE_CACHE",
    "CanDriver",
    "CanEngine",
    "Handoff",
    "Loop",
    "Periodic",
    "ToEngine",
]

BUG_BACKOFF = 0.01  # s an engine's advance is held back after it raised (no tight loop on a failing timer)
#: the longest wait of a call into the loop (adding an engine, closing): only a stalled loop gets there
STALL = 30.0

T = TypeVar("T")


class CanDriver(BusWrites):
    """The engines on one python-can bus, run by the scheduler (a :class:`~starterbus.core.scheduler.Served`)."""

    def __init__(self, bus: can.BusABC, name: str, loop: Loop, *, owns_bus: bool = True) -> None:
        self.bus = bus
        self.name = name
        self.loop = loop
        self._owns_bus = owns_bus
        self.engines: list[CanEngine] = []
        self._filters: dict[CanEngine, list[can.typechecking.CanFilter] | None] = {}
        self._seen: list[frozenset[int]] = []  # each engine's `wanted` as last routed
        self._routes: dict[int, tuple[CanEngine, ...]] = {}
        self._held: dict[CanEngine, float] = {}  # engine -> no advance before (it raised)
        self._futures: dict[Ticket[Any, Any], Future[Any] | Handoff | None] = {}
        self._owner: dict[Ticket[Any, Any], CanEngine] = {}
        self._batches: dict[Ticket[Any, Any], list[Ticket[Any, Any]]] = {}
        self._periodics: list[Periodic] = []
        self._messages: dict[CanFrame, can.Message] = {}
        self.errors: collections.deque[str] = collections.deque(maxlen=100)
        self._received = 0
        self._dropped = 0
        self.sent = 0
        self.crashes = 0
        self.closed = False
        self.key: tuple[str, str] = ("", "")
        #: the bit rate asked when the bus was opened (None: none named, the interface's own)
        self.bitrate: int | None = None
        self._step_cpu = 0.0
        try:
            self._fd = bus.fileno()
        except (NotImplementedError, AttributeError, OSError, can.CanError):
            self._fd = -1
        #: a virtual bus: the loop may wait on its queue (no reader thread until a descriptor is needed). The
        #: messages the driver keeps for it hold the frame's bytes, not the bytearray python-can makes of them:
        #: its send deep-copies each message for every receiver (the copy's data a bytearray again), and a
        #: deepcopy of bytes is free where a bytearray's goes through copyreg (2.3 us of a 3.9 us send and take).
        #: Not on other interfaces: some write into the data (gs_usb pads it, ixxat takes a writable buffer).
        self._queue = QueueWait.of(bus) if self._fd < 0 else None
        self._reader = CanReader(bus, name, self.errors) if self._fd < 0 and self._queue is None else None

    # -- sharing one bus per (interface, channel) in a process --------------------------------------------------

    @classmethod
    def acquire(
        cls,
        interface: str,
        channel: str,
        loop: Loop,
        bitrate: int | None = None,
        *,
        needs_peer: str | None = None,
    ) -> CanDriver:
        """The driver of this bus in this process (opened and added to the scheduler at first use); give it
        back with :meth:`release`."""
        key = (interface, channel)

        def make() -> CanDriver:
            bus = open_bus(interface, channel, bitrate, needs_peer=needs_peer)
            try:
                driver = cls(bus, f"{interface}/{channel}", loop)
                driver.key, driver.bitrate = key, bitrate
                driver.call(lambda now: driver.loop.add(driver), "add the bus")
            except BaseException:
                shutdown(bus)
                raise
            return driver

        driver = CAN_BUSES.acquire(key, make)
        if bitrate is not None and driver.bitrate is None:
            driver.bitrate = bitrate  # (opened without one: the first to name a rate sets what the others must ask)
        elif bitrate is not None and driver.bitrate != bitrate:
            opened = driver.bitrate
            driver.release()
            raise ConfigurationError(
                f"CAN bus {interface}/{channel} is already open in this process at {opened} bit/s; opening it at "
                f"{bitrate} bit/s refused: one bus has one bit rate (give every protocol on it the same bitrate=)"
            )
        return driver

    def release(self) -> None:
        """One user fewer; the last one closes the driver (its reader, and the bus it opened)."""
        CAN_BUSES.release(self.key)

    def call(self, fn: Callable[[float], T], what: str) -> T:
        """Run ``fn(now)`` in the loop and wait for it (leading the loop while no other thread does)."""
        return self.loop.wait(self.loop.call(fn), STALL, f"{self.name}: {what}")

    def close(self) -> None:
        """Stop serving the bus: every ticket fails, the reader stops, a bus the driver opened is shut down."""
        if self.closed:
            return

        def close(now: float) -> None:
            self.loop.remove(self)
            self._fail_all(TransportError(f"CAN bus {self.name} is closed"), now)
            for periodic in list(self._periodics):
                periodic.stop()

        try:
            self.call(close, "close")
        finally:
            self.closed = True
            if self._reader is not None:
                self._reader.close()
            if self._owns_bus:
                shutdown(self.bus)

    def submit_here(self, engine: CanEngine, request: object) -> Handoff | None:
        """Submit ``request`` to ``engine`` in the calling thread if the loop waits in this bus's own queue now
        (:meth:`block`): the frame goes out at once, the loop left waiting (woken only if the request's deadline
        comes before its wait ends), no thread hand-off; the loop ends the :class:`Handoff` with the ticket. None:
        the loop does not wait there (another thread runs a turn, or waits in a ``select``, or the caller itself
        leads): submit through the loop (``loop.submit(driver, ToEngine(engine, request))``). A ticket given here
        is withdrawn with :meth:`withdraw` in the loop."""
        direct = self._queue
        if direct is None or not direct.gate.acquire(blocking=False):
            return None
        try:  # the loop waits in block() until the gate is given back: the driver is this thread's meanwhile
            if self.closed or engine not in self.engines:
                return None
            was = engine.deadline  # the loop's wait ends at it or earlier (when it is the driver's first)
            now = self.loop.clock()
            ticket = engine.submit(request, now)
            handoff = self._futures[ticket] = Handoff(ticket)
            self._owner[ticket] = engine
            self._flush(engine, now)
            due = engine.deadline
            if due < direct.until and due != was:  # sooner than the loop will look: wake it
                direct.interrupt()
            return handoff
        finally:
            direct.gate.release()

    # -- engines (in the loop) ------------------------------------------------------------------------------------

    def add(self, engine: CanEngine, filters: list[can.typechecking.CanFilter] | None = None) -> None:
        """Route frames to ``engine`` from now on; ``filters``: python-can filters covering its ``wanted`` (None:
        it may want any identifier: the bus then filters nothing)."""
        if engine in self.engines:
            return
        self.engines = [*self.engines, engine]
        self._filters[engine] = filters
        self._route()
        self._set_filters()

    def remove(self, engine: CanEngine, now: float) -> None:
        """Stop routing to ``engine``; its tickets still open fail."""
        if engine not in self.engines:
            return
        self.engines = [e for e in self.engines if e is not engine]
        self._filters.pop(engine, None)
        self._held.pop(engine, None)
        self._route()
        error = TransportError(f"{self.name}: the engine was removed from the bus")
        for ticket, owner in list(self._owner.items()):
            if owner is engine:
                if not ticket.ended:
                    ticket.failed(error, now)
                self._end(ticket)
        self._set_filters()

    def _set_filters(self) -> None:
        lists = [self._filters.get(engine) for engine in self.engines]
        merged: list[can.typechecking.CanFilter] | None = None
        if lists and all(f is not None for f in lists):
            merged = [item for f in lists for item in (f or [])]
        try:
            self.bus.set_filters(merged)
        except (can.CanError, NotImplementedError, AttributeError):  # pragma: no cover - software routing only
            pass

    # -- what the scheduler reads ---------------------------------------------------------------------------------

    @property
    def fd(self) -> int:
        """The bus's descriptor, else its reader's pipe (a virtual bus's reader started at the first need: the loop
        waits on other descriptors too, or a poller outside the loop waits)."""
        if self._fd >= 0:
            return self._fd
        reader = self._reader
        if reader is None:
            reader = self._reader = CanReader(self.bus, self.name, self.errors)
            reader.wanted = frozenset(self._routes)
        return reader.fd

    @property
    def can_block(self) -> bool:
        """The loop may wait in :meth:`block` (a virtual bus read by no thread) when no other driver has a
        descriptor."""
        return self._reader is None and self._queue is not None

    def block(self, timeout: float) -> bool:
        """The loop's wait when it has no descriptor to watch but this bus's: up to ``timeout`` s for frames or an
        :meth:`interrupt`; True: frames were read (step with ``ready``). Meanwhile :meth:`submit_here` may submit
        in the caller's own thread."""
        assert self._queue is not None
        return self._queue.block(timeout, self.loop.clock() + timeout)

    def interrupt(self) -> None:
        """End the loop's :meth:`block` now, or the next one (any thread)."""
        if self._queue is not None:
            self._queue.interrupt()

    @property
    def writing(self) -> bool:
        return False

    @property
    def deadline(self) -> float:
        at = float("inf")
        held = self._held
        for engine in self.engines:
            due = engine.deadline
            if held and engine in held:
                due = max(due, held[engine])
            at = min(at, due)
        for periodic in self._periodics:
            at = min(at, periodic.next_at)
        return at

    @property
    def received(self) -> int:
        """Frames read from the bus (past its filters)."""
        reader = self._reader
        return self._received + (reader.received if reader is not None else 0)

    @property
    def dropped(self) -> int:
        """Of them, frames no engine wanted (or not classic 11-bit data frames)."""
        reader = self._reader
        return self._dropped + (reader.dropped if reader is not None else 0)

    @property
    def pending(self) -> int:
        return len(self._futures)

    @property
    def io_cpu(self) -> float:
        """CPU seconds spent in this driver's steps (in whichever thread led) and in its reader thread."""
        return self._step_cpu + self.reader_cpu

    @property
    def reader_cpu(self) -> float:
        """CPU seconds of the reader thread (0 for a bus with a descriptor)."""
        return self._reader.cpu if self._reader is not None else 0.0

    # -- the loop body --------------------------------------------------------------------------------------------

    def step(self, now: float, ready: bool) -> None:
        cpu = time.thread_time()
        try:
            reader, direct = self._reader, self._queue
            flushed: set[CanEngine] | tuple[()] = ()
            if ready or (direct is not None and direct.pending) or (reader is not None and reader.queued):
                flushed = self._take_input(now)  # frames read before any timer runs
            held = self._held
            for engine in self.engines:
                if now >= engine.deadline and not (held and now < held.get(engine, 0.0)):
                    try:
                        engine.advance(now)
                    except Exception as exc:
                        self._failed(engine, exc, now, "advance")
                        held[engine] = now + BUG_BACKOFF
                elif engine in flushed:
                    continue  # its output was taken after its frames at this same time: nothing new since
                self._flush(engine, now)
            if self._periodics:
                self._send_periodics(now)
        finally:
            self._step_cpu += time.thread_time() - cpu

    def _take_input(self, now: float) -> set[CanEngine]:
        """Read what is ready and deliver it; the engines that got frames (their output already written)."""
        reader, direct = self._reader, self._queue
        if direct is not None:
            messages = direct.take()
            self._received += len(messages)
            if reader is not None:
                messages += reader.take()
        elif reader is None:
            messages = []
            while True:
                try:
                    message = self.bus.recv(0.0)
                except can.CanError as exc:
                    self.errors.append(f"receive failed: {exc}")
                    break
                if message is None:
                    break
                messages.append(message)
            self._received += len(messages)
        else:
            messages = reader.take()
        return self._deliver(messages, now) if messages else set()


#: one driver per (interface, channel) in this process
CAN_BUSES: SharedPool[CanDriver] = SharedPool("CAN buses")
