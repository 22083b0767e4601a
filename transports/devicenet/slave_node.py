"""A Group 2 only DeviceNet slave as a sans-IO state machine: frames and times in, frames out.

:class:`SlaveNode` implements, for one MAC id, the duplicate MAC ID check, the Predefined Master/Slave
Connection Set (explicit + polled only, allocated through the group 2 only unconnected port), the Connection
objects' states, expected packet rates and inactivity watchdogs, fragmentation in both directions, and the
objects a master reads (Identity, DeviceNet, Assembly, Connection). What the I/O data mean is the
application's business (:class:`SlaveApplication`): the JJR8000 adapter lives in the simulator module.

Nothing here reads a clock or touches a bus: the driver calls :meth:`SlaveNode.start`, :meth:`handle` for
every frame and :meth:`tick` when :meth:`next_deadline` is due, passing the time, and sends what they return.

Decisions where the specification leaves room (documented in ``docs/devicenet.md``):

- Allocate from another master while allocated: 0x0C object state conflict, additional 0x01. Allocate of a
  connection already allocated to the same master, or Release of one not allocated: 0x0B already in requested
  mode, additional 0x02. Bit-strobe/multicast poll/COS/cyclic/acknowledge suppression: 0x02 resource
  unavailable, additional 0x02. Choice 0 or reserved bit 7: 0x20 invalid parameter, additional 0x02. Any other
  service on the group 2 only port: 0x08 service not supported, additional 0x03.
- The polled connection's watchdog moves it to "timed out" (the application is told: the JJR8000 soft-stops);
  poll commands are then ignored until the master releases and allocates again (Set EPR answers 0x0C).
- The explicit connection's watchdog (default EPR 2500 ms, so 10 s of silence) deletes it and with it the
  whole connection set, so a master that vanished does not keep the slave owned forever.
- A zero-length poll command is the master's "idle": the application is told once, the slave still answers.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from starterbus.transports.devicenet import cip
from starterbus.transports.devicenet.assemblies import INPUT_SIZES, OUTPUT_SIZES, AssemblySet
from starterbus.transports.devicenet.cip import (
    CipStatus,
    DeviceNetDecodeError,
    GeneralStatus,
    ObjectClass,
    Service,
)
from starterbus.transports.devicenet.connection import (
    BAUD_CODES,
    DEFAULT_EXPLICIT_EPR_MS,
    SUPPORTED_CHOICE,
    UNALLOCATED_MASTER,
    AllocationChoice,
    ConnectionAttribute,
    ConnectionInstance,
    ConnectionState,
    DeviceNetAttribute,
    WatchdogAction,
    assembly_path,
    describe_choice,
    inactivity_timeout,
    round_epr,
    uint,
)
from starterbus.transports.devicenet.dupmac import DEFAULT_WAIT, DuplicateMacCheck, decode_duplicate_mac
from starterbus.transports.devicenet.explicit import (
    ErrorResponse,
    ExplicitRequest,
    ExplicitResponse,
    decode_header,
    decode_request,
)
from starterbus.transports.devicenet.fragmentation import (
    Fragmenter,
    FragmentOverflowError,
    Reassembler,
    decode_fragment,
    frames_for,
    is_fragment,
)
from starterbus.transports.devicenet.frames import CanFrame
from starterbus.transports.devicenet.identity import STATUS_OWNED, Identity
from starterbus.transports.devicenet.ids import (
    duplicate_mac_id,
    explicit_request_id,
    explicit_response_id,
    poll_command_id,
    poll_response_id,
    unconnected_request_id,
)

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


def _const(data: bytes) -> Callable[[], bytes]:
    return lambda: data


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
class _PendingResponse:
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
class _Check:
    step: int = 0  # requests sent so far
    deadline: float = 0.0


@dataclass(slots=True)
class SlaveNode:
    """One DeviceNet slave (MAC ``mac``) in front of a :class:`SlaveApplication`."""

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
    _check: _Check = field(default_factory=_Check)
    _reassembler: Reassembler = field(default_factory=Reassembler)
    _pending: _PendingResponse | None = None
    _idle: bool = False
    _fault_reason: str = ""

    # -- wiring ------------------------------------------------------------------------------------------------

    def routes(self) -> dict[int, Callable[[bytes, float], list[CanFrame]]]:
        """The identifiers this node consumes and the handler of each (the driver dispatches on them)."""
        return {
            poll_command_id(self.mac): self._on_poll,
            explicit_request_id(self.mac): self._on_explicit,
            unconnected_request_id(self.mac): self._on_unconnected,
            duplicate_mac_id(self.mac): self._on_duplicate_mac,
        }

    def handle(self, frame: CanFrame, now: float) -> list[CanFrame]:
        """Any frame seen on the bus; those not for this node are ignored."""
        route = self.routes().get(frame.can_id)
        return route(frame.data, now) if route is not None else []

    def _log(self, now: float, text: str) -> None:
        self.events.append((now, text))
        del self.events[:-200]

    @property
    def fault_reason(self) -> str:
        return self._fault_reason

    # -- duplicate MAC ID check ---------------------------------------------------------------------------------

    def _dup_frame(self, response: bool) -> CanFrame:
        return DuplicateMacCheck(self.mac, response, self.identity.vendor_id, self.identity.serial_number).frame()

    def start(self, now: float) -> list[CanFrame]:
        """Begin the duplicate MAC ID check: the first request."""
        self.state = NodeState.CHECKING
        self._check = _Check(1, now + self.dup_mac_wait)
        self._log(now, f"duplicate MAC ID check started for MAC {self.mac}")
        return [self._dup_frame(False)]

    def _on_duplicate_mac(self, data: bytes, now: float) -> list[CanFrame]:
        try:
            message = decode_duplicate_mac(CanFrame(duplicate_mac_id(self.mac), data))
        except DeviceNetDecodeError as exc:
            self.counters.bad_frames += 1
            self._log(now, f"bad duplicate MAC ID frame ignored: {exc}")
            return []
        if self.state is NodeState.CHECKING:
            self._fault(now, f"duplicate MAC ID {self.mac} during the check: {message.describe()}")
            return []
        if self.state is NodeState.ONLINE:
            if message.response:
                self._fault(now, f"duplicate MAC ID {self.mac} while on line: {message.describe()}")
                return []
            return [self._dup_frame(True)]
        return []

    def _fault(self, now: float, why: str) -> None:
        self.state = NodeState.COMM_FAULT
        self._fault_reason = why
        self._log(now, why)
        self._release(AllocationChoice.EXPLICIT | AllocationChoice.POLLED, now, "communication fault")

    # -- timers ---------------------------------------------------------------------------------------------------

    def next_deadline(self) -> float | None:
        times = []
        if self.state is NodeState.CHECKING:
            times.append(self._check.deadline)
        for conn in (self.explicit, self.polled):
            if conn.deadline is not None and conn.state is ConnectionState.ESTABLISHED:
                times.append(conn.deadline)
        if self._pending is not None:
            times.append(self._pending.deadline)
        return min(times) if times else None

    def tick(self, now: float) -> list[CanFrame]:
        out: list[CanFrame] = []
        while self.state is NodeState.CHECKING and now >= self._check.deadline:
            if self._check.step == 1:
                self._check = _Check(2, self._check.deadline + self.dup_mac_wait)
                out.append(self._dup_frame(False))
            else:
                self.state = NodeState.ONLINE
                self._log(now, f"on line as MAC {self.mac}")
        if self.state is not NodeState.ONLINE:
            return out
        if self._pending is not None and now >= self._pending.deadline:
            pending = self._pending
            if pending.retries > 0:
                pending.retries -= 1
                pending.deadline = now + FRAGMENT_ACK_TIMEOUT
                out.append(CanFrame(explicit_response_id(self.mac), pending.fragmenter.current))
            else:
                self._pending = None
                self._log(now, "fragmented response abandoned: no acknowledgement")
        polled = self.polled
        if polled.state is ConnectionState.ESTABLISHED and polled.deadline is not None and now >= polled.deadline:
            self._watchdog(polled, now)
        explicit = self.explicit
        if explicit.state is ConnectionState.ESTABLISHED and explicit.deadline is not None and now >= explicit.deadline:
            self._watchdog(explicit, now)
        return out

    def _watchdog(self, conn: Connection, now: float) -> None:
        action = conn.watchdog_action
        name = "explicit" if conn.instance is ConnectionInstance.EXPLICIT else "polled I/O"
        timeout_ms = conn.epr_ms * 4
        if action is WatchdogAction.AUTO_RESET:
            conn.restart_timer(now)
            self._log(now, f"{name} connection inactivity ({timeout_ms} ms): auto reset")
            return
        if action is WatchdogAction.TRANSITION_TO_TIMED_OUT:
            conn.state = ConnectionState.TIMED_OUT
            conn.deadline = None
            self._log(now, f"{name} connection timed out (no message for {timeout_ms} ms)")
            if conn.instance is ConnectionInstance.POLLED:
                self.app.connection_lost(f"DeviceNet polled I/O connection timed out ({timeout_ms} ms)")
            return
        # auto delete / deferred delete
        if conn.instance is ConnectionInstance.EXPLICIT:
            self._log(now, f"explicit connection deleted after {timeout_ms} ms of silence: connection set released")
            self._release(AllocationChoice.EXPLICIT | AllocationChoice.POLLED, now, "explicit connection timed out")
        else:
            self._log(now, f"polled I/O connection deleted after {timeout_ms} ms of silence")
            self._release(AllocationChoice.POLLED, now, "polled connection timed out (auto delete)")

    # -- I/O --------------------------------------------------------------------------------------------------

    def _on_poll(self, data: bytes, now: float) -> list[CanFrame]:
        response = self.poll(data, now)
        return [] if response is None else [CanFrame(poll_response_id(self.mac), response)]

    def poll(self, data: bytes, now: float) -> bytes | None:
        """A poll command's data in, the poll response's data out (None: no response). The driver's fast path."""
        polled = self.polled
        if self.state is not NodeState.ONLINE or polled.state is not ConnectionState.ESTABLISHED:
            self.counters.ignored_frames += 1
            return None
        assemblies = self.app.assembly_set()
        if data:
            if len(data) != OUTPUT_SIZES[assemblies.output_instance]:
                self.counters.bad_frames += 1
                self._log(now, f"poll command of {len(data)} bytes ignored (consumed size {assemblies.output_size})")
                return None
            if self._idle:
                self._idle = False
                self._log(now, "master active again")
            self.app.consume(assemblies.output_instance, data)
        elif not self._idle:
            self._idle = True
            self._log(now, "master idle (zero-length poll command)")
            self.app.idle()
        if polled.epr_ms:
            polled.deadline = now + polled.epr_ms * 0.004  # 4 x EPR
        self.counters.polls += 1
        return self.app.produce(assemblies.input_instance)

    # -- explicit messaging ------------------------------------------------------------------------------------

    def _respond(self, message: bytes, now: float) -> list[CanFrame]:
        response_id = explicit_response_id(self.mac)
        frames = frames_for(message)
        if len(frames) == 1:
            self._pending = None
            return [CanFrame(response_id, frames[0])]
        fragmenter = Fragmenter(message)
        self._pending = _PendingResponse(fragmenter, now + FRAGMENT_ACK_TIMEOUT)
        return [CanFrame(response_id, fragmenter.current)]

    def _on_explicit(self, data: bytes, now: float) -> list[CanFrame]:
        """Group 2 message id 4: requests (and fragment acknowledgements) on the explicit connection."""
        if self.state is not NodeState.ONLINE or self.explicit.state is not ConnectionState.ESTABLISHED:
            self.counters.ignored_frames += 1
            return []
        if not data:
            self.counters.bad_frames += 1
            return []
        if decode_header(data[0]).mac != self.master_mac:
            self.counters.ignored_frames += 1
            self._log(
                now, f"explicit frame from MAC {data[0] & 0x3F} ignored (connection belongs to {self.master_mac})"
            )
            return []
        self.explicit.restart_timer(now)
        message = data
        if is_fragment(data):
            try:
                fragment = decode_fragment(data)
                if fragment.is_ack:
                    return self._on_ack(data, now)
                reply, whole = self._reassembler.feed(data)
            except FragmentOverflowError as exc:
                self.counters.bad_frames += 1
                self._log(now, f"fragmented request refused: {exc}")
                return [CanFrame(explicit_response_id(self.mac), exc.ack)]
            except DeviceNetDecodeError as exc:
                self.counters.bad_frames += 1
                self._log(now, f"fragment dropped: {exc}")
                return []
            out = [CanFrame(explicit_response_id(self.mac), reply)]
            if whole is None:
                return out
            message = whole
            return out + self._serve(message, now, unconnected=False)
        return self._serve(message, now, unconnected=False)

    def _on_ack(self, data: bytes, now: float) -> list[CanFrame]:
        pending = self._pending
        if pending is None:
            self.counters.ignored_frames += 1
            return []
        try:
            following = pending.fragmenter.on_ack(data)
        except DeviceNetDecodeError as exc:
            self._pending = None
            self._log(now, f"fragmented response aborted: {exc}")
            return []
        if pending.fragmenter.done:
            self._pending = None
            return []
        if following is None:
            return []
        pending.deadline = now + FRAGMENT_ACK_TIMEOUT
        pending.retries = FRAGMENT_RETRIES
        return [CanFrame(explicit_response_id(self.mac), following)]

    def _on_unconnected(self, data: bytes, now: float) -> list[CanFrame]:
        """Group 2 message id 6: the group 2 only unconnected explicit request port (Allocate/Release only)."""
        if self.state is not NodeState.ONLINE:
            self.counters.ignored_frames += 1
            return []
        if is_fragment(data):
            self.counters.bad_frames += 1
            self._log(now, "fragmented frame on the group 2 only port ignored (the port does not fragment)")
            return []
        return self._serve(data, now, unconnected=True)

    def _serve(self, message: bytes, now: float, *, unconnected: bool) -> list[CanFrame]:
        if len(message) < 2:
            self.counters.bad_frames += 1
            self._log(now, f"explicit message of {len(message)} byte(s) ignored (no service byte)")
            return []
        header = decode_header(message[0])
        self.counters.explicit_requests += 1
        try:
            request = decode_request(message)
            if unconnected and (
                request.service not in (Service.ALLOCATE, Service.RELEASE) or request.class_id != ObjectClass.DEVICENET
            ):
                raise RequestRefused(cip.GROUP2_ONLY_SERVICE, f"{request.describe()} on the group 2 only port")
            data = self._dispatch(request, now)
        except DeviceNetDecodeError as exc:
            return self._error(header.mac, header.xid, exc.status, str(exc), now)
        except RequestRefused as exc:
            return self._error(header.mac, header.xid, exc.status, str(exc), now)
        frames = self._respond(ExplicitResponse(header.mac, request.service, data, header.xid).encode(), now)
        if request.service == Service.RESET and request.class_id == ObjectClass.IDENTITY:
            self._release(AllocationChoice.EXPLICIT | AllocationChoice.POLLED, now, "identity reset")
        return frames

    def _error(self, mac: int, xid: int, status: CipStatus, why: str, now: float) -> list[CanFrame]:
        self.counters.error_responses += 1
        self._log(now, f"error response {status.describe()}: {why}")
        return self._respond(ErrorResponse(mac, status, xid).encode(), now)

    # -- objects --------------------------------------------------------------------------------------------------

    def _dispatch(self, request: ExplicitRequest, now: float) -> bytes:
        handlers: dict[int, Callable[[ExplicitRequest, float], bytes]] = {
            ObjectClass.IDENTITY: self._identity,
            ObjectClass.MESSAGE_ROUTER: self._message_router,
            ObjectClass.DEVICENET: self._devicenet,
            ObjectClass.ASSEMBLY: self._assembly,
            ObjectClass.CONNECTION: self._connection,
        }
        handler = handlers.get(request.class_id)
        if handler is None:
            raise RequestRefused(
                CipStatus(GeneralStatus.PATH_DESTINATION_UNKNOWN), f"no object class 0x{request.class_id:02X}"
            )
        return handler(request, now)

    @staticmethod
    def _unsupported(request: ExplicitRequest) -> RequestRefused:
        return RequestRefused(
            CipStatus(GeneralStatus.SERVICE_NOT_SUPPORTED), f"{cip.service_name(request.service)} not supported here"
        )

    @staticmethod
    def _no_instance(request: ExplicitRequest) -> RequestRefused:
        return RequestRefused(
            CipStatus(GeneralStatus.OBJECT_DOES_NOT_EXIST),
            f"{cip.class_name(request.class_id)} has no instance {request.instance}",
        )

    @staticmethod
    def _no_attribute(request: ExplicitRequest) -> RequestRefused:
        return RequestRefused(
            CipStatus(GeneralStatus.ATTRIBUTE_NOT_SUPPORTED),
            f"{cip.class_name(request.class_id)} instance {request.instance} has no attribute {request.attribute}",
        )

    @staticmethod
    def _no_data(request: ExplicitRequest) -> None:
        if request.data:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), f"{request.describe()} carries extra data")

    def _get(self, request: ExplicitRequest, attributes: dict[int, Callable[[], bytes]]) -> bytes:
        """Get_Attribute_Single / Set_Attribute_Single against a table of readable attributes."""
        if request.service == Service.GET_ATTRIBUTE_SINGLE:
            self._no_data(request)
            getter = attributes.get(request.attribute or 0)
            if getter is None:
                raise self._no_attribute(request)
            return getter()
        if request.service == Service.SET_ATTRIBUTE_SINGLE:
            if (request.attribute or 0) in attributes:
                raise RequestRefused(
                    CipStatus(GeneralStatus.ATTRIBUTE_NOT_SETTABLE), f"attribute {request.attribute} is read-only"
                )
            raise self._no_attribute(request)
        raise self._unsupported(request)

    def current_identity(self) -> Identity:
        return self.identity.with_status(self.identity.status | (STATUS_OWNED if self.allocation else 0))

    def _identity(self, request: ExplicitRequest, now: float) -> bytes:
        if request.instance == 0:
            return self._get(request, {1: lambda: uint(1), 2: lambda: uint(1)})
        if request.instance != 1:
            raise self._no_instance(request)
        identity = self.current_identity()
        if request.service == Service.GET_ATTRIBUTES_ALL:
            self._no_data(request)
            return identity.attributes_all()
        if request.service == Service.RESET:
            if len(request.data) > 1:
                raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "Reset takes at most one type byte")
            if request.data and request.data[0] != 0:
                raise RequestRefused(
                    CipStatus(GeneralStatus.INVALID_PARAMETER), f"reset type {request.data[0]} is not supported"
                )
            return b""
        table = {n: _const(encoded) for n in range(1, 8) if (encoded := identity.attribute(n)) is not None}
        return self._get(request, table)

    def _message_router(self, request: ExplicitRequest, now: float) -> bytes:
        if request.instance not in (0, 1):
            raise self._no_instance(request)
        return self._get(request, {})

    def _devicenet(self, request: ExplicitRequest, now: float) -> bytes:
        if request.service in (Service.ALLOCATE, Service.RELEASE):
            if request.instance != 1:
                raise self._no_instance(request)
            if request.service == Service.ALLOCATE:
                return self._allocate(request, now)
            return self._release_request(request, now)
        if request.instance == 0:
            return self._get(request, {1: lambda: uint(2)})
        if request.instance != 1:
            raise self._no_instance(request)
        return self._get(
            request,
            {
                DeviceNetAttribute.MAC_ID: lambda: bytes((self.mac,)),
                DeviceNetAttribute.BAUD_RATE: lambda: bytes((BAUD_CODES.get(self.bitrate, 2),)),
                DeviceNetAttribute.BUS_OFF_INTERRUPT: lambda: b"\x00",
                DeviceNetAttribute.BUS_OFF_COUNTER: lambda: b"\x00",
                DeviceNetAttribute.ALLOCATION_INFORMATION: lambda: bytes((self.allocation, self.master_mac)),
            },
        )

    def _assembly(self, request: ExplicitRequest, now: float) -> bytes:
        instance = request.instance
        if instance == 0:
            return self._get(request, {1: lambda: uint(2), 2: lambda: uint(102)})
        if instance in INPUT_SIZES:
            return self._get(request, {3: lambda: self.app.produce(instance)})
        if instance in OUTPUT_SIZES:
            return self._get(request, {3: lambda: self.app.output_data(instance)})
        raise self._no_instance(request)

    # -- allocation ---------------------------------------------------------------------------------------------

    def _check_choice(self, request: ExplicitRequest, choice: int) -> None:
        if choice == 0 or choice & AllocationChoice.RESERVED:
            raise RequestRefused(cip.INVALID_CHOICE, f"choice 0x{choice:02X} ({describe_choice(choice)})")
        unsupported = choice & ~int(SUPPORTED_CHOICE) & 0xFF
        if unsupported:
            raise RequestRefused(
                cip.UNSUPPORTED_CONNECTION,
                f"{describe_choice(unsupported)} not supported (the JJR8000 offers polled and explicit only)",
            )

    def _allocate(self, request: ExplicitRequest, now: float) -> bytes:
        if len(request.data) < 2:
            raise RequestRefused(CipStatus(GeneralStatus.NOT_ENOUGH_DATA), "Allocate needs choice and allocator MAC")
        if len(request.data) > 2:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "Allocate takes choice and allocator MAC")
        choice, allocator = request.data[0], request.data[1]
        self._check_choice(request, choice)
        if allocator > 63:
            raise RequestRefused(CipStatus(GeneralStatus.INVALID_PARAMETER), f"allocator MAC {allocator} > 63")
        if self.allocation and self.master_mac != allocator:
            raise RequestRefused(
                cip.ALLOCATED_TO_ANOTHER_MASTER, f"allocated to master {self.master_mac}, requested by {allocator}"
            )
        if choice & self.allocation:
            raise RequestRefused(
                cip.ALREADY_ALLOCATED, f"{describe_choice(choice & self.allocation)} already allocated to {allocator}"
            )
        self.allocation |= choice
        self.master_mac = allocator
        if choice & AllocationChoice.EXPLICIT:
            self.explicit = Connection(
                ConnectionInstance.EXPLICIT,
                ConnectionState.ESTABLISHED,
                round_epr(self.explicit_epr_ms, self.tick_ms),
                WatchdogAction.AUTO_DELETE,
            )
            self.explicit.restart_timer(now)
        if choice & AllocationChoice.POLLED:
            self.polled = Connection(ConnectionInstance.POLLED, ConnectionState.CONFIGURING)
            self._idle = False
        self._log(now, f"allocated {describe_choice(choice)} to master {allocator}")
        return b"\x00"  # message body format 0: DeviceNet 8/8

    def _release_request(self, request: ExplicitRequest, now: float) -> bytes:
        if not request.data:
            raise RequestRefused(CipStatus(GeneralStatus.NOT_ENOUGH_DATA), "Release needs a choice byte")
        if len(request.data) > 1:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "Release takes one choice byte")
        choice = request.data[0]
        self._check_choice(request, choice)
        if self.allocation and request.mac != self.master_mac:
            raise RequestRefused(
                cip.ALLOCATED_TO_ANOTHER_MASTER, f"allocated to master {self.master_mac}, release from {request.mac}"
            )
        if choice & ~self.allocation & 0xFF:
            raise RequestRefused(cip.NOT_ALLOCATED, f"{describe_choice(choice & ~self.allocation)} not allocated")
        self._release(choice, now, f"released by master {request.mac}")
        return b""

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

    # -- connection objects -------------------------------------------------------------------------------------

    def _connection(self, request: ExplicitRequest, now: float) -> bytes:
        if request.instance == 0:
            return self._get(request, {1: lambda: uint(1)})
        if request.instance == ConnectionInstance.EXPLICIT:
            conn = self.explicit
        elif request.instance == ConnectionInstance.POLLED:
            conn = self.polled
        else:
            raise self._no_instance(request)
        if conn.state is ConnectionState.NON_EXISTENT:
            raise self._no_instance(request)
        attribute = request.attribute or 0
        if request.service == Service.SET_ATTRIBUTE_SINGLE and attribute == ConnectionAttribute.EXPECTED_PACKET_RATE:
            return self._set_epr(conn, request, now)
        if request.service == Service.SET_ATTRIBUTE_SINGLE and attribute == ConnectionAttribute.WATCHDOG_TIMEOUT_ACTION:
            if len(request.data) != 1:
                status = GeneralStatus.NOT_ENOUGH_DATA if not request.data else GeneralStatus.TOO_MUCH_DATA
                raise RequestRefused(CipStatus(status), "watchdog action is one USINT")
            if request.data[0] > WatchdogAction.DEFERRED_DELETE:
                raise RequestRefused(
                    CipStatus(GeneralStatus.INVALID_ATTRIBUTE_VALUE), f"watchdog action {request.data[0]} is not 0-3"
                )
            conn.watchdog_action = WatchdogAction(request.data[0])
            return b""
        return self._get(request, self._connection_attributes(conn))

    def _set_epr(self, conn: Connection, request: ExplicitRequest, now: float) -> bytes:
        if len(request.data) < 2:
            raise RequestRefused(CipStatus(GeneralStatus.NOT_ENOUGH_DATA), "expected packet rate is a UINT")
        if len(request.data) > 2:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "expected packet rate is a UINT")
        if conn.state is ConnectionState.TIMED_OUT:
            raise RequestRefused(
                CipStatus(GeneralStatus.OBJECT_STATE_CONFLICT), "connection timed out: release and allocate again"
            )
        requested = int.from_bytes(request.data, "little")
        conn.epr_ms = round_epr(requested, self.tick_ms)
        if conn.state is ConnectionState.CONFIGURING:
            conn.state = ConnectionState.ESTABLISHED
            self._log(now, f"polled I/O connection established, expected packet rate {conn.epr_ms} ms")
        conn.restart_timer(now)
        return uint(conn.epr_ms)

    def _connection_attributes(self, conn: Connection) -> dict[int, Callable[[], bytes]]:
        explicit = conn.instance is ConnectionInstance.EXPLICIT
        assemblies = self.app.assembly_set()
        if explicit:
            produced_id, consumed_id = explicit_response_id(self.mac), explicit_request_id(self.mac)
            sizes = (EXPLICIT_CONNECTION_SIZE, EXPLICIT_CONNECTION_SIZE)
            paths = (b"", b"")
        else:
            produced_id, consumed_id = poll_response_id(self.mac), poll_command_id(self.mac)
            sizes = (assemblies.input_size, assemblies.output_size)
            paths = (assembly_path(assemblies.input_instance), assembly_path(assemblies.output_instance))
        return {
            ConnectionAttribute.STATE: lambda: bytes((int(conn.state),)),
            ConnectionAttribute.INSTANCE_TYPE: lambda: b"\x00" if explicit else b"\x01",
            ConnectionAttribute.TRANSPORT_CLASS_TRIGGER: lambda: b"\x83" if explicit else b"\x82",
            ConnectionAttribute.PRODUCED_CONNECTION_ID: lambda: uint(produced_id),
            ConnectionAttribute.CONSUMED_CONNECTION_ID: lambda: uint(consumed_id),
            ConnectionAttribute.INITIAL_COMM_CHARACTERISTICS: lambda: b"\x21" if explicit else b"\x01",
            ConnectionAttribute.PRODUCED_CONNECTION_SIZE: lambda: uint(sizes[0]),
            ConnectionAttribute.CONSUMED_CONNECTION_SIZE: lambda: uint(sizes[1]),
            ConnectionAttribute.EXPECTED_PACKET_RATE: lambda: uint(conn.epr_ms),
            ConnectionAttribute.WATCHDOG_TIMEOUT_ACTION: lambda: bytes((int(conn.watchdog_action),)),
            ConnectionAttribute.PRODUCED_CONNECTION_PATH_LENGTH: lambda: uint(len(paths[0])),
            ConnectionAttribute.PRODUCED_CONNECTION_PATH: lambda: paths[0],
            ConnectionAttribute.CONSUMED_CONNECTION_PATH_LENGTH: lambda: uint(len(paths[1])),
            ConnectionAttribute.CONSUMED_CONNECTION_PATH: lambda: paths[1],
            ConnectionAttribute.PRODUCTION_INHIBIT_TIME: lambda: uint(0),
        }
