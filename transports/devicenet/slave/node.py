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

from collections.abc import Callable

from starterbus.core import CanFrame
from starterbus.transports.devicenet.codec import cip
from starterbus.transports.devicenet.codec.assemblies import OUTPUT_SIZES
from starterbus.transports.devicenet.codec.cip import CipStatus, DeviceNetDecodeError, ObjectClass, Service
from starterbus.transports.devicenet.codec.connection import (
    AllocationChoice,
    ConnectionInstance,
    ConnectionState,
    WatchdogAction,
)
from starterbus.transports.devicenet.codec.dupmac import DuplicateMacCheck, decode_duplicate_mac
from starterbus.transports.devicenet.codec.explicit import (
    ErrorResponse,
    ExplicitResponse,
    decode_header,
    decode_request,
)
from starterbus.transports.devicenet.codec.fragmentation import (
    Fragmenter,
    FragmentOverflowError,
    decode_fragment,
    frames_for,
    is_fragment,
)
from starterbus.transports.devicenet.codec.ids import (
    duplicate_mac_id,
    explicit_request_id,
    explicit_response_id,
    poll_command_id,
    poll_response_id,
    unconnected_request_id,
)
from starterbus.transports.devicenet.slave.objects import SlaveObjects
from starterbus.transports.devicenet.slave.state import (
    FRAGMENT_ACK_TIMEOUT,
    FRAGMENT_RETRIES,
    CheckProgress,
    Connection,
    NodeState,
    PendingResponse,
    RequestRefused,
)

__all__ = ["SlaveNode"]


class SlaveNode(SlaveObjects):
    """One DeviceNet slave (MAC ``mac``) in front of a :class:`SlaveApplication`: the bus side."""

    __slots__ = ()

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

    # -- duplicate MAC ID check ---------------------------------------------------------------------------------

    def _dup_frame(self, response: bool) -> CanFrame:
        return DuplicateMacCheck(self.mac, response, self.identity.vendor_id, self.identity.serial_number).frame()

    def start(self, now: float) -> list[CanFrame]:
        """Begin the duplicate MAC ID check: the first request."""
        self.state = NodeState.CHECKING
        self._check = CheckProgress(1, now + self.dup_mac_wait)
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
                self._check = CheckProgress(2, self._check.deadline + self.dup_mac_wait)
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
        self._pending = PendingResponse(fragmenter, now + FRAGMENT_ACK_TIMEOUT)
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
