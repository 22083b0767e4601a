"""Going on line, sans-IO (a base of :class:`~.node.MasterNode`): the duplicate MAC ID check, answering another
node's check, the communication fault (a duplicate of the master's MAC ID) and leaving it after a backoff, and a
slave lost (its sequence starts over).

Rules (documented in ``docs/devicenet.md``): on line, a duplicate MAC ID *request* for the master's MAC is
answered with a response; a *response* (or, during the check, a request or a response) puts the master in the
communication faulted state: nothing is sent, every link shows the fault. With ``auto_reset`` the master leaves
the fault after a backoff (1 s, doubling up to 60 s; back to 1 s after 10 minutes on line) by re-running the
whole check.
"""

from __future__ import annotations

from starterbus.core import CanFrame, TimeoutError
from starterbus.transports.devicenet.codec.cip import DeviceNetDecodeError
from starterbus.transports.devicenet.codec.dupmac import DuplicateMacCheck, decode_duplicate_mac
from starterbus.transports.devicenet.master.link import (
    CommunicationFaultError,
    IoPhase,
    LinkState,
    MasterLink,
    ScannerConfig,
    ScannerState,
)
from starterbus.transports.devicenet.master.polling import PollScheduler

__all__ = ["MASTER_VENDOR_ID", "RESET_BACKOFF", "STABLE_ONLINE", "OnLine"]

RESET_BACKOFF = (1.0, 60.0)  # first and longest wait before leaving the communication fault
STABLE_ONLINE = 600.0  # seconds on line after which the backoff starts over
MASTER_VENDOR_ID = 0  # the scanner is no registered product; vendor 0 in its duplicate MAC ID messages


class OnLine(PollScheduler):
    """The master's duplicate MAC ID check, its communication fault and its lost slaves."""

    config: ScannerConfig
    serial: int
    where: str
    state: ScannerState
    fault: CommunicationFaultError | None
    faults: int
    reset_at: float
    online_since: float
    links: dict[int, MasterLink]
    ignored: int
    _out: list[CanFrame]
    _check_step: int
    _check_deadline: float

    def start(self, now: float) -> list[CanFrame]:
        raise NotImplementedError  # the node's (MasterNode.start)

    def _begin_check(self, now: float) -> None:
        self.state = ScannerState.CHECKING
        self._out.append(self._dup_mac_frame(False))
        self._check_step = 1
        self._check_deadline = now + self.config.dup_mac_wait
        self._wake(self._check_deadline)

    def _dup_mac_frame(self, response: bool) -> CanFrame:
        return DuplicateMacCheck(self.config.master_mac, response, MASTER_VENDOR_ID, self.serial).frame()

    def _on_duplicate_mac(self, frame: CanFrame, now: float) -> None:
        try:
            message = decode_duplicate_mac(frame)
        except DeviceNetDecodeError:
            self.ignored += 1
            return
        if message.mac == self.config.master_mac:
            if self.state is ScannerState.CHECKING or (self.state is ScannerState.ONLINE and message.response):
                kind = "response" if message.response else "request"
                self._fault(
                    now,
                    f"duplicate MAC ID {message.mac} on {self.where}: another node (vendor {message.vendor_id}, "
                    f"serial 0x{message.serial_number:08X}) uses the master's MAC (duplicate MAC ID check {kind} "
                    f"{frame.text()})",
                )
            elif self.state is ScannerState.ONLINE:
                self._out.append(self._dup_mac_frame(True))
            return
        link = self.links.get(message.mac)
        if link is not None and not message.response and link.state is LinkState.ESTABLISHED:
            self._lose(link, now, "the slave restarted (duplicate MAC ID check seen)")
            link.retry_at = now + 2 * self.config.dup_mac_wait
            self._wake(link.retry_at)

    # -- the communication fault ------------------------------------------------------------------------------

    def _fault(self, now: float, why: str) -> None:
        if self.online_since and now - self.online_since >= STABLE_ONLINE:
            self.faults = 0
        self.faults += 1
        self.online_since = 0.0
        self.fault = CommunicationFaultError(why)
        self.state = ScannerState.FAULT
        first, longest = RESET_BACKOFF
        self.reset_at = now + min(longest, first * 2 ** (self.faults - 1))
        if self.config.auto_reset:
            self._wake(self.reset_at)
        self._ready.clear()
        self._confirming.clear()
        self._deadlines.clear()
        self._due.clear()
        self._in_flight = 0
        for link in self.links.values():
            link.awaiting = link.queued = False
            link.pending = None
            link.urgent = 0
            if link.run:  # the slave's watchdog stops the motor: a start must be sent again
                link.run = False
                link.output_seq += 1
            link.state = LinkState.FAULTED
            link.io = IoPhase.NONE
            link.last_error = self.fault
            self._fail_transactions(link, self.fault, started_too=True)
            link.note(now, f"master faulted: {why}")

    def reset(self, now: float) -> list[CanFrame]:
        """Leave the communication fault: run the whole duplicate MAC ID check again."""
        if self.state is not ScannerState.FAULT:
            return []
        return self.start(now)

    def _go_online(self, now: float) -> None:
        self.state = ScannerState.ONLINE
        self.fault = None
        self.online_since = now
        for link in self.links.values():
            if link.state in (LinkState.WAITING, LinkState.FAULTED):
                link.state = LinkState.ALLOCATING
                link.retry_at = now
        self._wake(now)

    # -- a slave lost

    def _lose(self, link: MasterLink, now: float, why: str) -> None:
        link.state = LinkState.LOST
        link.io = IoPhase.NONE
        self._stop_polling(link)
        if link.run:
            link.run = False
            link.output_seq += 1
            why += "; run command dropped (send start again)"
        link.last_error = TimeoutError(f"{link.describe()}: {why}")
        link.retry_at = now
        link.failures += 1
        self._wake(now)
        link.note(now, f"lost: {why}")
