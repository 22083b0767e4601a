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

import threading
import time
from collections.abc import Generator, Sequence
from typing import Any

from starterbus.core import (
    CW_RESET,
    CW_START,
    Capability,
    Command,
    ConfigurationError,
    ControlSourceError,
    ControlWordState,
    DecodeError,
    DeviceUrl,
    PointDef,
    PollResult,
    PollTask,
    Profile,
    Reading,
    SharedPool,
    Status,
    TimeoutError,
    Transport,
    UnsupportedOperationError,
)
from starterbus.transports.devicenet.codec.assemblies import (
    CURRENT_RESOLUTION_A,
    AssemblySet,
    InputAssembly,
    InputBit,
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
from starterbus.transports.devicenet.master.link import InputSample, LinkState
from starterbus.transports.devicenet.master.polling import POLL_RESPONSE_TIMEOUT
from starterbus.transports.devicenet.master.requests import (
    Explicit,
    FreshInput,
    MasterRequest,
    Outputs,
    TakeControl,
    Until,
)
from starterbus.transports.devicenet.master.sequence import input_request
from starterbus.transports.devicenet.settings import devicenet_settings
from starterbus.transports.devicenet.url import NAME, parse_url

__all__ = ["SCANNERS", "ControlConflictError", "DeviceNetTransport"]

#: one scanner per (interface, channel) in this process
SCANNERS: SharedPool[Scanner] = SharedPool("devicenet scanners")


class ControlConflictError(ControlSourceError):
    """Taking control (the polled I/O connection) would override a run command this master did not give."""


class DeviceNetTransport(Transport):
    name = NAME
    #: polled I/O: the slave's watchdog stops the motor when the master lets the connection go
    run_needs_connection = True

    def __init__(self, url: DeviceUrl, profile: Profile) -> None:
        super().__init__(url, profile)
        self.scanner_config, self.link_config = parse_url(url, profile)
        self.settings = devicenet_settings(profile)
        self.scanner: Scanner | None = None
        self.link: SlaveLink | None = None
        self._select_lock = threading.Lock()
        self._key = (self.scanner_config.interface, self.scanner_config.channel)
        self.control = url.get_str("control", "command", choices=("command", "open"))

    # -- lifecycle ---------------------------------------------------------------------------------------------

    def _open(self) -> None:
        config = self.scanner_config
        scanner = SCANNERS.acquire(self._key, lambda: Scanner(config))
        try:
            conflicts = scanner.config.conflicts(config)
            if conflicts:
                raise ConfigurationError(
                    f"{self.url.text}: the DeviceNet scanner on {scanner.where} already runs with other "
                    + ", ".join(f"{n}={getattr(scanner.config, n)}" for n in conflicts)
                )
            scanner.wait_online(2 * config.dup_mac_wait + config.timeout + 1.0)
            link = scanner.attach(self.link_config)
        except BaseException:
            SCANNERS.release(self._key)
            raise
        self.scanner, self.link = scanner, link
        try:
            self._wait_established(4 * config.timeout + 0.5)
            if self.control == "open":
                self._take_control(scanner, link, "opening with control=open")
        except BaseException:
            self._close()
            raise

    def _wait_established(self, timeout: float) -> None:
        scanner, link = self._require()

        def settled() -> bool:
            return link.established or (link.state is LinkState.REFUSED and link.last_error is not None)

        scanner.wait_for(settled, timeout)
        if link.established:
            return
        if link.last_error is not None and not isinstance(link.last_error, TimeoutError):
            raise link.last_error
        raise TimeoutError(
            f"{self.describe()}: the slave did not answer the connection sequence within {timeout:g} s"
            + (f" (last error: {link.last_error})" if link.last_error else "")
        )

    def _close(self) -> None:
        scanner, link = self.scanner, self.link
        self.scanner = self.link = None
        if scanner is not None and link is not None:
            try:
                scanner.detach(link)
            finally:
                SCANNERS.release(self._key)

    def _require(self) -> tuple[Scanner, SlaveLink]:
        if self.scanner is None or self.link is None:
            raise self._not_open()
        return self.scanner, self.link

    # -- capabilities -------------------------------------------------------------------------------------------

    @property
    def capabilities(self) -> frozenset[Capability]:
        return frozenset({Capability.READ_MEASUREMENTS, Capability.COMMANDS, Capability.STATUS})

    def describe(self) -> str:
        return f"{self.url.text} (MAC {self.link_config.mac})"

    @property
    def timeout(self) -> float:
        return self.scanner_config.timeout

    def stale_after(self, link: SlaveLink) -> float:
        """Age after which the latest input no longer counts as the device's status."""
        return max(2 * link.interval, 0.1) + POLL_RESPONSE_TIMEOUT

    def _fresh_sample(self, link: SlaveLink, scanner: Scanner) -> InputSample:
        return scanner.drive(self._fresh_steps(link, scanner))

    def _fresh_steps(self, link: SlaveLink, scanner: Scanner) -> Generator[MasterRequest, Any, InputSample]:
        limit = self.stale_after(link)
        error = scanner.link_error(link)
        if error is not None:
            raise error
        sample = yield FreshInput(link, limit, self.timeout)  # polled at once if older: a slow scan never fails
        if sample is None:
            last = link.sample
            age = "never" if last is None else f"{scanner.clock() - last.at:.3f} s ago"
            raise TimeoutError(
                f"{self.describe()}: no fresh input assembly (last one {age}, fresh means < {limit:.3f} s; "
                f"connection {link.state.value}" + (f": {link.last_error}" if link.last_error else "") + ")"
            )
        assert isinstance(sample, InputSample)
        return sample

    def _await_explicit(self, scanner: Scanner, link: SlaveLink) -> None:
        """Give a slave being (re-)allocated up to ``timeout`` to establish its explicit connection."""
        if not link.established:
            scanner.wait_for(lambda: link.established or scanner.machine.link_error(link) is not None, self.timeout)

    def _explicit_inputs(self, scanner: Scanner, link: SlaveLink) -> InputAssembly:
        """The input assembly read over explicit messaging (Get_Attribute_Single, attribute 3): no outputs sent."""
        return scanner.drive(self._explicit_steps(scanner, link))

    def _explicit_steps(self, scanner: Scanner, link: SlaveLink) -> Generator[MasterRequest, Any, InputAssembly]:
        if not link.established:  # a slave being (re-)allocated gets up to ``timeout`` to establish
            yield Until(lambda: link.established or scanner.machine.link_error(link) is not None, self.timeout)
        error = scanner.link_error(link)
        if error is not None:
            raise error
        assemblies = link.assemblies or AssemblySet.EXTENDED
        if not link.established:
            raise TimeoutError(
                f"{self.describe()}: no explicit connection ({link.state.value}"
                + (f": {link.last_error}" if link.last_error else "")
                + ")"
            )
        request = input_request(scanner.machine, link, assemblies)
        response = yield Explicit(link, request, False, self.timeout * 2)
        return decode_input(response.data, assemblies.input_instance)

    def _retake(self, scanner: Scanner, link: SlaveLink, *, strict: bool) -> None:
        """``control=open``: hold the polled I/O connection again after a loss or a fault took it. While the
        motor runs on a command this master no longer holds, a status read monitors (``strict`` False) and a
        status parameter read raises the :class:`ControlConflictError`."""
        if self.control == "open" and not link.polling:
            scanner.drive(self._retake_steps(scanner, link, strict=strict))

    def _retake_steps(self, scanner: Scanner, link: SlaveLink, *, strict: bool) -> Generator[MasterRequest, Any, None]:
        """:meth:`_retake` as tickets (the fleet's poll task runs them too): the input assembly read over explicit
        messaging, then the polled I/O connection taken only if no motor runs under another control."""
        if self.control != "open" or link.polling:
            return
        inputs = yield from self._explicit_steps(scanner, link)
        conflict = self._conflict(inputs, link, "taking control again (control=open)")
        if conflict is not None:
            if strict:
                raise conflict
            return
        scanner.keep()  # from now on the master polls unattended (the slave's watchdog)
        yield TakeControl(link, 4 * self.timeout)

    def _conflict(self, inputs: InputAssembly, link: SlaveLink, why: str) -> ControlConflictError | None:
        """Why taking control now would stop a motor run under another control (its first poll carries run = 0),
        or None."""
        bits = inputs.bits & (InputBit.RUNNING | InputBit.STARTING)  # a soft stop under way agrees with run = 0
        if not bits or link.run:
            return None
        state = " and ".join(str(b.name).lower() for b in InputBit if b & bits)
        return ControlConflictError(
            f"{self.describe()}: the motor is {state} under another control (keypad, terminals or another "
            f"master); {why} would take control with run = 0 and stop it: nothing sent"
        )

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

    def _take_control(self, scanner: Scanner, link: SlaveLink, why: str, *, refuse_running: bool = True) -> None:
        """Allocate the polled I/O connection. With ``refuse_running``, refused while the motor runs on a command
        this master did not give (the first poll would carry run = 0: a stop nobody asked for)."""
        if refuse_running:
            conflict = self._conflict(self._explicit_inputs(scanner, link), link, why)
            if conflict is not None:
                raise conflict
        scanner.take_control(link, 4 * self.timeout)

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
                self._take_control(scanner, link, "a fault reset")
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
        link = self.link
        run = link.run if link is not None else False
        assemblies = (link.assemblies if link is not None else None) or (
            AssemblySet.BASIC if self.link_config.assemblies == "basic" else AssemblySet.EXTENDED
        )
        select = link.select if link is not None else 0x01
        frames = []
        for word in self._words(command, run):
            output: OutputAssembly = output_for_word(word, assemblies.output_instance, select)
            frames.append(f"{poll_command_id(self.link_config.mac):03X}#{output.encode().hex().upper()}")
        return frames

    def _why_not(self, capability: Capability) -> str:
        if capability in (Capability.READ_PARAMETERS, Capability.WRITE_PARAMETERS):
            return f"the {self.profile.display_name} does not support parameter access over DeviceNet"
        return super()._why_not(capability)

    # -- measurements ------------------------------------------------------------------------------------------

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        scanner, link = self._require()
        self._retake(scanner, link, strict=True)
        return [self._read_measurement(scanner, link, point) for point in points]

    def read_refusal(self, point: PointDef) -> str | None:
        """Monitoring (``control=command``) reads the input assembly only: the status and the L1 current."""
        phases = self.profile.phase_currents()
        if self.control == "open" or (phases and point.key == phases[0].key):
            return None
        return (
            "the status parameters travel only in the polled I/O connection, whose output assembly also carries "
            "the run bit; reading never takes control: send a command first in this session, open with "
            "control=open (refused while the motor runs under another control), or read it over another "
            "transport; the input assembly (explicit messaging) carries the status and the L1 current"
        )

    def _read_measurement(self, scanner: Scanner, link: SlaveLink, point: PointDef) -> Reading:
        phases = self.profile.phase_currents()
        if not link.polling:
            refusal = self.read_refusal(point)
            if refusal is not None:
                raise self.unsupported(f"read {point.key}", refusal)
            if phases and point.key == phases[0].key:
                return Reading(point, self._explicit_inputs(scanner, link).current_a, CURRENT_RESOLUTION_A)
        if link.assemblies is AssemblySet.BASIC:
            if phases and point.key == phases[0].key:
                sample = self._fresh_sample(link, scanner)
                return Reading(point, decode_input(sample.data, 1).current_a, CURRENT_RESOLUTION_A)
            raise self._basic_refusal(point)
        address = point.address_for(NAME)
        if address is None or not 0 <= address <= 0xFF:
            raise self.unsupported(f"read {point.key}", "it has no DeviceNet status parameter address")
        with self._select_lock:
            return scanner.drive(self._status_parameter_steps(scanner, link, point, address))

    def _basic_refusal(self, point: PointDef) -> UnsupportedOperationError:
        return self.unsupported(
            f"read {point.key}",
            "basic assemblies (PRO type P1/M1) carry only the status bits and the L1 current; "
            "use assemblies=extended (P3/M2) for the status parameters",
        )

    def _status_parameter_steps(
        self, scanner: Scanner, link: SlaveLink, point: PointDef, address: int
    ) -> Generator[MasterRequest, Any, Reading]:
        """Select the status parameter in the outputs, then its value once ``settle`` answers carried it (the
        input does not echo the address: the answers are counted)."""
        settle = self.link_config.settle
        error = scanner.link_error(link)
        if error is not None:
            raise error
        yield Outputs(link, select=address, polls=settle)

        def reported() -> bool:
            sample = link.sample
            return sample is not None and sample.select == address and sample.select_count >= settle

        def settled() -> bool:
            return reported() or not link.established or scanner.machine.link_error(link) is not None

        done = yield Until(settled, self.timeout)
        if not done or not reported():
            error = scanner.link_error(link)
            if error is not None:
                raise error
            raise TimeoutError(
                f"{self.describe()}: status parameter 0x{address:02X} ({point.key}) was not reported within "
                f"{self.timeout:g} s (connection {link.state.value})"
            )
        current = link.sample
        assert current is not None
        inputs = decode_input(current.data, 101)
        if inputs.selected_value is None:
            raise DecodeError("input assembly 101 without bytes 4-5", current.data, "selected_value")
        return Reading(point, inputs.selected_value)

    # -- the fleet's poll without blocking ------------------------------------------------------------------------

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        """The poll as tickets: monitoring, the status and the L1 current from one explicit read of the input
        assembly; while this master polls, the latest fresh sample and each status parameter selected in turn.
        With ``control=open`` and the polled connection lost, the poll first takes control again as the blocking
        path does (refused while a motor runs under another control: then the status is monitored and points
        fail). What the blocking path refuses polls by blocking (None), which raises its message."""
        scanner, link = self._require()
        phases = self.profile.phase_currents()
        l1 = phases[0].key if phases else None
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
