"""The DeviceNet master's driver: one thread and one python-can bus around a sans-IO :class:`MasterNode`.

The protocol (duplicate MAC ID check, connection sequence, keep-alive, fragmentation, scan scheduling, the
communication fault and duplicate responders) lives in :mod:`~starterbus.transports.devicenet.master.node`.
This module only moves frames and times: the thread receives, drops at once every frame the master has no use
for (one set lookup; CAN filters on interfaces that filter in hardware or in the kernel), feeds the rest to
the machine and runs its timers when due. User threads call the machine under the same lock and send what it
returns; they wait on a condition that is notified after every change.
"""

from __future__ import annotations

import collections
import logging
import random
import threading
import time
from collections.abc import Callable

import can

from starterbus.core import CanFrame, StarterbusError, TimeoutError, open_bus, shutdown_bus
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest, ExplicitResponse
from starterbus.transports.devicenet.master.link import (
    IoPhase,
    LinkConfig,
    LinkState,
    MasterLink,
    ScannerConfig,
    ScannerState,
    Transaction,
)
from starterbus.transports.devicenet.master.node import MasterNode

__all__ = ["VIRTUAL_HINT", "Scanner", "SlaveLink"]

log = logging.getLogger(__name__)

SlaveLink = MasterLink
#: what a master told that its virtual channel has no peer in this process should use instead
VIRTUAL_HINT = (
    "from another process, serve the simulator through its loopback bridge (starterbus simulate ... "
    "--devicenet virtual:bus0 --devicenet-bridge 127.0.0.1:54701) and use devicenet://remote/127.0.0.1:54701?mac=N"
)
MAX_WAIT = 0.25  # longest receive wait: bounds the latency of timers a user thread set meanwhile
BUG_BACKOFF = 0.01  # seconds before timers run again after an unexpected exception
MESSAGE_CACHE = 512  # python-can messages kept for frames sent again (poll commands)
#: every identifier the master listens to, as three mask filters: poll responses (group 1 id 15), explicit
#: responses (group 2 id 3) and duplicate MAC ID checks (group 2 id 7); exact matching follows in software
CAN_FILTERS: list[can.typechecking.CanFilter] = [
    {"can_id": 0x3C0, "can_mask": 0x7C0, "extended": False},
    {"can_id": 0x403, "can_mask": 0x607, "extended": False},
    {"can_id": 0x407, "can_mask": 0x607, "extended": False},
]


class Scanner:
    """One DeviceNet master on one CAN bus. Thread-safe; shared by every Device on that bus in a process."""

    def __init__(
        self, config: ScannerConfig, bus: can.BusABC | None = None, clock: Callable[[], float] = time.monotonic
    ):
        self.config = config
        self.where = f"{config.interface}/{config.channel}"
        self.clock = clock
        self.bus = (
            bus
            if bus is not None
            else open_bus(config.interface, config.channel, config.bitrate, needs_peer=VIRTUAL_HINT)
        )
        self._owns_bus = bus is None
        try:
            self.bus.set_filters(CAN_FILTERS)
        except (can.CanError, NotImplementedError, AttributeError):  # pragma: no cover - software filtering
            pass
        self.machine = MasterNode(config, random.getrandbits(32), self.where)
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self._waiters = 0
        self._stop = threading.Event()
        self.received = 0
        self.dropped = 0
        self.io_cpu = 0.0
        self._messages: dict[CanFrame, can.Message] = {}  # poll commands repeat: built once
        self.errors: collections.deque[str] = collections.deque(maxlen=100)
        self.started = time.monotonic()
        self._wall_offset = time.time() - clock()
        with self.lock:
            self._send(self.machine.start(clock()))
        self._thread = threading.Thread(target=self._run, name=f"devicenet-scanner {self.where}", daemon=True)
        self._thread.start()

    # -- state --------------------------------------------------------------------------------------------------

    @property
    def state(self) -> ScannerState:
        return self.machine.state

    @property
    def fault(self) -> BaseException | None:
        return self.machine.fault

    @property
    def cycles(self) -> int:
        """Poll answers published so far (all links)."""
        return self.machine.cycles

    @property
    def polls_sent(self) -> int:
        return self.machine.polls_sent

    @property
    def links(self) -> dict[int, MasterLink]:
        return self.machine.links

    def wall_time(self, at: float) -> float:
        """Wall-clock time of a machine time (samples carry the machine's clock)."""
        return at + self._wall_offset

    def link_error(self, link: MasterLink) -> Exception | None:
        with self.lock:
            return self.machine.link_error(link)

    # -- user side ----------------------------------------------------------------------------------------------

    def _call(self, frames: list[CanFrame]) -> None:
        """Send what a machine call returned and wake the waiters (under the lock)."""
        self._send(frames)
        if self._waiters:
            self.changed.notify_all()

    def attach(self, config: LinkConfig) -> MasterLink:
        with self.lock:
            link = self.machine.attach(config, self.clock())
            self._call(self.machine.take())
            return link

    def detach(self, link: MasterLink, release: bool = True) -> None:
        """Stop scanning a slave; release its connection set first if it is established."""
        if release:
            with self.lock:
                transaction = self.machine.release(link, self.clock())
                self._call(self.machine.take())
            if transaction is not None:
                self.wait_for(lambda: transaction.done, self.config.timeout * 2)
                if transaction.error is not None:
                    link.note(self.clock(), f"release on close failed: {transaction.error}")
        with self.lock:
            self.machine.detach(link)
            self._call(self.machine.take())

    def request(
        self, link: MasterLink, request: ExplicitRequest, *, unconnected: bool = False, timeout: float | None = None
    ) -> ExplicitResponse:
        """Send an explicit request and wait for its (success) response."""
        transaction = Transaction(request, unconnected)
        with self.lock:
            self.machine.submit(link, transaction, self.clock())
            self._call(self.machine.take())
        wait = self.config.timeout * 4 if timeout is None else timeout
        if not self.wait_for(lambda: transaction.done, wait):
            raise TimeoutError(f"{link.describe()}: no response to {request.describe()} within {wait:g} s")
        if transaction.error is not None:
            raise transaction.error
        assert transaction.response is not None
        return transaction.response

    def take_control(self, link: MasterLink, timeout: float) -> None:
        """Establish the polled I/O connection of a monitored slave (the outputs set before go out with its
        first poll); raises why it could not."""
        with self.lock:
            self.machine.take_control(link, self.clock())
            self._call(self.machine.take())

        def settled() -> bool:
            return link.io in (IoPhase.HELD, IoPhase.NONE) or self.machine.link_error(link) is not None

        self.wait_for(settled, timeout)
        with self.lock:
            if link.polling:
                return
            error = self.machine.link_error(link) or link.io_error or link.last_error
        if error is not None:
            raise error
        raise TimeoutError(f"{link.describe()}: the polled I/O connection was not established within {timeout:g} s")

    def release_control(self, link: MasterLink) -> None:
        """Give the polled I/O connection back (monitoring over explicit messaging goes on)."""
        with self.lock:
            transaction = self.machine.release_control(link, self.clock())
            self._call(self.machine.take())
        if transaction is not None:
            self.wait_for(lambda: transaction.done, self.config.timeout * 2)

    def wait_for(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Wait (on the scanner's condition) until ``predicate`` holds; True if it did."""
        with self.changed:
            self._waiters += 1
            try:
                return self.changed.wait_for(predicate, timeout)
            finally:
                self._waiters -= 1

    def set_outputs(
        self,
        link: MasterLink,
        *,
        run: bool | None = None,
        reset: bool | None = None,
        select: int | None = None,
        polls: int = 1,
    ) -> int:
        """Change a slave's outputs (polled at once); returns the output sequence number to wait for."""
        with self.lock:
            seq = self.machine.set_outputs(link, self.clock(), run=run, reset=reset, select=select, polls=polls)
            self._call(self.machine.tick(self.clock()))
            return seq

    def expedite(self, link: MasterLink, polls: int = 1) -> None:
        """Poll ``link`` now (a reader wants fresh inputs)."""
        with self.lock:
            self.machine.expedite(link, self.clock(), polls)
            self._call(self.machine.tick(self.clock()))

    def wait_acked(self, link: MasterLink, seq: int, timeout: float) -> bool:
        def settled() -> bool:
            return link.acked_seq >= seq or link.state is LinkState.CLOSED or self.machine.link_error(link) is not None

        return self.wait_for(settled, timeout) and link.acked_seq >= seq

    def reset(self) -> None:
        """Leave the communication fault now (the duplicate MAC ID check runs again)."""
        with self.lock:
            self._call(self.machine.reset(self.clock()))

    def close(self) -> None:
        with self.lock:
            links = list(self.machine.links.values())
        for link in links:
            self.detach(link)
        self._halt()

    def abandon(self) -> None:
        """Stop at once without releasing anything (what a crashed or unplugged master leaves behind)."""
        self._halt()

    def _halt(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        with self.lock:
            self.machine.close()
            self.changed.notify_all()
        if self._owns_bus:
            shutdown_bus(self.bus)

    def _not_online(self) -> Exception:
        return self.machine.not_online()

    def wait_online(self, timeout: float) -> None:
        if not self.wait_for(lambda: self.machine.state is not ScannerState.CHECKING, timeout):
            raise TimeoutError(
                f"DeviceNet master on {self.where}: duplicate MAC ID check did not finish in {timeout:g} s"
            )
        if self.machine.state is not ScannerState.ONLINE:
            raise self.machine.not_online()

    def stats(self) -> dict[str, float]:
        elapsed = time.monotonic() - self.started
        machine = self.machine
        return {
            "cycles": machine.cycles,
            "polls": machine.polls_sent,
            "io_cpu_s": self.io_cpu,
            "elapsed_s": elapsed,
            "received": self.received,
            "dropped": self.dropped,
        }

    # -- the I/O thread -----------------------------------------------------------------------------------------

    def _send(self, frames: list[CanFrame]) -> None:
        messages = self._messages
        for frame in frames:
            message = messages.get(frame)
            if message is None:
                message = can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=False)
                if len(messages) >= MESSAGE_CACHE:
                    messages.clear()
                messages[frame] = message
            try:
                self.bus.send(message)
            except can.CanError as exc:
                log.warning("DeviceNet send %s failed: %s", frame.text(), exc)

    def _run(self) -> None:
        cpu0 = time.thread_time()
        machine, bus, clock, lock, stop = self.machine, self.bus, self.clock, self.lock, self._stop
        while not stop.is_set():
            try:
                now = clock()
                if now >= machine.deadline:
                    with lock:
                        self._call(machine.tick(now))
                    self.io_cpu = time.thread_time() - cpu0
                message = bus.recv(min(max(machine.deadline - clock(), 0.0), MAX_WAIT))
                if message is None:
                    continue
                self.received += 1
                can_id = message.arbitration_id
                if can_id not in machine.wanted or message.is_extended_id or message.is_remote_frame:
                    self.dropped += 1
                    continue
                data = bytes(message.data)
                if len(data) > 8:  # CAN FD: not DeviceNet
                    self.dropped += 1
                    continue
                with lock:
                    self._call(machine.receive(can_id, data, clock()))
            except StarterbusError as exc:  # a malformed frame; never stop the master
                self.errors.append(str(exc))
            except Exception as exc:  # a bug must not stop the master either; keep it visible
                if stop.is_set():
                    break
                log.exception("DeviceNet scanner on %s", self.where)
                self.errors.append(f"{type(exc).__name__}: {exc}")
                with lock:  # a timer that failed must not be retried in a tight loop
                    machine.deadline = max(machine.deadline, clock() + BUG_BACKOFF)
        self.io_cpu = time.thread_time() - cpu0
