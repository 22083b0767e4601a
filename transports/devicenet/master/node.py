"""The DeviceNet master as a sans-IO state machine: frames and times in, frames out.

:class:`MasterNode` goes on line with the duplicate MAC ID check, runs the connection sequence of every
attached slave (:mod:`~starterbus.transports.devicenet.master.connection`), polls each established slave at its
own interval (up to ``WINDOW`` poll commands in flight) and keeps the latest input assembly of each. Nothing
here reads a clock, locks or touches a bus: the driver calls :meth:`start`, :meth:`handle` for every frame
that :meth:`wants`, :meth:`tick` when :attr:`deadline` is due, passing the time, and sends :meth:`take`.

Rules (documented in ``docs/devicenet.md``; going on line, the communication fault and a lost slave are
:mod:`~starterbus.transports.devicenet.master.online`'s):

- On line, a duplicate MAC ID *request* for the master's MAC is answered with a response; a *response* (or,
  during the check, a request or a response) puts the master in the communication faulted state: nothing is
  sent, every link shows the fault. With ``auto_reset`` the master leaves the fault after a backoff (1 s,
  doubling up to 60 s; back to 1 s after 10 minutes on line) by re-running the whole check.
- An answer to a poll is published only when no second answer to the same poll came within ``ANSWER_GUARD``
  (and never after the next poll command went out). Two answers to one poll mark the link with a
  :class:`DuplicateResponderError`, withdraw its inputs, and keep it marked until ``CLEAR_POLLS`` polls in a row
  got exactly one answer.
- A slave silent for 4 x EPR is lost (its run command is dropped: a start must be sent again) and the
  sequence starts over until it answers. The explicit connection is kept alive by reading the identity status.
"""

from __future__ import annotations

import math
from collections import deque

from starterbus.core import CanFrame, ConfigurationError, TimeoutError, TransportError
from starterbus.transports.devicenet.codec.cip import ObjectClass, Service
from starterbus.transports.devicenet.codec.connection import AllocationChoice, inactivity_timeout
from starterbus.transports.devicenet.codec.ids import duplicate_mac_id, explicit_response_id
from starterbus.transports.devicenet.codec.ids import poll_response_id as _poll_response_id
from starterbus.transports.devicenet.master.link import (
    CommunicationFaultError,
    IoPhase,
    LinkConfig,
    LinkState,
    MasterLink,
    ScannerConfig,
    ScannerState,
    Transaction,
)
from starterbus.transports.devicenet.master.online import MASTER_VENDOR_ID, RESET_BACKOFF, STABLE_ONLINE, OnLine

__all__ = [
    "CONFIRM_SLACK",
    "IDLE_TICK",
    "KEEPALIVE_GRID",
    "MASTER_VENDOR_ID",
    "MONITOR_LOST_AFTER",
    "RESET_BACKOFF",
    "STABLE_ONLINE",
    "MasterNode",
]

CONFIRM_SLACK = 0.0005  # answers confirmed together when their guards end within this (fewer wake-ups)
IDLE_TICK = 1.0  # longest time between two passes over the links (every timer is also woken exactly)
MONITOR_LOST_AFTER = 10.0  # s without explicit answer after which a monitored slave (explicit EPR 0) is lost
#: keep-alive reads fall due on a grid of this share of their period (from 4/5 of the period after the last
#: explicit message, never later than the period), so that slaves whose keep-alives fall due close together
#: (attached one after the other) share one pass over the links instead of each costing a pass over every link
KEEPALIVE_GRID = 0.2


class MasterNode(OnLine):
    """One DeviceNet master (scanner) on one CAN bus, as a state machine."""

    def __init__(self, config: ScannerConfig, serial: int, where: str = "") -> None:
        self.config = config
        self.serial = serial
        self.where = where or f"{config.interface}/{config.channel}"
        self.state = ScannerState.CLOSED
        self.fault: CommunicationFaultError | None = None
        self.faults = 0  # communication faults since the master was last stable on line
        self.reset_at = 0.0
        self.online_since = 0.0
        self.links: dict[int, MasterLink] = {}
        self.deadline = float("inf")
        self.cycles = 0
        self.polls_sent = 0
        self.ignored = 0  # frames handled but not for this master
        self._out: list[CanFrame] = []
        self._check_step = 0
        self._check_deadline = 0.0
        self._scan: list[MasterLink] = []
        self._ready: deque[MasterLink] = deque()
        self._in_flight = 0
        self._confirming: deque[MasterLink] = deque()
        self._deadlines: deque[tuple[float, MasterLink]] = deque()  # poll commands' answer deadlines, in order
        self._due: list[tuple[float, int, MasterLink]] = []  # heap of next poll times
        self._sequence = 0
        self._slow_at = float("inf")
        self._routes: dict[int, MasterLink] = {}  # poll and explicit response ids
        self.wanted: frozenset[int] = frozenset()  # identifiers worth handing to :meth:`handle`
        self._update_routes()

    # -- driver interface -----------------------------------------------------------------------------------

    def take(self) -> list[CanFrame]:
        """The frames to send, in order (and forget them)."""
        out, self._out = self._out, []
        return out

    def start(self, now: float) -> list[CanFrame]:
        """Begin (or restart, after a fault) the duplicate MAC ID check."""
        self._begin_check(now)
        return self.take()

    def close(self) -> None:
        self.state = ScannerState.CLOSED
        for link in list(self.links.values()):
            self.detach(link)

    def _update_routes(self) -> None:
        routes: dict[int, MasterLink] = {}
        for link in self.links.values():
            routes[_poll_response_id(link.mac)] = link
            routes[explicit_response_id(link.mac)] = link
        self._routes = routes
        dup_ids = {duplicate_mac_id(mac) for mac in (self.config.master_mac, *self.links)}
        self.wanted = frozenset(routes) | dup_ids
        self._scan = sorted(self.links.values(), key=lambda item: item.mac)

    # -- links ----------------------------------------------------------------------------------------------

    def attach(self, config: LinkConfig, now: float) -> MasterLink:
        if config.mac in self.links:
            raise ConfigurationError(f"DeviceNet MAC {config.mac} on {self.where} is already open in this process")
        if config.mac == self.config.master_mac:
            raise ConfigurationError(f"slave MAC {config.mac} equals the master's MAC on {self.where}")
        interval = self.config.poll_period if config.interval is None else config.interval
        link = MasterLink(config, self.where, interval)
        self.links[config.mac] = link
        self._update_routes()
        if self.state is ScannerState.ONLINE:
            link.state = LinkState.ALLOCATING
            link.retry_at = now
            self._wake(now)
        elif self.state is ScannerState.FAULT and self.fault is not None:
            link.state = LinkState.FAULTED
            link.io = IoPhase.NONE
            link.last_error = self.fault
        return link

    def release(self, link: MasterLink, now: float) -> Transaction | None:
        """Queue the Release of an established slave's connection set (before :meth:`detach`)."""
        if not link.established or self.state is not ScannerState.ONLINE:
            return None
        choice = int(AllocationChoice.EXPLICIT) | (int(AllocationChoice.POLLED) if link.io is not IoPhase.NONE else 0)
        transaction = Transaction(self._release_request(choice), False)
        self.enqueue(link, transaction, now)
        return transaction

    def detach(self, link: MasterLink) -> None:
        link.state = LinkState.CLOSED
        if self.links.get(link.mac) is link:
            del self.links[link.mac]
        if link.awaiting:
            link.awaiting = False
            self._in_flight -= 1
        self._update_routes()
        self._fail_transactions(link, ConfigurationError(f"{link.describe()} closed"), started_too=True)

    def submit(self, link: MasterLink, transaction: Transaction, now: float) -> None:
        """Queue a user's explicit request; ``transaction.done`` turns True with its outcome."""
        if self.state is not ScannerState.ONLINE:
            transaction.error = self.not_online()
            transaction.done = True
            return
        if not transaction.unconnected and not link.established:
            transaction.error = TimeoutError(f"{link.describe()}: no explicit connection ({link.state.value})")
            transaction.done = True
            return
        self.enqueue(link, transaction, now)

    def set_outputs(
        self,
        link: MasterLink,
        now: float,
        *,
        run: bool | None = None,
        reset: bool | None = None,
        select: int | None = None,
        polls: int = 1,
    ) -> int:
        """Change a slave's outputs and poll it ``polls`` times at once; returns the sequence number to wait for."""
        if run is not None:
            link.run = run
        if reset is not None:
            link.reset = reset
        if select is not None:
            link.select = select
        link.output_seq += 1
        self.expedite(link, now, polls)
        return link.output_seq

    def expedite(self, link: MasterLink, now: float, polls: int = 1) -> None:
        """Poll ``link`` as soon as possible, ``polls`` times in a row (a reader waits for fresh inputs)."""
        link.urgent = max(link.urgent, polls)
        link.next_poll_at = min(link.next_poll_at, now)
        self._make_ready(link)
        self._wake_fast(now)

    def not_online(self) -> Exception:
        if self.fault is not None:
            again = " (checking the MAC id again)" if self.state is ScannerState.CHECKING else ""
            return CommunicationFaultError(f"DeviceNet master on {self.where} is off line{again}: {self.fault}")
        if self.state is ScannerState.CLOSED:
            return TransportError(f"DeviceNet master on {self.where} is closed")
        return TimeoutError(f"DeviceNet master on {self.where} is not on line yet ({self.state.value})")

    def link_error(self, link: MasterLink) -> Exception | None:
        """Why ``link`` cannot deliver a value right now (None if it can)."""
        if self.state is not ScannerState.ONLINE:
            return self.not_online()
        if link.duplicate is not None:
            return link.duplicate
        return None

    # -- frames ---------------------------------------------------------------------------------------------

    def handle(self, frame: CanFrame, now: float) -> list[CanFrame]:
        """A frame seen on the bus; returns the frames to send."""
        return self.receive(frame.can_id, frame.data, now)

    def receive(self, can_id: int, data: bytes, now: float) -> list[CanFrame]:
        """:meth:`handle` for a driver that has the identifier and data of a classic 11-bit data frame."""
        link = self._routes.get(can_id)
        if link is not None:
            if can_id & 0x400:
                if self.state is ScannerState.ONLINE:
                    self._on_explicit_response(link, data, now)
            elif link.polling and self.state is ScannerState.ONLINE:
                self._on_poll_response(link, data, now)
        elif can_id in self.wanted:
            self._on_duplicate_mac(CanFrame(can_id, data), now)
        else:
            self.ignored += 1
        out, self._out = self._out, []
        return out

    # -- timers ---------------------------------------------------------------------------------------------

    def tick(self, now: float) -> list[CanFrame]:
        """Run what is due at ``now``; returns the frames to send. :attr:`deadline` is the next due time."""
        if self.state is ScannerState.ONLINE:
            self._fast(now)
        if now >= self._slow_at:
            self._slow(now)
        self.deadline = self._slow_at
        if self.state is ScannerState.ONLINE:
            self._send_ready(now)
            if self._confirming:
                self._wake_fast(self._confirming[0].confirm_at + CONFIRM_SLACK)
            deadlines = self._deadlines
            while deadlines and not deadlines[0][1].awaiting:  # answered: no timer needed
                deadlines.popleft()
            if deadlines:
                self._wake_fast(deadlines[0][0])
            if self._due:
                self._wake_fast(self._due[0][0])
        return self.take()

    def _slow(self, now: float) -> None:
        self._slow_at = now + IDLE_TICK
        if self.state is ScannerState.CHECKING:
            if now >= self._check_deadline:
                if self._check_step == 1:
                    self._out.append(self._dup_mac_frame(False))
                    self._check_step = 2
                    self._check_deadline = now + self.config.dup_mac_wait
                else:
                    self._go_online(now)
            if self.state is ScannerState.CHECKING:
                self._wake(self._check_deadline)
        elif self.state is ScannerState.FAULT and self.config.auto_reset:
            if now >= self.reset_at:
                self._begin_check(now)
            else:
                self._wake(self.reset_at)
        if self.state is ScannerState.ONLINE:
            for link in self._scan:
                self._link_timers(link, now)

    def _link_timers(self, link: MasterLink, now: float) -> None:
        self._transaction_timer(link, now)
        head = link.transactions[0] if link.transactions else None
        if head is not None:
            self._wake(head.deadline)
        if link.state is LinkState.ESTABLISHED and not link.polling:
            lost_after = inactivity_timeout(link.explicit_epr_ms) or MONITOR_LOST_AFTER
            if now - link.last_explicit_answer_at > lost_after:
                self._lose(link, now, f"no explicit response for {now - link.last_explicit_answer_at:.3f} s")
                return
            due = _keepalive_due(link)
            if head is None and now >= due:
                keepalive = self._request(Service.GET_ATTRIBUTE_SINGLE, ObjectClass.IDENTITY, 1, 5)
                self.enqueue(link, Transaction(keepalive, False), now)
            self._wake(due)
            self._wake(link.last_explicit_answer_at + lost_after)
        elif link.state is LinkState.ESTABLISHED:
            lost_after = inactivity_timeout(link.epr_ms) or max(1.0, 10 * link.interval)
            if now - link.last_response_at > lost_after:
                self._lose(link, now, f"no poll response for {now - link.last_response_at:.3f} s")
                return
            due = _keepalive_due(link)
            if head is None and now >= due:
                keepalive = self._request(Service.GET_ATTRIBUTE_SINGLE, ObjectClass.IDENTITY, 1, 5)
                self.enqueue(link, Transaction(keepalive, False), now)
            self._wake(due)
            self._wake(link.last_response_at + lost_after)
            if self._idle(link) and now - link.next_poll_at > 1.0:  # safety net: never forget a link
                self._make_ready(link)
        elif head is None and link.state in (LinkState.ALLOCATING, LinkState.LOST, LinkState.REFUSED):
            if now >= link.retry_at:
                self._allocate(link, now)
            else:
                self._wake(link.retry_at)


def _keepalive_due(link: MasterLink) -> float:
    """When the link's next keep-alive read is due: the first point of the grid (:data:`KEEPALIVE_GRID` of its
    period) at least 4/5 of the period after the last explicit message: within the period, in step with the
    other links whose keep-alives fall due in the same step of the grid."""
    period = link.keepalive
    step = period * KEEPALIVE_GRID
    return math.ceil((link.last_explicit_at + period - step) / step - 1e-9) * step
