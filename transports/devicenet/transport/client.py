"""The ``devicenet`` transport: one slave (the profile's model), scanned by the process-wide scanner of its bus.

URL: ``devicenet://INTERFACE/CHANNEL?mac=5`` with any python-can interface (``virtual``, ``socketcan``,
``pcan``, ``remote`` for the loopback bridge, ...) and these parameters:

=============== ========= ================================================================================
``mac``         required  slave MAC id (1-63)
``master_mac``  0         the scanner's own MAC id (0-63)
``bitrate``     500000    125000, 250000 or 500000 (software interfaces ignore it)
``assemblies``  auto      ``basic`` (1/2), ``extended`` (101/102) or ``auto`` (from the polled connection sizes)
``epr``         100       expected packet rate of the polled connection, ms (inactivity timeout = 4 x EPR)
``period``      none      seconds between fresh inputs the caller needs (e.g. a fleet's poll period): the
                          scan interval follows it (at least 0.005 s, at most 1 s) and so does the expected
                          packet rate (2 x the interval, at least 100 ms); not with ``poll``
``poll``        20        scan interval, ms (0: as fast as possible); at most ``epr``
``dup_mac_wait`` 1.0      seconds of each wait of the scanner's duplicate MAC ID check (the spec says 1 s)
``timeout``     1.0       seconds to wait for an explicit response, a command or fresh inputs
``settle``      2         poll responses after a new status parameter address before its value is used
``control``     command   when to allocate the polled I/O connection, whose output assembly carries the run
                          bit: ``command`` (only to send a command; reads use explicit messaging and send no
                          output data) or ``open`` (at open, refused while the motor runs: then every status
                          parameter can be read, and this master controls the starter)
=============== ========= ================================================================================

Reading never moves a motor: until a command is sent (or with ``control=open``), the master allocates the
explicit connection only and reads the input assembly with Get_Attribute_Single (class 4, attribute 3). The
polled I/O connection is allocated by the first command (its first poll carries that command) and released
again once a command left the run bit clear (``control=command``).

Scanner-wide parameters (``master_mac``, ``bitrate``, ``dup_mac_wait``) must agree between the
devices of one bus in one process. Parameters cannot be read or written (the manual: not supported).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from starterbus.core import (
    CW_RESET,
    CW_START,
    Capability,
    Command,
    ControlWordState,
    PlannedRequest,
    PointDef,
    PollResult,
    PollTask,
    Reading,
    Status,
    TimeoutError,
)
from starterbus.transports.devicenet.codec.assemblies import (
    CURRENT_RESOLUTION_A,
    AssemblySet,
    OutputAssembly,
    decode_input,
    output_for_word,
)
from starterbus.transports.devicenet.codec.cip import ObjectClass, Service
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest
from starterbus.transports.devicenet.codec.identity import ATTRIBUTE_NAMES, decode_identity
from starterbus.transports.devicenet.codec.ids import poll_command_id
from starterbus.transports.devicenet.driver.poll import DeviceNetPoll, Steps
from starterbus.transports.devicenet.driver.scanner import Scanner, SlaveLink
from starterbus.transports.devicenet.master.sequence import input_request
from starterbus.transports.devicenet.transport.link import SCANNERS, ControlConflictError, LinkTransport
from starterbus.transports.devicenet.url import NAME

__all__ = ["SCANNERS", "ControlConflictError", "DeviceNetTransport"]


class DeviceNetTransport(LinkTransport):
    name = NAME
    #: polled I/O: the slave's watchdog stops the motor when the master lets the connection go
    run_needs_connection = True

    def _read_status(self) -> Status:
        scanner, link = self._require()
        self._retake(scanner, link, strict=False)
        if not link.polling:
            inputs = self._explicit_inputs(scanner, link)
            return inputs.to_status(self.profile, timestamp=time.time(), source=NAME)
        sample = self._fresh_sample(link, scanner)
        assemblies = link.assemblies or AssemblySet.EXTENDED
        inputs = decode_input(sample.data, assemblies.input_instance)
        timestamp = scanner.wall_time(sample.at)
        return inputs.to_status(self.profile, selected_address=sample.select, timestamp=timestamp, source=NAME)

    # -- commands --------------------------------------------------------------------------------------------------

    def _words(self, command: Command, run: bool) -> list[int]:
        if command in (Command.TAKE_BUS_CONTROL, Command.RELEASE_BUS_CONTROL):
            raise self.unsupported(
                f"send the command {command.value!r}",
                "the output assemblies have no bus-control bit (DeviceNet is the network control path: the slave "
                "sets control word bit 3 itself)",
            )
        return ControlWordState(bus_control=True, run=run).apply(command)

    def _send_command(self, command: Command) -> None:
        scanner, link = self._require()
        words = self._words(command, link.run)
        error = scanner.link_error(link)
        if error is not None:
            raise error
        if not link.established:
            raise TimeoutError(f"{self.describe()}: connection {link.state.value}; command {command.value!r} not sent")
        for index, word in enumerate(words):
            taking = not link.polling
            if taking and command is Command.FAULT_RESET:  # its run = 0 would stop a motor run from elsewhere
                self._refuse_conflict(scanner, link, "a fault reset")
            # set before the polled connection exists, the outputs go out with its very first poll
            seq = scanner.set_outputs(link, run=bool(word & CW_START), reset=bool(word & CW_RESET))
            if taking and not link.polling:
                try:
                    scanner.take_control(link, 4 * self.timeout)
                except BaseException:
                    scanner.set_outputs(link, run=False, reset=False)  # not sent: nothing of ours runs
                    raise
            if not scanner.wait_acked(link, seq, self.timeout):
                error = scanner.link_error(link)
                if error is not None:
                    raise error
                raise TimeoutError(
                    f"{self.describe()}: command {command.value!r} was not confirmed by a poll response within "
                    f"{self.timeout:g} s (connection {link.state.value}; word {index + 1} of {len(words)})"
                )
        if self.control == "command" and not link.run:
            scanner.release_control(link)  # nothing of ours runs: give control back, monitor again

    def _preview_command(self, command: Command) -> list[str]:
        """The frames of a command: the poll commands carrying its words; on a monitored slave (an open link
        without the polled I/O connection) first the explicit requests that allocate it (a fault reset reads the
        input assembly before: no control is taken while a motor runs under another), and with ``control=command``
        the release once the last word leaves the run bit clear. A device not opened: the poll commands only."""
        link = self.link
        run = link.run if link is not None else False
        assemblies = (link.assemblies if link is not None else None) or (
            AssemblySet.BASIC if self.link_config.assemblies == "basic" else AssemblySet.EXTENDED
        )
        select = link.select if link is not None else 0x01
        words = self._words(command, run)
        polls = []
        for word in words:
            output: OutputAssembly = output_for_word(word, assemblies.output_instance, select)
            polls.append(f"{poll_command_id(self.link_config.mac):03X}#{output.encode().hex().upper()}")
        if link is None or not link.established:
            return polls
        machine = self._require()[0].machine
        taking = not link.polling
        before = (
            [(False, input_request(machine, link, assemblies))] if taking and command is Command.FAULT_RESET else []
        )
        if taking:
            before += machine.control_requests(link)
        releasing = self.control == "command" and not words[-1] & CW_START
        after = machine.control_requests(link, release=True) if releasing else []
        first = [frame.text() for frame in machine.preview_frames(link, before)]
        last = [frame.text() for frame in machine.preview_frames(link, after, queued=len(before))]
        return first + polls + last

    def _why_not(self, capability: Capability) -> str:
        if capability in (Capability.READ_PARAMETERS, Capability.WRITE_PARAMETERS):
            return f"the {self.profile.display_name} does not support parameter access over DeviceNet"
        return super()._why_not(capability)

    # -- measurements ------------------------------------------------------------------------------------------

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        scanner, link = self._require()
        self._retake(scanner, link, strict=True)
        return [self._read_measurement(scanner, link, point) for point in points]

    @property
    def _l1(self) -> str | None:
        """The key of the L1 current, the one measurement the input assembly carries (None: the model has none)."""
        phases = self.profile.phase_currents()
        return phases[0].key if phases else None

    def read_refusal(self, point: PointDef) -> str | None:
        """Monitoring (``control=command``) reads the input assembly only: the status and the L1 current."""
        if self.control == "open" or point.key == self._l1:
            return None
        return (
            "the status parameters travel only in the polled I/O connection, whose output assembly also carries "
            "the run bit; reading never takes control: send a command first in this session, open with "
            "control=open (refused while the motor runs under another control), or read it over another "
            "transport; the input assembly (explicit messaging) carries the status and the L1 current"
        )

    def _read_measurement(self, scanner: Scanner, link: SlaveLink, point: PointDef) -> Reading:
        l1 = self._l1
        if not link.polling:
            refusal = self.read_refusal(point)
            if refusal is not None:
                raise self.unsupported(f"read {point.key}", refusal)
            if point.key == l1:
                return Reading(point, self._explicit_inputs(scanner, link).current_a, CURRENT_RESOLUTION_A)
        if link.assemblies is AssemblySet.BASIC:
            if point.key == l1:
                sample = self._fresh_sample(link, scanner)
                return Reading(point, decode_input(sample.data, 1).current_a, CURRENT_RESOLUTION_A)
            raise self._basic_refusal(point)
        address = point.address_for(NAME)
        if address is None or not 0 <= address <= 0xFF:
            raise self.unsupported(f"read {point.key}", "it has no DeviceNet status parameter address")
        with self._select_lock:
            return scanner.drive(self._status_parameter_steps(scanner, link, point, address))

    # -- polls ---------------------------------------------------------------------------------------------------

    def _monitors(self, points: Sequence[PointDef]) -> bool:
        """A poll of these points is one explicit read of the input assembly: this master monitors (no polled
        connection, ``control=command``) and they are at most the L1 current."""
        link, l1 = self.link, self._l1
        monitoring = self.control == "command" and (link is None or not link.polling)
        return monitoring and all(point.key == l1 for point in points)

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        """Monitoring, the status and the L1 current from one explicit read, as the poll task does."""
        if self._monitors(points) and (status or points):
            scanner, link = self._require()
            result: PollResult = scanner.drive(self._poll_steps(scanner, link, points, status, {}))
            return result
        return super()._poll(points, status)

    def plan(self, points: Sequence[PointDef], status: bool) -> list[PlannedRequest]:
        """Monitoring: one explicit read of the input assembly (the status and the L1 current)."""
        if not self._monitors(points):
            return super().plan(points, status)
        what = (["status"] if status else []) + [point.key for point in points]
        if not what:
            return []
        return [PlannedRequest(f"read the input assembly (explicit messaging): {', '.join(what)}", len(what))]

    # -- the fleet's poll without blocking ------------------------------------------------------------------------

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        """The poll as tickets: monitoring, the status and the L1 current from one explicit read of the input
        assembly; while this master polls, the latest fresh sample and each status parameter selected in turn.
        With ``control=open`` and the polled connection lost, the poll first takes control again as the blocking
        path does (refused while a motor runs under another control: then the status is monitored and points
        fail). What the blocking path refuses polls by blocking (None), which raises its message."""
        scanner, link = self._require()
        l1 = self._l1
        if self.control == "open" and not link.polling:
            if any(point.key != l1 and not _has_address(point) for point in points):
                return None  # refused by the blocking path, with its message
            return DeviceNetPoll(scanner, self._retake_poll_steps(scanner, link, points, status, l1))
        if not link.polling or link.assemblies is AssemblySet.BASIC:
            if any(point.key != l1 for point in points):
                return None  # refused by the blocking path, with its message
            return DeviceNetPoll(scanner, self._poll_steps(scanner, link, points, status, {}))
        if not all(_has_address(point) for point in points):
            return None  # refused by the blocking path, with its message
        addresses = {point.key: _address(point) for point in points}
        return DeviceNetPoll(scanner, self._poll_steps(scanner, link, points, status, addresses))

    def _retake_poll_steps(
        self, scanner: Scanner, link: SlaveLink, points: Sequence[PointDef], status: bool, l1: str | None
    ) -> Steps:
        """``control=open`` after a loss: take control again (points refused while a motor runs under another
        control, as ``_read_points`` does), then the poll of the state that left."""
        yield from self._retake_steps(scanner, link, strict=bool(points))
        addresses: dict[str, int] = {}
        if link.polling and link.assemblies is not AssemblySet.BASIC:
            addresses = {point.key: _address(point) for point in points}
        elif link.polling:
            for point in points:
                if point.key != l1:
                    raise self._basic_refusal(point)
        result: PollResult = yield from self._poll_steps(scanner, link, points, status, addresses)
        return result

    def _poll_steps(
        self,
        scanner: Scanner,
        link: SlaveLink,
        points: Sequence[PointDef],
        status: bool,
        addresses: dict[str, int],
    ) -> Steps:
        """``addresses``: the status parameter of each point (extended assemblies, this master polling); none:
        the points are the L1 current of the input assembly. Without the select lock of the blocking path: a
        concurrent select on the link can only make this one time out (its answers are counted by address)."""
        value: Status | None = None
        if not link.polling:
            inputs = yield from self._explicit_steps(scanner, link)
            value = inputs.to_status(self.profile, timestamp=time.time(), source=NAME)
        elif status or not addresses:
            sample = yield from self._fresh_steps(link, scanner)
            assemblies = link.assemblies or AssemblySet.EXTENDED
            inputs = decode_input(sample.data, assemblies.input_instance)
            timestamp = scanner.wall_time(sample.at)
            value = inputs.to_status(self.profile, selected_address=sample.select, timestamp=timestamp, source=NAME)
        readings = []
        for point in points:
            if addresses:
                readings.append((yield from self._status_parameter_steps(scanner, link, point, addresses[point.key])))
            else:
                readings.append(Reading(point, inputs.current_a, CURRENT_RESOLUTION_A))
        return PollResult(value if status else None, readings)

    # -- identity ------------------------------------------------------------------------------------------------

    def _identify(self) -> dict[str, object]:
        """Identity object attributes 1-7 (Get_Attribute_Single each; the product name is fragmented)."""
        scanner, link = self._require()
        self._await_explicit(scanner, link)
        raw: dict[int, bytes] = {}
        for attribute in sorted(ATTRIBUTE_NAMES):
            request = ExplicitRequest(
                scanner.config.master_mac, Service.GET_ATTRIBUTE_SINGLE, ObjectClass.IDENTITY, 1, attribute
            )
            raw[attribute] = scanner.request(link, request, timeout=self.timeout * 2).data
        identity = decode_identity(raw)
        result: dict[str, object] = {"mac": link.mac, **identity.as_dict()}
        if link.assemblies is not None:
            result["input_assembly"], result["output_assembly"] = self.settings.instances(link.assemblies)
        result["io_connection"] = link.io.name.lower()
        if link.polling:
            result["expected_packet_rate_ms"] = link.epr_ms
        return result

    def connection_info(self) -> dict[str, object]:
        """The link's state for diagnostics (no bus traffic)."""
        _, link = self._require()
        return {
            "state": link.state.value,
            "io_connection": link.io.value,
            "assemblies": link.assemblies.value if link.assemblies else None,
            "expected_packet_rate_ms": link.epr_ms,
            "responses": link.responses,
            "misses": link.misses,
            "duplicate_answers": link.duplicates,
            "last_error": str(link.last_error) if link.last_error else None,
        }


def _address(point: PointDef) -> int:
    address = point.address_for(NAME)
    assert isinstance(address, int)
    return address


def _has_address(point: PointDef) -> bool:
    """Whether ``point`` has a DeviceNet status parameter address (what the polled connection can select)."""
    address = point.address_for(NAME)
    return address is not None and 0 <= address <= 0xFF
