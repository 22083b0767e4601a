"""A DeviceNet slave node's state (:class:`SlaveState`) and its parts: the connections, the counters and what
the node needs from the device behind it (:class:`SlaveApplication`).

The node's behaviour builds on it in two layers: ``slave.objects`` (the objects a master reads and the
allocation of the connection set) and ``slave.node`` (the bus side: duplicate MAC ID check, timers, I/O,
explicit messaging; its docstring lists the decisions). Sans-IO like them: no clock, no bus.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol

from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.cip import CipStatus
from starterbus.transports.devicenet.codec.connection import (
    DEFAULT_EXPLICIT_EPR_MS,
    UNALLOCATED_MASTER,
    AllocationChoice,
    ConnectionInstance,
    ConnectionState,
    WatchdogAction,
    describe_choice,
    inactivity_timeout,
)
from starterbus.transports.devicenet.codec.dupmac import DEFAULT_WAIT
from starterbus.transports.devicenet.codec.fragmentation import Fragmenter, Reassembler
from starterbus.transports.devicenet.codec.identity import STATUS_OWNED, Identity

EXPLICIT_CONNECTION_SIZE = 64  # bytes the explicit connection produces/consumes at most (fragmented)
FRAGMENT_ACK_TIMEOUT = 1.0  # seconds a fragmented response waits for each acknowledgement
FRAGMENT_RETRIES = 1


class NodeState(str, enum.Enum):
    OFFLINE = "offline"  # not started
    CHECKING = "checking"  # duplicate MAC ID check in progress
    ONLINE = "online"
    COMM_FAULT = "communication fault"  # duplicate MAC ID detected


class SlaveApplication(Protocol):
    """What a slave node needs from the device behind it."""

    def assembly_set(self) -> AssemblySet:
        """The assembly pair the polled connection produces/consumes (the JJR8000's PRO type)."""

    def instance_numbers(self) -> tuple[int, int]:
        """The (input, output) instance numbers of :meth:`assembly_set` as the model numbers them."""

    def produce(self, instance: int) -> bytes:
        """The current data of input assembly ``instance``."""

    def consume(self, instance: int, data: bytes) -> None:
        """Output assembly data received by the polled connection."""

    def output_data(self, instance: int) -> bytes:
        """The last output data consumed for ``instance`` (zeros before any)."""

    def idle(self) -> None:
        """The master sent an idle (zero-length) poll."""

    def connection_lost(self, reason: str) -> None:
        """The polled connection timed out or was deleted while established."""


class RequestRefused(Exception):
    """Internal: answer the request with this CIP status."""

    def __init__(self, status: CipStatus, why: str) -> None:
        self.status = status
        super().__init__(why)


@dataclass(slots=True)
class Connection:
    instance: ConnectionInstance
    state: ConnectionState = ConnectionState.NON_EXISTENT
    epr_ms: int = 0
    watchdog_action: WatchdogAction = WatchdogAction.TRANSITION_TO_TIMED_OUT
    deadline: float | None = None

    def restart_timer(self, now: float) -> None:
        timeout = inactivity_timeout(self.epr_ms)
        self.deadline = None if timeout is None else now + timeout


@dataclass(slots=True)
class PendingResponse:
    fragmenter: Fragmenter
    deadline: float
    retries: int = FRAGMENT_RETRIES


@dataclass(slots=True)
class NodeCounters:
    polls: int = 0
    explicit_requests: int = 0
    error_responses: int = 0
    ignored_frames: int = 0
    bad_frames: int = 0


@dataclass(slots=True)
class CheckProgress:
    step: int = 0  # requests sent so far
    deadline: float = 0.0


@dataclass(slots=True)
class SlaveState:
    """The state of one DeviceNet slave (MAC ``mac``) in front of a :class:`SlaveApplication`."""

    mac: int
    app: SlaveApplication
    identity: Identity = field(default_factory=Identity)
    dup_mac_wait: float = DEFAULT_WAIT
    tick_ms: int = 10
    bitrate: int = 500000
    explicit_epr_ms: int = DEFAULT_EXPLICIT_EPR_MS
    state: NodeState = NodeState.OFFLINE
    allocation: int = 0
    master_mac: int = UNALLOCATED_MASTER
    counters: NodeCounters = field(default_factory=NodeCounters)
    events: list[tuple[float, str]] = field(default_factory=list)
    explicit: Connection = field(default_factory=lambda: Connection(ConnectionInstance.EXPLICIT))
    polled: Connection = field(default_factory=lambda: Connection(ConnectionInstance.POLLED))
    _check: CheckProgress = field(default_factory=CheckProgress)
    _reassembler: Reassembler = field(default_factory=Reassembler)
    _pending: PendingResponse | None = None
    _idle: bool = False
    _fault_reason: str = ""

    def _log(self, now: float, text: str) -> None:
        self.events.append((now, text))
        del self.events[:-200]

    @property
    def fault_reason(self) -> str:
        return self._fault_reason

    def current_identity(self) -> Identity:
        return self.identity.with_status(self.identity.status | (STATUS_OWNED if self.allocation else 0))

    def _release(self, choice: int, now: float, why: str) -> None:
        released = choice & self.allocation
        if not released:
            return
        if released & AllocationChoice.POLLED:
            if self.polled.state is ConnectionState.ESTABLISHED:
                self.app.connection_lost(f"DeviceNet polled I/O connection released ({why})")
            self.polled = Connection(ConnectionInstance.POLLED)
        if released & AllocationChoice.EXPLICIT:
            self.explicit = Connection(ConnectionInstance.EXPLICIT)
            self._pending = None
            self._reassembler.reset()
        self.allocation &= ~released & 0xFF
        if not self.allocation:
            self.master_mac = UNALLOCATED_MASTER
        self._log(now, f"released {describe_choice(released)}: {why}")
