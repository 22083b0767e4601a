"""The DeviceNet master's view of one slave, and the master's own states, settings and errors.

Plain data for the sans-IO :class:`~starterbus.transports.devicenet.master.node.MasterNode`: nothing here
reads a clock, locks or touches a bus. The driver (:mod:`~starterbus.transports.devicenet.driver.scanner`) reads
these objects under its lock.
"""

from __future__ import annotations

import collections
import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

from starterbus.core import CanFrame, TransportError
from starterbus.transports.devicenet.codec.assemblies import AssemblySet, OutputAssembly
from starterbus.transports.devicenet.codec.connection import DEFAULT_EXPLICIT_EPR_MS, inactivity_timeout
from starterbus.transports.devicenet.codec.dupmac import DEFAULT_WAIT
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest, ExplicitResponse
from starterbus.transports.devicenet.codec.fragmentation import Fragmenter, Reassembler
from starterbus.transports.devicenet.codec.ids import poll_command_id

ANSWER_GUARD = 0.002  # seconds an answer waits for a second one (a duplicate responder) before it is published
KEEPALIVE = 2.5  # longest time between explicit keep-alive reads (the default inactivity timeout is 10 s)


class CommunicationFaultError(TransportError):
    """The master is in the DeviceNet communication faulted state (a duplicate MAC ID): nothing is sent."""


class DuplicateResponderError(TransportError):
    """Two answers to one poll command: another node answers for this slave's MAC id."""


class ScannerState(str, enum.Enum):
    CHECKING = "duplicate MAC ID check"
    ONLINE = "on line"
    FAULT = "communication fault"
    CLOSED = "closed"


class IoPhase(str, enum.Enum):
    """The polled I/O connection of a link: its output assembly carries the run bit, so holding it is control."""

    NONE = "not allocated (monitoring over explicit messaging)"
    TAKING = "allocating the polled I/O connection"
    HELD = "held (this master controls the starter)"
    RELEASING = "releasing the polled I/O connection"


class LinkState(str, enum.Enum):
    WAITING = "waiting for the scanner"
    ALLOCATING = "allocating"
    RELEASING = "releasing an old allocation"
    CONFIGURING = "configuring the connection"
    ESTABLISHED = "established"
    LOST = "lost (no answer)"
    REFUSED = "refused"
    FAULTED = "master in communication fault"
    CLOSED = "closed"


@dataclass(frozen=True, slots=True)
class ScannerConfig:
    interface: str
    channel: str
    master_mac: int = 0
    bitrate: int = 500000
    poll_period: float = 0.02  # default scan interval of a link whose LinkConfig gives none
    dup_mac_wait: float = DEFAULT_WAIT
    timeout: float = 1.0
    auto_reset: bool = True  # leave the communication fault by itself (with backoff)
    answer_guard: float = ANSWER_GUARD  # 0: publish answers at once (a rogue's first answer may get through)

    def conflicts(self, other: ScannerConfig) -> list[str]:
        names = ("master_mac", "bitrate", "dup_mac_wait")
        return [n for n in names if getattr(self, n) != getattr(other, n)]


@dataclass(frozen=True, slots=True)
class LinkConfig:
    mac: int
    assemblies: str = "auto"  # auto | basic | extended
    epr_ms: int = 100
    settle: int = 2  # poll responses with a new status parameter address before its value is trusted
    interval: float | None = None  # seconds between polls of this slave (None: the scanner's poll_period)
    #: allocate the polled I/O connection with the connection set (True) or only when :meth:`take_control`
    #: asks (False: monitoring over explicit messaging sends no output data, so it never moves a motor)
    io: bool = True
    input_instances: tuple[int, int] = (1, 101)  # the model's numbers of the basic and extended input assemblies
    product: str = "the device"  # the profile's name, for messages
    sets: str = "basic or extended"  # the model's assembly sets and their instance numbers, for messages


class InputSample(NamedTuple):
    """The latest input assembly of a slave (a tuple: built on every poll response, so kept cheap)."""

    data: bytes
    at: float  # receive time (the machine's clock)
    wall: float  # wall-clock time at receipt (the driver's; 0.0 in transcripts)
    select: int | None  # status parameter address the answered poll carried (extended)
    select_count: int  # consecutive responses to polls with this address, this one included
    seq: int  # output sequence number the answered poll carried


@dataclass(slots=True)
class Transaction:
    """One explicit request/response with a slave; ``done`` turns True with a response or an error."""

    request: ExplicitRequest
    unconnected: bool
    on_done: Callable[[Transaction, float], None] | None = None
    response: ExplicitResponse | None = None
    error: BaseException | None = None
    done: bool = False
    deadline: float = 0.0
    fragmenter: Fragmenter | None = None
    reassembler: Reassembler = field(default_factory=Reassembler)
    started: bool = False


class MasterLink:
    """The master's view of one slave: connection state, outputs to send, latest inputs."""

    def __init__(self, config: LinkConfig, where: str, interval: float) -> None:
        self.config = config
        self.mac = config.mac
        self.where = where
        self.interval = interval
        self.state = LinkState.WAITING
        self.assemblies: AssemblySet | None = None
        self.epr_ms = 0
        self.last_error: BaseException | None = None
        self.io = IoPhase.NONE
        self.io_error: BaseException | None = None  # why the latest take_control failed
        self.duplicate: DuplicateResponderError | None = None  # set while another node answers its polls
        self.failures = 0  # connection attempts that failed since the last success
        self.retry_at = 0.0
        self.established_at = 0.0
        self.events: collections.deque[tuple[float, str]] = collections.deque(maxlen=100)
        # outputs
        self.run = False
        self.reset = False
        self.select = 0x01
        self.output_seq = 0
        self.urgent = 0  # polls wanted as soon as possible (a read or command waits for them)
        # poll bookkeeping
        self.poll_data = b""
        self.poll_frame = CanFrame(poll_command_id(config.mac))  # the poll command of poll_data (built with it)
        self.built_seq = -1
        self.built_select: int | None = None
        self.sent_seq = 0
        self.sent_select: int | None = None
        self.next_poll_at = 0.0
        self.poll_deadline = 0.0
        self.awaiting = False  # a poll command is out, no answer yet
        self.queued = False  # due, waiting for a free slot in the window
        self.answers = 0  # answers to the latest poll command
        self.missed = 0  # polls in a row without an answer in time (their answers may still come, late)
        self.tolerate = 0  # this poll follows missed ones: that many extra (late) answers are no duplicate
        self.late = 0  # late answers recognised
        self.quarantine_until = 0.0  # no poll before this (a missed poll's answer may still come)
        self.last_answer = b""  # data of the latest answer taken (named when a second one comes)
        self.pending: InputSample | None = None  # first answer, published once no second one came
        self.confirm_at = 0.0
        self.clean_polls = 0  # consecutive polls with exactly one answer (to clear ``duplicate``)
        self.sample: InputSample | None = None
        self.acked_seq = -1
        self.responses = 0
        self.misses = 0
        self.duplicates = 0
        self.last_response_at = 0.0
        # explicit messaging
        self.transactions: collections.deque[Transaction] = collections.deque()
        self.xid = 0
        self.last_explicit_at = 0.0
        self.last_explicit_answer_at = 0.0
        self.explicit_inputs: tuple[bytes, float] | None = None  # the input assembly read at establishment
        self.explicit_epr_ms = DEFAULT_EXPLICIT_EPR_MS

    @property
    def keepalive(self) -> float:
        """Seconds between keep-alive reads: a third of the explicit connection's inactivity timeout, at most 2.5 s."""
        timeout = inactivity_timeout(self.explicit_epr_ms)
        return KEEPALIVE if timeout is None else min(KEEPALIVE, timeout / 3)

    def note(self, now: float, text: str) -> None:
        self.events.append((now, text))

    @property
    def established(self) -> bool:
        """The explicit connection is established (reads over explicit messaging work)."""
        return self.state is LinkState.ESTABLISHED

    @property
    def polling(self) -> bool:
        """The polled I/O connection is established too: this master polls the slave and controls it."""
        return self.state is LinkState.ESTABLISHED and self.io is IoPhase.HELD

    def output(self) -> OutputAssembly:
        bits = (0x01 if self.run else 0) | (0x04 if self.reset else 0)
        if self.assemblies is AssemblySet.BASIC:
            return OutputAssembly(2, bits)
        return OutputAssembly(102, bits, self.select)

    def describe(self) -> str:
        return f"MAC {self.mac} on {self.where}"
