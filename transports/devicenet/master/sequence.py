"""The master's connection sequence and control on demand (sans-IO; a base of the master machine).

Monitoring (``LinkConfig.io`` False, what the transport uses)::

    Allocate explicit (choice 0x01) through the group 2 only unconnected port
      -> "already allocated" (0x0B, our own old allocation, e.g. after a restart): Release, Allocate again
      -> "allocated to another master" (0x0C/0x01): refused, retried every retry interval
    Get the explicit connection's EPR (class 5 instance 1 attribute 9) -> keep-alive period
    Get the input assembly's data (class 4 instance 101, else 1, attribute 3) -> established, monitoring

Nothing in it carries output data: a monitored starter keeps whatever run command it has. Control (the polled
I/O connection, whose output assembly carries the run bit) is taken on demand by :meth:`take_control`::

    Allocate polled (choice 0x02) -> Get produced/consumed size of the polled connection (class 5 instance 2
    attributes 7, 8) -> assembly set -> Set its expected packet rate (attribute 9) -> polled, first poll

and given back by :meth:`release_control` (Release 0x02). With ``LinkConfig.io`` True the first Allocate takes
both at once (choice 0x03), as a dedicated PLC master would.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from starterbus.core import ConfigurationError, StarterbusError, TimeoutError, TransportError
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.cip import GeneralStatus, ObjectClass, Service
from starterbus.transports.devicenet.codec.connection import (
    DEFAULT_EXPLICIT_EPR_MS,
    EXPLICIT_AND_POLLED,
    AllocationChoice,
    ConnectionAttribute,
    ConnectionInstance,
    describe_choice,
)
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest
from starterbus.transports.devicenet.master.connection import ExplicitMessaging
from starterbus.transports.devicenet.master.link import IoPhase, LinkState, MasterLink, Transaction

#: the polled connection's attributes read before its assembly set is chosen (produced, consumed size)
SIZES = (ConnectionAttribute.PRODUCED_CONNECTION_SIZE, ConnectionAttribute.CONSUMED_CONNECTION_SIZE)


class ConnectionSequence(ExplicitMessaging):
    """The connection sequence of every link, monitoring and control; :class:`MasterNode` builds on it."""

    def _stop_polling(self, link: MasterLink) -> None:
        raise NotImplementedError

    def _allocate_request(self, choice: int) -> ExplicitRequest:
        data = bytes((choice, self.config.master_mac))
        return self._request(Service.ALLOCATE, ObjectClass.DEVICENET, 1, None, data)

    # -- the connection sequence ----------------------------------------------------------------------------

    def _allocate(self, link: MasterLink, now: float, after_release: bool = False) -> None:
        link.state = LinkState.ALLOCATING
        link.io = IoPhase.NONE
        link.retry_at = now + self.config.timeout  # overwritten by the outcome
        choice = EXPLICIT_AND_POLLED if link.config.io else int(AllocationChoice.EXPLICIT)
        request = self._allocate_request(choice)

        def done(t: Transaction, at: float) -> None:
            if t.error is None:
                link.note(at, f"allocated {describe_choice(choice)}")
                if link.config.io:
                    link.io = IoPhase.TAKING
                    self._configure(link, at)
                else:
                    self._configure_monitoring(link, at)
                return
            if not after_release and _already_allocated(t.error):
                link.note(at, "the slave still holds our old allocation: release and allocate again")
                self._release_then(link, choice, at, lambda when: self._allocate(link, when, after_release=True))
                return
            self._failed(link, t.error, at)

        self.enqueue(link, Transaction(request, True, done), now)

    def _release_then(self, link: MasterLink, choice: int, now: float, then: Callable[[float], None]) -> None:
        if not link.established:
            link.state = LinkState.RELEASING

        def done(t: Transaction, at: float) -> None:
            if t.error is not None:
                self._failed(link, t.error, at)
                return
            then(at)

        self.enqueue(link, Transaction(self._release_request(choice), not link.established, done), now)

    def _get_explicit_epr(self, link: MasterLink, now: float) -> None:
        def got_explicit_epr(t: Transaction, at: float) -> None:
            data = t.response.data if t.response is not None else b""
            link.explicit_epr_ms = struct.unpack("<H", data)[0] if len(data) == 2 else DEFAULT_EXPLICIT_EPR_MS

        epr = ConnectionAttribute.EXPECTED_PACKET_RATE
        get_epr = self._request(Service.GET_ATTRIBUTE_SINGLE, ObjectClass.CONNECTION, ConnectionInstance.EXPLICIT, epr)
        self.enqueue(link, Transaction(get_epr, False, got_explicit_epr), now)

    def _configure_monitoring(self, link: MasterLink, now: float) -> None:
        """Explicit connection only: learn its EPR and which input assembly the slave serves, then established."""
        link.state = LinkState.CONFIGURING
        self._get_explicit_epr(link, now)
        wanted = link.config.assemblies
        order = [AssemblySet.EXTENDED, AssemblySet.BASIC]
        if wanted == AssemblySet.BASIC.value:
            order.reverse()

        def try_set(index: int, at: float) -> None:
            chosen = order[index]

            def done(t: Transaction, when: float) -> None:
                data = t.response.data if t.response is not None else b""
                if t.error is None and len(data) == chosen.input_size:
                    if wanted in ("auto", chosen.value):
                        self._monitoring(link, chosen, data, when)
                        return
                    error: BaseException = ConfigurationError(
                        f"{link.describe()} serves {chosen.value} assemblies (input assembly "
                        f"{input_instance(link, chosen)}; no {order[0].value} input assembly "
                        f"{input_instance(link, order[0])}) but the URL asks for assemblies={wanted} "
                        f"({link.config.product} assembly sets: {link.config.sets}; the device's PRO type parameter "
                        "selects one)"
                    )
                elif t.error is not None and _no_such_object(t.error) and index + 1 < len(order):
                    try_set(index + 1, when)
                    return
                elif t.error is not None and not _no_such_object(t.error):
                    error = t.error
                else:
                    what = f"{len(data)} bytes" if t.error is None else "no such object"
                    error = ConfigurationError(
                        f"{link.describe()}: no {link.config.product} input assembly answered as expected (input "
                        f"assembly {input_instance(link, chosen)}: {what}; {link.config.product} assembly sets: "
                        f"{link.config.sets})"
                    )
                self._failed(link, error, when, release=isinstance(error, ConfigurationError))

            self.enqueue(link, Transaction(input_request(self, link, chosen), False, done), at)

        try_set(0, now)

    def _monitoring(self, link: MasterLink, found: AssemblySet, data: bytes, now: float) -> None:
        link.assemblies = found
        link.state = LinkState.ESTABLISHED
        link.established_at = link.last_explicit_answer_at = link.last_explicit_at = now
        link.failures = 0
        link.last_error = None
        link.explicit_inputs = (data, now)
        link.note(now, f"established: explicit messaging only, input assembly {found.input_instance}")

    def _configure(self, link: MasterLink, now: float) -> None:
        """The polled connection's sizes (the assembly set), then its expected packet rate."""
        upgrading = link.established  # take_control on a monitored slave: the explicit connection stays
        if not upgrading:
            link.state = LinkState.CONFIGURING
            self._get_explicit_epr(link, now)
        sizes: dict[int, int] = {}

        def got_size(attribute: int) -> Callable[[Transaction, float], None]:
            def done(t: Transaction, at: float) -> None:
                if t.error is not None or t.response is None:
                    self._failed(link, t.error or TransportError("no response"), at)
                    return
                if len(t.response.data) != 2:
                    self._failed(link, TransportError(f"connection size of {len(t.response.data)} bytes"), at)
                    return
                sizes[attribute] = struct.unpack("<H", t.response.data)[0]
                if len(sizes) == 2:
                    produced = sizes[ConnectionAttribute.PRODUCED_CONNECTION_SIZE]
                    consumed = sizes[ConnectionAttribute.CONSUMED_CONNECTION_SIZE]
                    self._choose_assemblies(link, produced, consumed, at)

            return done

        for attribute in SIZES:
            self.enqueue(link, Transaction(self._size_request(attribute), False, got_size(attribute)), now)

    def _size_request(self, attribute: int) -> ExplicitRequest:
        return self._request(Service.GET_ATTRIBUTE_SINGLE, ObjectClass.CONNECTION, ConnectionInstance.POLLED, attribute)

    def _epr_request(self, link: MasterLink) -> ExplicitRequest:
        return self._request(
            Service.SET_ATTRIBUTE_SINGLE,
            ObjectClass.CONNECTION,
            ConnectionInstance.POLLED,
            ConnectionAttribute.EXPECTED_PACKET_RATE,
            struct.pack("<H", link.config.epr_ms),
        )

    def control_requests(self, link: MasterLink, *, release: bool = False) -> list[tuple[bool, ExplicitRequest]]:
        """The explicit requests (unconnected?, request) of :meth:`take_control` on a monitored slave, or with
        ``release`` of :meth:`release_control`, on the usual path: what a preview shows."""
        if release:
            return [(False, self._release_request(int(AllocationChoice.POLLED)))]
        allocate = (True, self._allocate_request(int(AllocationChoice.POLLED)))
        return [allocate, *((False, self._size_request(a)) for a in SIZES), (False, self._epr_request(link))]

    def _choose_assemblies(self, link: MasterLink, produced: int, consumed: int, now: float) -> None:
        found = AssemblySet.for_sizes(produced, consumed)
        wanted = link.config.assemblies
        if found is None or wanted not in ("auto", found.value):
            what = f"{found.value} assemblies" if found else f"no {link.config.product} assembly pair"
            error = ConfigurationError(
                f"{link.describe()} produces {produced} and consumes {consumed} bytes ({what}) but the URL asks "
                f"for assemblies={wanted} ({link.config.product} assembly sets: {link.config.sets}; the device's "
                "PRO type parameter selects one)"
            )
            self._failed(link, error, now, release=True)
            return
        link.assemblies = found
        link.built_seq = -1
        request = self._epr_request(link)

        def done(t: Transaction, at: float) -> None:
            if t.error is not None or t.response is None:
                self._failed(link, t.error or TransportError("no response"), at)
                return
            actual = struct.unpack("<H", t.response.data)[0] if len(t.response.data) == 2 else link.config.epr_ms
            link.epr_ms = actual
            if not link.established:
                link.established_at = at
                link.last_explicit_at = at
                link.failures = 0
                link.last_error = None
            link.state = LinkState.ESTABLISHED
            link.io = IoPhase.HELD
            link.io_error = None
            link.last_response_at = at
            self._established(link, at)
            link.note(at, f"established: {found.value} assemblies, expected packet rate {actual} ms")

        self.enqueue(link, Transaction(request, False, done), now)

    # -- control: the polled I/O connection on demand -------------------------------------------------------

    def take_control(self, link: MasterLink, now: float) -> None:
        """Allocate and establish the polled I/O connection of a monitored slave (its first poll carries the
        outputs set before this call); :attr:`MasterLink.io` turns HELD, or NONE with ``io_error``."""
        if link.io in (IoPhase.TAKING, IoPhase.HELD) or not link.established:
            return
        link.io = IoPhase.TAKING
        link.io_error = None
        self._allocate_polled(link, now, after_release=False)

    def _allocate_polled(self, link: MasterLink, now: float, *, after_release: bool) -> None:
        choice = int(AllocationChoice.POLLED)
        request = self._allocate_request(choice)

        def done(t: Transaction, at: float) -> None:
            if t.error is None:
                link.note(at, "allocated the polled I/O connection (taking control)")
                self._configure(link, at)
            elif not after_release and _already_allocated(t.error):
                link.note(at, "the slave still holds our old polled connection: release and allocate again")
                self._release_then(link, choice, at, lambda when: self._allocate_polled(link, when, after_release=True))
            else:
                self._failed(link, t.error, at)

        self.enqueue(link, Transaction(request, True, done), now)

    def release_control(self, link: MasterLink, now: float) -> Transaction | None:
        """Release the polled I/O connection (the run bit is dropped first): back to monitoring."""
        if link.io is not IoPhase.HELD or not link.established:
            return None
        link.io = IoPhase.RELEASING
        link.run = link.reset = False
        link.output_seq += 1
        self._stop_polling(link)

        def done(t: Transaction, at: float) -> None:
            link.io = IoPhase.NONE
            link.note(at, "released the polled I/O connection" + (f" ({t.error})" if t.error else ""))

        transaction = Transaction(self._release_request(int(AllocationChoice.POLLED)), False, done)
        self.enqueue(link, transaction, now)
        return transaction

    def _failed(self, link: MasterLink, error: BaseException, now: float, release: bool = False) -> None:
        if link.established and link.io is not IoPhase.HELD:  # taking control failed: monitoring goes on
            self._fail_transactions(link, error, started_too=False)
            link.io = IoPhase.NONE
            link.io_error = error
            link.note(now, f"taking control failed: {error}")
            if release:
                self.enqueue(link, Transaction(self._release_request(int(AllocationChoice.POLLED)), False), now)
            return
        self._fail_transactions(link, error, started_too=False)  # the rest of the sequence cannot go on
        link.failures += 1
        link.last_error = error
        link.io = IoPhase.NONE
        if isinstance(error, TimeoutError):
            link.state = LinkState.LOST
            link.retry_at = now + min(self.config.timeout, 0.25)
        else:
            link.state = LinkState.REFUSED
            link.retry_at = now + max(self.config.timeout, 1.0)
        self._wake(link.retry_at)
        link.note(now, f"{link.state.value}: {error}")
        if release:
            choice = EXPLICIT_AND_POLLED if link.config.io else int(AllocationChoice.EXPLICIT)
            self.enqueue(link, Transaction(self._release_request(choice), True), now)


def input_instance(link: MasterLink, assemblies: AssemblySet) -> int:
    """The model's instance number of the input assembly of ``assemblies``."""
    return link.config.input_instances[0 if assemblies is AssemblySet.BASIC else 1]


def input_request(messaging: ExplicitMessaging, link: MasterLink, assemblies: AssemblySet) -> ExplicitRequest:
    """Get_Attribute_Single of an input assembly's data (attribute 3): the inputs without sending outputs."""
    instance = input_instance(link, assemblies)
    return messaging._request(Service.GET_ATTRIBUTE_SINGLE, ObjectClass.ASSEMBLY, instance, 3)


def _already_allocated(error: BaseException) -> bool:
    code = getattr(error, "code", None)
    return isinstance(error, StarterbusError) and code == GeneralStatus.ALREADY_IN_REQUESTED_MODE


def _no_such_object(error: BaseException) -> bool:
    codes = (GeneralStatus.OBJECT_DOES_NOT_EXIST, GeneralStatus.PATH_DESTINATION_UNKNOWN)
    return isinstance(error, StarterbusError) and getattr(error, "code", None) in codes
