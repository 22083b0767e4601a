"""The ``devicenet`` transport's link to its slave: the process-wide scanner of its bus (:data:`SCANNERS`), the
link attached and released, and the steps its reads are made of as tickets (a fresh sample, the input assembly
over explicit messaging, control taken again, a status parameter selected in the outputs), which the blocking
path drives and the fleet's poll task runs (``client.py``).
"""

from __future__ import annotations

import threading
from collections.abc import Generator
from typing import Any

from starterbus.core import (
    Capability,
    ConfigurationError,
    ControlSourceError,
    DecodeError,
    DeviceUrl,
    PointDef,
    Profile,
    Reading,
    SharedPool,
    TimeoutError,
    Transport,
    UnsupportedOperationError,
)
from starterbus.transports.devicenet.codec.assemblies import (
    AssemblySet,
    InputAssembly,
    InputBit,
    decode_input,
)
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
from starterbus.transports.devicenet.url import parse_url

__all__ = ["SCANNERS", "ControlConflictError", "LinkTransport"]

#: one scanner per (interface, channel) in this process
SCANNERS: SharedPool[Scanner] = SharedPool("devicenet scanners")


class ControlConflictError(ControlSourceError):
    """Taking control (the polled I/O connection) would override a run command this master did not give."""


class LinkTransport(Transport):
    """The transport's link to its slave on the bus's shared scanner (opened, closed, waited for) and the steps,
    as tickets, that the blocking reads and the fleet's poll task are made of (:class:`DeviceNetTransport`)."""

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

    def _take_control(self, scanner: Scanner, link: SlaveLink, why: str, *, refuse_running: bool = True) -> None:
        """Allocate the polled I/O connection. With ``refuse_running``, refused while the motor runs on a command
        this master did not give (the first poll would carry run = 0: a stop nobody asked for)."""
        if refuse_running:
            self._refuse_conflict(scanner, link, why)
        scanner.take_control(link, 4 * self.timeout)

    def _refuse_conflict(self, scanner: Scanner, link: SlaveLink, why: str) -> None:
        """Raise the :class:`ControlConflictError` if the motor runs on a command this master did not give (read
        over explicit messaging: nothing is sent to the outputs)."""
        conflict = self._conflict(self._explicit_inputs(scanner, link), link, why)
        if conflict is not None:
            raise conflict

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
