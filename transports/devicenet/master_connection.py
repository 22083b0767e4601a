"""The master's explicit messaging and connection sequence (sans-IO; the base of the master machine).

Explicit transactions are queued per slave and sent one at a time, fragmented or reassembled as needed. The
connection sequence (Allocate/Release through the group 2 only unconnected port, the rest on the explicit
connection)::

    Allocate explicit + polled (choice 0x03)
      -> "already allocated" (0x0B, our own old allocation, e.g. after a restart): Release 0x03, Allocate again
      -> "allocated to another master" (0x0C/0x01): refused, retried every retry interval
    Get the explicit connection's EPR (class 5 instance 1 attribute 9) -> keep-alive period
    Get produced/consumed size of the polled connection (class 5 instance 2 attributes 7, 8) -> assembly set
    Set expected packet rate (class 5 instance 2 attribute 9) -> polled connection established
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from starterbus.core.errors import ConfigurationError, StarterbusError, TimeoutError, TransportError
from starterbus.transports.devicenet.assemblies import AssemblySet
from starterbus.transports.devicenet.cip import DeviceNetDecodeError, GeneralStatus, ObjectClass, Service
from starterbus.transports.devicenet.connection import (
    DEFAULT_EXPLICIT_EPR_MS,
    EXPLICIT_AND_POLLED,
    ConnectionAttribute,
    ConnectionInstance,
)
from starterbus.transports.devicenet.explicit import (
    ErrorResponse,
    ExplicitRequest,
    Response,
    check_response,
    decode_response,
)
from starterbus.transports.devicenet.fragmentation import Fragmenter, decode_fragment, frames_for, is_fragment
from starterbus.transports.devicenet.frames import CanFrame
from starterbus.transports.devicenet.ids import explicit_request_id, unconnected_request_id
from starterbus.transports.devicenet.master_link import LinkState, MasterLink, ScannerConfig, Transaction


class ExplicitMessaging:
    """Explicit transactions and the connection sequence of every link; :class:`MasterNode` builds on it."""

    config: ScannerConfig
    where: str
    _out: list[CanFrame]

    def _wake(self, at: float) -> None:
        raise NotImplementedError

    def _established(self, link: MasterLink, now: float) -> None:
        raise NotImplementedError

    # -- transactions ---------------------------------------------------------------------------------------

    def _request(
        self, service: int, class_id: int, instance: int, attribute: int | None = None, data: bytes = b""
    ) -> ExplicitRequest:
        return ExplicitRequest(self.config.master_mac, service, class_id, instance, attribute, data)

    def _release_request(self) -> ExplicitRequest:
        return self._request(Service.RELEASE, ObjectClass.DEVICENET, 1, None, bytes((EXPLICIT_AND_POLLED,)))

    def enqueue(self, link: MasterLink, transaction: Transaction, now: float) -> None:
        """Queue a transaction (its request gets the master's MAC and the next transaction id)."""
        link.xid ^= 1
        request = transaction.request
        transaction.request = ExplicitRequest(
            self.config.master_mac,
            request.service,
            request.class_id,
            request.instance,
            request.attribute,
            request.data,
            link.xid,
        )
        link.transactions.append(transaction)
        if len(link.transactions) == 1:
            self._start_transaction(link, transaction, now)

    def _start_transaction(self, link: MasterLink, transaction: Transaction, now: float) -> None:
        transaction.started = True
        transaction.deadline = now + self.config.timeout
        self._wake(transaction.deadline)
        link.last_explicit_at = now
        message = transaction.request.encode()
        can_id = unconnected_request_id(link.mac) if transaction.unconnected else explicit_request_id(link.mac)
        frames = frames_for(message)
        if len(frames) > 1:
            if transaction.unconnected:
                self._finish(link, transaction, now, error=TransportError("the group 2 only port does not fragment"))
                return
            transaction.fragmenter = Fragmenter(message)
            self._out.append(CanFrame(can_id, transaction.fragmenter.current))
        else:
            self._out.append(CanFrame(can_id, frames[0]))

    def _finish(
        self,
        link: MasterLink,
        transaction: Transaction,
        now: float,
        response: object = None,
        error: BaseException | None = None,
    ) -> None:
        if link.transactions and link.transactions[0] is transaction:
            link.transactions.popleft()
        transaction.response = response  # type: ignore[assignment]
        transaction.error = error
        transaction.done = True
        if transaction.on_done is not None:
            transaction.on_done(transaction, now)
        head = link.transactions[0] if link.transactions else None
        if head is not None and not head.started:
            self._start_transaction(link, head, now)

    def _fail_transactions(self, link: MasterLink, error: BaseException, *, started_too: bool) -> None:
        """End queued transactions with ``error`` (no continuation runs: the sequence stops)."""
        for transaction in list(link.transactions):
            if started_too or not transaction.started:
                link.transactions.remove(transaction)
                transaction.error = error
                transaction.done = True

    def _transaction_timer(self, link: MasterLink, now: float) -> None:
        head = link.transactions[0] if link.transactions else None
        if head is None:
            return
        if not head.started:
            self._start_transaction(link, head, now)
        elif now >= head.deadline:
            error = TimeoutError(
                f"{link.describe()}: no response to {head.request.describe()} within {self.config.timeout:g} s"
            )
            self._finish(link, head, now, error=error)

    def _on_explicit_response(self, link: MasterLink, data: bytes, now: float) -> None:
        transaction = link.transactions[0] if link.transactions else None
        if transaction is None or not transaction.started or not data:
            return
        if data[0] & 0x3F != self.config.master_mac:
            return  # for another master
        ack_id = explicit_request_id(link.mac)
        try:
            if is_fragment(data):
                fragment = decode_fragment(data)
                if fragment.is_ack:
                    fragmenter = transaction.fragmenter
                    if fragmenter is None:
                        return
                    following = fragmenter.on_ack(data)
                    if following is not None:
                        transaction.deadline = now + self.config.timeout
                        self._out.append(CanFrame(ack_id, following))
                    return
                reply, whole = transaction.reassembler.feed(data)
                self._out.append(CanFrame(ack_id, reply))
                transaction.deadline = now + self.config.timeout
                if whole is None:
                    return
                data = whole
            response: Response = decode_response(data)
            if response.xid != transaction.request.xid:
                return  # a late answer to an earlier, timed-out request
            if isinstance(response, ErrorResponse):
                error = response.error(transaction.request.service, transaction.request.describe())
                self._finish(link, transaction, now, error=error)
                return
            self._finish(link, transaction, now, response=check_response(transaction.request, response))
        except DeviceNetDecodeError as exc:
            self._finish(link, transaction, now, error=exc)

    # -- the connection sequence ----------------------------------------------------------------------------

    def _allocate(self, link: MasterLink, now: float, after_release: bool = False) -> None:
        link.state = LinkState.ALLOCATING
        link.retry_at = now + self.config.timeout  # overwritten by the outcome
        choice = bytes((EXPLICIT_AND_POLLED, self.config.master_mac))
        request = self._request(Service.ALLOCATE, ObjectClass.DEVICENET, 1, None, choice)

        def done(t: Transaction, at: float) -> None:
            if t.error is None:
                link.note(at, "allocated explicit + polled")
                self._configure(link, at)
                return
            error = t.error
            if (
                not after_release
                and isinstance(error, StarterbusError)
                and getattr(error, "code", None) == GeneralStatus.ALREADY_IN_REQUESTED_MODE
            ):
                link.note(at, "the slave still holds our old allocation: release and allocate again")
                self._release_then_allocate(link, at)
                return
            self._failed(link, error, at)

        self.enqueue(link, Transaction(request, True, done), now)

    def _release_then_allocate(self, link: MasterLink, now: float) -> None:
        link.state = LinkState.RELEASING

        def done(t: Transaction, at: float) -> None:
            if t.error is not None:
                self._failed(link, t.error, at)
                return
            self._allocate(link, at, after_release=True)

        self.enqueue(link, Transaction(self._release_request(), True, done), now)

    def _configure(self, link: MasterLink, now: float) -> None:
        link.state = LinkState.CONFIGURING
        sizes: dict[int, int] = {}

        def got_explicit_epr(t: Transaction, at: float) -> None:
            data = t.response.data if t.response is not None else b""
            link.explicit_epr_ms = struct.unpack("<H", data)[0] if len(data) == 2 else DEFAULT_EXPLICIT_EPR_MS

        epr = ConnectionAttribute.EXPECTED_PACKET_RATE
        get_epr = self._request(Service.GET_ATTRIBUTE_SINGLE, ObjectClass.CONNECTION, ConnectionInstance.EXPLICIT, epr)
        self.enqueue(link, Transaction(get_epr, False, got_explicit_epr), now)

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

        for attribute in (ConnectionAttribute.PRODUCED_CONNECTION_SIZE, ConnectionAttribute.CONSUMED_CONNECTION_SIZE):
            request = self._request(
                Service.GET_ATTRIBUTE_SINGLE, ObjectClass.CONNECTION, ConnectionInstance.POLLED, attribute
            )
            self.enqueue(link, Transaction(request, False, got_size(attribute)), now)

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
        request = self._request(
            Service.SET_ATTRIBUTE_SINGLE,
            ObjectClass.CONNECTION,
            ConnectionInstance.POLLED,
            ConnectionAttribute.EXPECTED_PACKET_RATE,
            struct.pack("<H", link.config.epr_ms),
        )

        def done(t: Transaction, at: float) -> None:
            if t.error is not None or t.response is None:
                self._failed(link, t.error or TransportError("no response"), at)
                return
            actual = struct.unpack("<H", t.response.data)[0] if len(t.response.data) == 2 else link.config.epr_ms
            link.epr_ms = actual
            link.state = LinkState.ESTABLISHED
            link.established_at = at
            link.last_response_at = at
            link.last_explicit_at = at
            link.failures = 0
            link.last_error = None
            self._established(link, at)
            link.note(at, f"established: {found.value} assemblies, expected packet rate {actual} ms")

        self.enqueue(link, Transaction(request, False, done), now)

    def _failed(self, link: MasterLink, error: BaseException, now: float, release: bool = False) -> None:
        self._fail_transactions(link, error, started_too=False)  # the rest of the sequence cannot go on
        link.failures += 1
        link.last_error = error
        if isinstance(error, TimeoutError):
            link.state = LinkState.LOST
            link.retry_at = now + min(self.config.timeout, 0.25)
        else:
            link.state = LinkState.REFUSED
            link.retry_at = now + max(self.config.timeout, 1.0)
        self._wake(link.retry_at)
        link.note(now, f"{link.state.value}: {error}")
        if release:
            self.enqueue(link, Transaction(self._release_request(), True), now)
