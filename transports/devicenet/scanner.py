"""The DeviceNet master (scanner): one per CAN bus and process, scanning every slave a Device asks for.

One background thread owns the python-can bus. It goes on line with the duplicate MAC ID check, then for each
slave (a :class:`SlaveLink`) runs the connection sequence (Allocate/Release through the group 2 only
unconnected port, the rest on the explicit connection)::

    Allocate explicit + polled (choice 0x03)
      -> "already allocated" (0x0B, our own old allocation, e.g. after a restart): Release 0x03, Allocate again
      -> "allocated to another master" (0x0C/0x01): refused, retried every retry interval
    Get the explicit connection's EPR (class 5 instance 1 attribute 9) -> keep-alive period
    Get produced/consumed size of the polled connection (class 5 instance 2 attributes 7, 8) -> assembly set
    Set expected packet rate (class 5 instance 2 attribute 9) -> polled connection established

and polls the established slaves cyclically (up to ``WINDOW`` poll commands in flight), keeping the latest
input assembly of each with its time. A slave silent for 4 x EPR is marked lost (its run command is dropped:
a start must be sent again) and the sequence starts over until it answers again. The explicit connection is
kept alive by reading the identity status at a third of its inactivity timeout (at most every second).
Explicit requests of user threads (identify) are queued per slave and sent one at a time, fragmented or
reassembled as needed.

User threads never touch the bus: they change a slave's outputs under the lock and wait (with a timeout) until
a poll carrying them was answered.
"""

from __future__ import annotations

import collections
import enum
import logging
import random
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import can

from starterbus.core.errors import (
    ConfigurationError,
    StarterbusError,
    TimeoutError,
    TransportError,
)
from starterbus.transports.devicenet.assemblies import AssemblySet, OutputAssembly
from starterbus.transports.devicenet.canbus import open_bus, shutdown
from starterbus.transports.devicenet.cip import (
    DeviceNetDecodeError,
    GeneralStatus,
    ObjectClass,
    Service,
)
from starterbus.transports.devicenet.connection import (
    DEFAULT_EXPLICIT_EPR_MS,
    EXPLICIT_AND_POLLED,
    ConnectionAttribute,
    ConnectionInstance,
    inactivity_timeout,
)
from starterbus.transports.devicenet.dupmac import DEFAULT_WAIT, DuplicateMacCheck, decode_duplicate_mac
from starterbus.transports.devicenet.explicit import (
    ErrorResponse,
    ExplicitRequest,
    ExplicitResponse,
    Response,
    check_response,
    decode_response,
)
from starterbus.transports.devicenet.fragmentation import (
    Fragmenter,
    Reassembler,
    decode_fragment,
    frames_for,
    is_fragment,
)
from starterbus.transports.devicenet.frames import CanFrame
from starterbus.transports.devicenet.ids import (
    explicit_request_id,
    explicit_response_id,
    poll_command_id,
    poll_response_id,
    unconnected_request_id,
)

log = logging.getLogger(__name__)

WINDOW = 8  # poll commands in flight at once
POLL_RESPONSE_TIMEOUT = 0.05  # seconds a scan cycle waits for the last poll responses
KEEPALIVE = 1.0  # longest time between explicit keep-alive reads (the default inactivity timeout is 10 s)
HOUSEKEEPING = 0.002  # seconds between timer checks while frames keep arriving
MAX_WAIT = 0.005  # longest receive wait: user requests are picked up at least this often
MASTER_VENDOR_ID = 0  # the scanner is no registered product; vendor 0 in its duplicate MAC ID messages


class ScannerState(str, enum.Enum):
    CHECKING = "duplicate MAC ID check"
    ONLINE = "on line"
    FAULT = "communication fault"
    CLOSED = "closed"


class LinkState(str, enum.Enum):
    WAITING = "waiting for the scanner"
    ALLOCATING = "allocating"
    RELEASING = "releasing an old allocation"
    CONFIGURING = "configuring the polled connection"
    ESTABLISHED = "established"
    LOST = "lost (no answer)"
    REFUSED = "refused"
    CLOSED = "closed"


@dataclass(frozen=True, slots=True)
class ScannerConfig:
    interface: str
    channel: str
    master_mac: int = 0
    bitrate: int = 500000
    poll_period: float = 0.02
    dup_mac_wait: float = DEFAULT_WAIT
    timeout: float = 1.0

    def conflicts(self, other: ScannerConfig) -> list[str]:
        names = ("master_mac", "bitrate", "poll_period", "dup_mac_wait")
        return [n for n in names if getattr(self, n) != getattr(other, n)]


@dataclass(frozen=True, slots=True)
class LinkConfig:
    mac: int
    assemblies: str = "auto"  # auto | basic | extended
    epr_ms: int = 100
    settle: int = 2  # poll responses with a new status parameter address before its value is trusted


class InputSample(NamedTuple):
    """The latest input assembly of a slave (a tuple: built on every poll response, so kept cheap)."""

    data: bytes
    at: float  # monotonic receive time
    wall: float  # time.time() at receipt
    select: int | None  # status parameter address the answered poll carried (extended)
    select_count: int  # consecutive responses to polls with this address, this one included
    seq: int  # output sequence number the answered poll carried


@dataclass(slots=True)
class Transaction:
    """One explicit request/response with a slave (the I/O thread's business once queued)."""

    request: ExplicitRequest
    unconnected: bool
    on_done: Callable[[Transaction], None] | None = None
    response: ExplicitResponse | None = None
    error: BaseException | None = None
    done: threading.Event = field(default_factory=threading.Event)
    deadline: float = 0.0
    fragmenter: Fragmenter | None = None
    reassembler: Reassembler = field(default_factory=Reassembler)
    started: bool = False


class SlaveLink:
    """The scanner's view of one slave: connection state, outputs to send, latest inputs."""

    def __init__(self, scanner: Scanner, config: LinkConfig) -> None:
        self.scanner = scanner
        self.config = config
        self.mac = config.mac
        self.state = LinkState.WAITING
        self.assemblies: AssemblySet | None = None
        self.epr_ms = 0
        self.last_error: BaseException | None = None
        self.failures = 0  # connection attempts that failed since the last success
        self.retry_at = 0.0
        self.established_at = 0.0
        self.events: collections.deque[tuple[float, str]] = collections.deque(maxlen=100)
        # outputs (changed under the scanner lock by user threads)
        self.run = False
        self.reset = False
        self.select = 0x01
        self.output_seq = 0
        self.select_lock = threading.Lock()
        # poll bookkeeping (I/O thread)
        self.poll_message: can.Message | None = None
        self.built_seq = -1
        self.built_select: int | None = None
        self.sent_seq = 0
        self.sent_select: int | None = None
        self.sample: InputSample | None = None
        self.acked_seq = -1
        self.responses = 0
        self.misses = 0
        self.last_response_at = 0.0
        self.awaiting = False
        # explicit messaging
        self.transactions: collections.deque[Transaction] = collections.deque()
        self.xid = 0
        self.last_explicit_at = 0.0
        self.explicit_epr_ms = DEFAULT_EXPLICIT_EPR_MS

    @property
    def keepalive(self) -> float:
        """Seconds between keep-alive reads: a third of the explicit connection's inactivity timeout, at most 1 s."""
        timeout = inactivity_timeout(self.explicit_epr_ms)
        return KEEPALIVE if timeout is None else min(KEEPALIVE, timeout / 3)

    def note(self, now: float, text: str) -> None:
        self.events.append((now, text))
        log.debug("MAC %d: %s", self.mac, text)

    @property
    def established(self) -> bool:
        return self.state is LinkState.ESTABLISHED

    def output(self) -> OutputAssembly:
        bits = (0x01 if self.run else 0) | (0x04 if self.reset else 0)
        if self.assemblies is AssemblySet.BASIC:
            return OutputAssembly(2, bits)
        return OutputAssembly(102, bits, self.select)

    def describe(self) -> str:
        return f"MAC {self.mac} on {self.scanner.where}"


class Scanner:
    """One DeviceNet master on one CAN bus. Thread-safe; shared by every Device on that bus in a process."""

    def __init__(
        self, config: ScannerConfig, bus: can.BusABC | None = None, clock: Callable[[], float] = time.monotonic
    ):
        self.config = config
        self.where = f"{config.interface}/{config.channel}"
        self.clock = clock
        self.bus = bus if bus is not None else open_bus(config.interface, config.channel, config.bitrate)
        self._owns_bus = bus is None
        self.serial = random.getrandbits(32)
        self.state = ScannerState.CHECKING
        self.fault: BaseException | None = None
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.links: dict[int, SlaveLink] = {}
        self._scan_list: list[SlaveLink] = []
        self._by_response: dict[int, SlaveLink] = {}
        self._by_explicit: dict[int, SlaveLink] = {}
        self._commands: collections.deque[Callable[[], None]] = collections.deque()
        self._waiters = 0
        self._stop = threading.Event()
        self._check_step = 0
        self._check_deadline = 0.0
        self._next_housekeeping = 0.0
        # scan cycle
        self._cycle_active = False
        self._cycle_queue: collections.deque[SlaveLink] = collections.deque()
        self._cycle_outstanding = 0
        self._cycle_deadline = 0.0
        self._next_cycle = 0.0
        self.cycles = 0
        self.polls_sent = 0
        self.io_cpu = 0.0
        self.started = time.monotonic()
        self._thread = threading.Thread(target=self._run, name=f"devicenet-scanner {self.where}", daemon=True)
        self._thread.start()

    # -- user side ----------------------------------------------------------------------------------------------

    def attach(self, config: LinkConfig) -> SlaveLink:
        with self.lock:
            if config.mac in self.links:
                raise ConfigurationError(f"DeviceNet MAC {config.mac} on {self.where} is already open in this process")
            if config.mac == self.config.master_mac:
                raise ConfigurationError(f"slave MAC {config.mac} equals the master's MAC on {self.where}")
            link = SlaveLink(self, config)
            self.links[config.mac] = link
            self._scan_list = sorted(self.links.values(), key=lambda item: item.mac)
            self._by_response[poll_response_id(config.mac)] = link
            self._by_explicit[explicit_response_id(config.mac)] = link
            if self.state is ScannerState.ONLINE:
                link.state = LinkState.ALLOCATING
                link.retry_at = self.clock()
            return link

    def detach(self, link: SlaveLink, release: bool = True) -> None:
        """Stop scanning a slave; release its connection set first if it is established."""
        if release and link.established and self.state is ScannerState.ONLINE:
            request = ExplicitRequest(
                self.config.master_mac, Service.RELEASE, ObjectClass.DEVICENET, 1, None, bytes((EXPLICIT_AND_POLLED,))
            )
            try:
                self.request(link, request, unconnected=False)
            except StarterbusError as exc:
                link.note(self.clock(), f"release on close failed: {exc}")
        with self.lock:
            link.state = LinkState.CLOSED
            self.links.pop(link.mac, None)
            self._scan_list = sorted(self.links.values(), key=lambda item: item.mac)
            self._by_response.pop(poll_response_id(link.mac), None)
            self._by_explicit.pop(explicit_response_id(link.mac), None)
            for transaction in link.transactions:
                transaction.error = TransportError(f"{link.describe()} closed")
                transaction.done.set()
            link.transactions.clear()

    def request(
        self, link: SlaveLink, request: ExplicitRequest, *, unconnected: bool = False, timeout: float | None = None
    ) -> ExplicitResponse:
        """Send an explicit request and wait for its (success) response."""
        if self.state is not ScannerState.ONLINE:
            raise self._not_online()
        if not unconnected and not link.established:
            raise TimeoutError(f"{link.describe()}: no explicit connection ({link.state.value})")
        transaction = Transaction(request, unconnected)
        self._enqueue(link, transaction)
        wait = self.config.timeout * 4 if timeout is None else timeout
        if not transaction.done.wait(wait):
            raise TimeoutError(f"{link.describe()}: no response to {request.describe()} within {wait:g} s")
        if transaction.error is not None:
            raise transaction.error
        assert transaction.response is not None
        return transaction.response

    def _enqueue(self, link: SlaveLink, transaction: Transaction) -> None:
        with self.lock:
            link.xid ^= 1
            transaction.request = ExplicitRequest(
                self.config.master_mac,
                transaction.request.service,
                transaction.request.class_id,
                transaction.request.instance,
                transaction.request.attribute,
                transaction.request.data,
                link.xid,
            )
            link.transactions.append(transaction)

    def wait_for(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Wait (on the scanner's condition) until ``predicate`` holds; True if it did."""
        with self.changed:
            self._waiters += 1
            try:
                return self.changed.wait_for(predicate, timeout)
            finally:
                self._waiters -= 1

    def set_outputs(
        self, link: SlaveLink, *, run: bool | None = None, reset: bool | None = None, select: int | None = None
    ) -> int:
        """Change a slave's outputs; returns the output sequence number to wait for."""
        with self.lock:
            if run is not None:
                link.run = run
            if reset is not None:
                link.reset = reset
            if select is not None:
                link.select = select
            link.output_seq += 1
            return link.output_seq

    def wait_acked(self, link: SlaveLink, seq: int, timeout: float) -> bool:
        return (
            self.wait_for(lambda: link.acked_seq >= seq or link.state is LinkState.CLOSED, timeout)
            and link.acked_seq >= seq
        )

    def close(self) -> None:
        with self.lock:
            links = list(self.links.values())
        for link in links:
            self.detach(link)
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        with self.lock:
            self.state = ScannerState.CLOSED
            self.changed.notify_all()
        if self._owns_bus:
            shutdown(self.bus)

    def abandon(self) -> None:
        """Stop at once without releasing anything (what a crashed or unplugged master leaves behind)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self.state = ScannerState.CLOSED
        if self._owns_bus:
            shutdown(self.bus)

    def _not_online(self) -> StarterbusError:
        if self.state is ScannerState.FAULT and self.fault is not None:
            return TransportError(f"DeviceNet master on {self.where} is off line: {self.fault}")
        if self.state is ScannerState.CLOSED:
            return TransportError(f"DeviceNet master on {self.where} is closed")
        return TimeoutError(f"DeviceNet master on {self.where} is not on line yet ({self.state.value})")

    def wait_online(self, timeout: float) -> None:
        if not self.wait_for(lambda: self.state is not ScannerState.CHECKING, timeout):
            raise TimeoutError(
                f"DeviceNet master on {self.where}: duplicate MAC ID check did not finish in {timeout:g} s"
            )
        if self.state is not ScannerState.ONLINE:
            raise self._not_online()

    def stats(self) -> dict[str, float]:
        elapsed = time.monotonic() - self.started
        return {"cycles": self.cycles, "polls": self.polls_sent, "io_cpu_s": self.io_cpu, "elapsed_s": elapsed}

    # -- the I/O thread -----------------------------------------------------------------------------------------

    def _send(self, can_id: int, data: bytes) -> None:
        try:
            self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        except can.CanError as exc:
            log.warning("DeviceNet send %03X#%s failed: %s", can_id, data.hex(), exc)

    def _notify(self) -> None:
        if self._waiters:
            with self.changed:
                self.changed.notify_all()

    def _run(self) -> None:
        cpu0 = time.thread_time()
        try:
            self._loop()
        except Exception as exc:  # keep the failure visible to every user
            log.exception("DeviceNet scanner on %s failed", self.where)
            self.fault = exc
            self.state = ScannerState.FAULT
        finally:
            self.io_cpu = time.thread_time() - cpu0
            self._notify_all()

    def _notify_all(self) -> None:
        with self.changed:
            self.changed.notify_all()

    def _loop(self) -> None:
        bus = self.bus
        clock = self.clock
        stop = self._stop
        by_response = self._by_response
        cpu0 = time.thread_time()
        now = clock()
        self._dup_mac(False)
        self._check_step = 1
        self._check_deadline = now + self.config.dup_mac_wait
        while not stop.is_set():
            now = clock()
            if now >= self._next_housekeeping:
                self._housekeeping(now)
                self.io_cpu = time.thread_time() - cpu0
            if self.state is ScannerState.ONLINE and not self._cycle_active and now >= self._next_cycle:
                self._start_cycle(now)
            wait = MAX_WAIT
            if self._cycle_active:
                wait = min(wait, self._cycle_deadline - now)
            elif self.state is ScannerState.ONLINE:
                wait = min(wait, self._next_cycle - now)
            message = bus.recv(max(0.0, wait))
            if message is None:
                continue
            link = by_response.get(message.arbitration_id)
            if link is not None and not message.is_extended_id:
                self._on_poll_response(link, bytes(message.data), clock())
            elif not message.is_extended_id and not message.is_error_frame and not message.is_remote_frame:
                self._on_other(message.arbitration_id, bytes(message.data), clock())

    # -- scan cycles ------------------------------------------------------------------------------------------

    def _start_cycle(self, now: float) -> None:
        self._next_cycle = now + self.config.poll_period
        queue = self._cycle_queue
        queue.extend(self._scan_list)  # _send_next_poll skips the links not established
        self._cycle_active = True
        self._cycle_outstanding = 0
        self._cycle_deadline = now + POLL_RESPONSE_TIMEOUT
        for _ in range(WINDOW):
            if not queue:
                break
            self._send_next_poll()
        if not self._cycle_outstanding:
            self._cycle_active = False
            self._next_cycle = now + max(self.config.poll_period, MAX_WAIT)

    def _send_next_poll(self) -> None:
        queue = self._cycle_queue
        while queue:
            link = queue.popleft()
            if link.state is not LinkState.ESTABLISHED:
                continue
            seq = link.output_seq
            if seq != link.built_seq or link.poll_message is None:
                output = link.output()
                link.poll_message = can.Message(
                    arbitration_id=poll_command_id(link.mac), data=output.encode(), is_extended_id=False
                )
                link.built_seq = seq
                link.built_select = output.address
            link.sent_seq = link.built_seq
            link.sent_select = link.built_select
            link.awaiting = True
            self._cycle_outstanding += 1
            self.polls_sent += 1
            try:
                self.bus.send(link.poll_message)
            except can.CanError as exc:
                log.warning("DeviceNet poll of MAC %d failed: %s", link.mac, exc)
            return

    def _on_poll_response(self, link: SlaveLink, data: bytes, now: float) -> None:
        if not link.awaiting:
            return  # late or unsolicited
        link.awaiting = False
        previous = link.sample
        select = link.sent_select
        count = previous.select_count + 1 if previous is not None and previous.select == select else 1
        link.sample = InputSample(data, now, time.time(), select, count, link.sent_seq)
        link.acked_seq = link.sent_seq
        link.responses += 1
        link.last_response_at = now
        self._cycle_outstanding -= 1
        if self._cycle_queue:
            self._send_next_poll()
        elif self._cycle_outstanding <= 0:
            self._end_cycle(now)
        if self._waiters:
            self._notify()

    def _end_cycle(self, now: float) -> None:
        self._cycle_active = False
        self.cycles += 1
        for link in self._scan_list:
            if link.awaiting:
                link.awaiting = False
                link.misses += 1
        if self.config.poll_period <= 0:
            self._next_cycle = now

    # -- timers -------------------------------------------------------------------------------------------------

    def _housekeeping(self, now: float) -> None:
        self._next_housekeeping = now + HOUSEKEEPING
        while self._commands:
            self._commands.popleft()()
        if self.state is ScannerState.CHECKING and now >= self._check_deadline:
            if self._check_step == 1:
                self._dup_mac(False)
                self._check_step = 2
                self._check_deadline = now + self.config.dup_mac_wait
            else:
                self._go_online(now)
        if self._cycle_active and now >= self._cycle_deadline:
            self._end_cycle(now)
        if self.state is not ScannerState.ONLINE:
            return
        with self.lock:
            links = list(self.links.values())
        for link in links:
            self._link_timers(link, now)

    def _go_online(self, now: float) -> None:
        with self.lock:
            self.state = ScannerState.ONLINE
            for link in self.links.values():
                if link.state is LinkState.WAITING:
                    link.state = LinkState.ALLOCATING
                    link.retry_at = now
            self.changed.notify_all()
        log.debug("DeviceNet master MAC %d on line on %s", self.config.master_mac, self.where)

    def _link_timers(self, link: SlaveLink, now: float) -> None:
        with self.lock:
            head = link.transactions[0] if link.transactions else None
        if head is not None:
            if not head.started:
                self._start_transaction(link, head, now)
            elif now >= head.deadline:
                self._finish(
                    link,
                    head,
                    error=TimeoutError(
                        f"{link.describe()}: no response to {head.request.describe()} within {self.config.timeout:g} s"
                    ),
                )
        if link.state is LinkState.ESTABLISHED:
            lost_after = inactivity_timeout(link.epr_ms) or max(1.0, 10 * self.config.poll_period)
            if now - link.last_response_at > lost_after:
                self._lose(link, now, f"no poll response for {now - link.last_response_at:.3f} s")
            elif head is None and now - link.last_explicit_at >= link.keepalive:
                link.last_explicit_at = now
                self._enqueue(link, Transaction(self._get(ObjectClass.IDENTITY, 1, 5), False, self._keepalive_done))
        elif (
            head is None
            and link.state in (LinkState.ALLOCATING, LinkState.LOST, LinkState.REFUSED)
            and now >= link.retry_at
        ):
            self._allocate(link, now)

    def _lose(self, link: SlaveLink, now: float, why: str) -> None:
        with self.lock:
            link.state = LinkState.LOST
            if link.run:
                link.run = False
                link.output_seq += 1
                why += "; run command dropped (send start again)"
            link.last_error = TimeoutError(f"{link.describe()}: {why}")
            link.retry_at = now
            link.failures += 1
            self.changed.notify_all()
        link.note(now, f"lost: {why}")

    # -- explicit transactions ------------------------------------------------------------------------------

    def _get(self, class_id: int, instance: int, attribute: int) -> ExplicitRequest:
        return ExplicitRequest(self.config.master_mac, Service.GET_ATTRIBUTE_SINGLE, class_id, instance, attribute)

    def _start_transaction(self, link: SlaveLink, transaction: Transaction, now: float) -> None:
        transaction.started = True
        transaction.deadline = now + self.config.timeout
        link.last_explicit_at = now
        message = transaction.request.encode()
        can_id = unconnected_request_id(link.mac) if transaction.unconnected else explicit_request_id(link.mac)
        frames = frames_for(message)
        if len(frames) > 1:
            if transaction.unconnected:
                self._finish(link, transaction, error=TransportError("the group 2 only port does not fragment"))
                return
            transaction.fragmenter = Fragmenter(message)
            self._send(can_id, transaction.fragmenter.current)
        else:
            self._send(can_id, frames[0])

    def _finish(
        self,
        link: SlaveLink,
        transaction: Transaction,
        response: ExplicitResponse | None = None,
        error: BaseException | None = None,
    ) -> None:
        with self.lock:
            if link.transactions and link.transactions[0] is transaction:
                link.transactions.popleft()
            transaction.response = response
            transaction.error = error
        if transaction.on_done is not None:
            try:
                transaction.on_done(transaction)
            except Exception as exc:
                log.exception("DeviceNet continuation failed for MAC %d", link.mac)
                link.last_error = exc
        transaction.done.set()
        now = self.clock()
        with self.lock:
            head = link.transactions[0] if link.transactions else None
        if head is not None and not head.started:
            self._start_transaction(link, head, now)

    def _on_other(self, can_id: int, data: bytes, now: float) -> None:
        link = self._by_explicit.get(can_id)
        if link is not None:
            self._on_explicit_response(link, data, now)
            return
        if 0x400 <= can_id < 0x600 and can_id & 0x07 == 7:
            self._on_duplicate_mac(CanFrame(can_id, data[:8]), now)

    def _on_explicit_response(self, link: SlaveLink, data: bytes, now: float) -> None:
        with self.lock:
            transaction = link.transactions[0] if link.transactions else None
        if transaction is None or not transaction.started or not data:
            return
        if data[0] & 0x3F != self.config.master_mac:
            return  # for another master
        ack_id = explicit_request_id(link.mac)
        try:
            if is_fragment(data):
                fragment = decode_fragment(data)
                if fragment.is_ack:
                    fragmenter = transaction.fragmenter
                    if fragmenter is None:
                        return
                    following = fragmenter.on_ack(data)
                    if following is not None:
                        transaction.deadline = now + self.config.timeout
                        self._send(ack_id, following)
                    return
                reply, whole = transaction.reassembler.feed(data)
                self._send(ack_id, reply)
                transaction.deadline = now + self.config.timeout
                if whole is None:
                    return
                data = whole
            response: Response = decode_response(data)
            if response.xid != transaction.request.xid:
                return  # a late answer to an earlier, timed-out request
            if isinstance(response, ErrorResponse):
                self._finish(
                    link, transaction, error=response.error(transaction.request.service, transaction.request.describe())
                )
                return
            self._finish(link, transaction, response=check_response(transaction.request, response))
        except DeviceNetDecodeError as exc:
            self._finish(link, transaction, error=exc)

    def _on_duplicate_mac(self, frame: CanFrame, now: float) -> None:
        try:
            message = decode_duplicate_mac(frame)
        except DeviceNetDecodeError:
            return
        if message.mac == self.config.master_mac:
            if self.state is ScannerState.CHECKING or message.response:
                self.fault = TransportError(
                    f"duplicate MAC ID {message.mac} on {self.where}: another node (vendor {message.vendor_id}, "
                    f"serial 0x{message.serial_number:08X}) uses the master's MAC"
                )
                with self.lock:
                    self.state = ScannerState.FAULT
                    self.changed.notify_all()
                self._stop.set()
            elif self.state is ScannerState.ONLINE:
                self._dup_mac(True)
            return
        link = self.links.get(message.mac)
        if link is not None and not message.response and link.state is LinkState.ESTABLISHED:
            self._lose(link, now, "the slave restarted (duplicate MAC ID check seen)")
            link.retry_at = now + 2 * self.config.dup_mac_wait

    def _dup_mac(self, response: bool) -> None:
        frame = DuplicateMacCheck(self.config.master_mac, response, MASTER_VENDOR_ID, self.serial).frame()
        self._send(frame.can_id, frame.data)

    # -- the connection sequence ----------------------------------------------------------------------------

    def _allocate(self, link: SlaveLink, now: float, after_release: bool = False) -> None:
        link.state = LinkState.ALLOCATING
        link.retry_at = now + self.config.timeout  # overwritten by the outcome
        request = ExplicitRequest(
            self.config.master_mac,
            Service.ALLOCATE,
            ObjectClass.DEVICENET,
            1,
            None,
            bytes((EXPLICIT_AND_POLLED, self.config.master_mac)),
        )

        def done(t: Transaction) -> None:
            if t.error is None:
                link.note(self.clock(), "allocated explicit + polled")
                self._configure(link)
                return
            error = t.error
            if (
                not after_release
                and isinstance(error, StarterbusError)
                and getattr(error, "code", None) == GeneralStatus.ALREADY_IN_REQUESTED_MODE
            ):
                link.note(self.clock(), "the slave still holds our old allocation: release and allocate again")
                self._release_then_allocate(link)
                return
            self._failed(link, error)

        self._enqueue(link, Transaction(request, True, done))

    def _release_then_allocate(self, link: SlaveLink) -> None:
        link.state = LinkState.RELEASING
        request = ExplicitRequest(
            self.config.master_mac, Service.RELEASE, ObjectClass.DEVICENET, 1, None, bytes((EXPLICIT_AND_POLLED,))
        )

        def done(t: Transaction) -> None:
            if t.error is not None:
                self._failed(link, t.error)
                return
            self._allocate(link, self.clock(), after_release=True)

        self._enqueue(link, Transaction(request, True, done))

    def _configure(self, link: SlaveLink) -> None:
        link.state = LinkState.CONFIGURING
        sizes: dict[int, int] = {}

        def got_explicit_epr(t: Transaction) -> None:
            data = t.response.data if t.response is not None else b""
            link.explicit_epr_ms = struct.unpack("<H", data)[0] if len(data) == 2 else DEFAULT_EXPLICIT_EPR_MS

        self._enqueue(
            link,
            Transaction(
                self._get(
                    ObjectClass.CONNECTION, ConnectionInstance.EXPLICIT, ConnectionAttribute.EXPECTED_PACKET_RATE
                ),
                False,
                got_explicit_epr,
            ),
        )

        def got_size(attribute: int) -> Callable[[Transaction], None]:
            def done(t: Transaction) -> None:
                if t.error is not None or t.response is None:
                    self._failed(link, t.error or TransportError("no response"))
                    return
                if len(t.response.data) != 2:
                    self._failed(link, TransportError(f"connection size of {len(t.response.data)} bytes"))
                    return
                sizes[attribute] = struct.unpack("<H", t.response.data)[0]
                if len(sizes) == 2:
                    self._choose_assemblies(
                        link,
                        sizes[ConnectionAttribute.PRODUCED_CONNECTION_SIZE],
                        sizes[ConnectionAttribute.CONSUMED_CONNECTION_SIZE],
                    )

            return done

        for attribute in (ConnectionAttribute.PRODUCED_CONNECTION_SIZE, ConnectionAttribute.CONSUMED_CONNECTION_SIZE):
            self._enqueue(
                link,
                Transaction(
                    self._get(ObjectClass.CONNECTION, ConnectionInstance.POLLED, attribute), False, got_size(attribute)
                ),
            )

    def _choose_assemblies(self, link: SlaveLink, produced: int, consumed: int) -> None:
        found = AssemblySet.for_sizes(produced, consumed)
        wanted = link.config.assemblies
        if found is None or wanted not in ("auto", found.value):
            what = f"{found.value} assemblies" if found else "no JJR8000 assembly pair"
            self._failed(
                link,
                ConfigurationError(
                    f"{link.describe()} produces {produced} and consumes {consumed} bytes ({what}) but the URL asks "
                    f"for assemblies={wanted} (PRO type P1/M1 = basic 1/2, P3/M2 = extended 101/102)"
                ),
                release=True,
            )
            return
        link.assemblies = found
        link.built_seq = -1
        request = ExplicitRequest(
            self.config.master_mac,
            Service.SET_ATTRIBUTE_SINGLE,
            ObjectClass.CONNECTION,
            ConnectionInstance.POLLED,
            ConnectionAttribute.EXPECTED_PACKET_RATE,
            struct.pack("<H", link.config.epr_ms),
        )

        def done(t: Transaction) -> None:
            if t.error is not None or t.response is None:
                self._failed(link, t.error or TransportError("no response"))
                return
            now = self.clock()
            actual = struct.unpack("<H", t.response.data)[0] if len(t.response.data) == 2 else link.config.epr_ms
            with self.lock:
                link.epr_ms = actual
                link.state = LinkState.ESTABLISHED
                link.established_at = now
                link.last_response_at = now
                link.last_explicit_at = now
                link.failures = 0
                link.last_error = None
                self.changed.notify_all()
            link.note(now, f"established: {found.value} assemblies, expected packet rate {actual} ms")

        self._enqueue(link, Transaction(request, False, done))

    def _failed(self, link: SlaveLink, error: BaseException, release: bool = False) -> None:
        now = self.clock()
        with self.lock:
            dropped = [t for t in link.transactions if not t.started]
            for transaction in dropped:  # the rest of the sequence (and any user request) cannot go on
                link.transactions.remove(transaction)
                transaction.error = error
                transaction.done.set()
            link.failures += 1
            link.last_error = error
            if isinstance(error, TimeoutError):
                link.state = LinkState.LOST
                link.retry_at = now + min(self.config.timeout, 0.25)
            else:
                link.state = LinkState.REFUSED
                link.retry_at = now + max(self.config.timeout, 1.0)
            self.changed.notify_all()
        link.note(now, f"{link.state.value}: {error}")
        if release:
            request = ExplicitRequest(
                self.config.master_mac, Service.RELEASE, ObjectClass.DEVICENET, 1, None, bytes((EXPLICIT_AND_POLLED,))
            )
            self._enqueue(link, Transaction(request, True))

    def _keepalive_done(self, transaction: Transaction) -> None:
        if transaction.error is not None:
            log.debug("DeviceNet keep-alive failed: %s", transaction.error)
