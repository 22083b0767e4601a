"""The master's explicit messaging (sans-IO; the base of the master machine): explicit transactions are
queued per slave and sent one at a time, fragmented or reassembled as needed. The connection sequence built
on them is in :mod:`~starterbus.transports.devicenet.master.sequence`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from starterbus.core import CanFrame, TimeoutError, TransportError
from starterbus.transports.devicenet.codec.cip import DeviceNetDecodeError, ObjectClass, Service
from starterbus.transports.devicenet.codec.connection import (
    EXPLICIT_AND_POLLED,
)
from starterbus.transports.devicenet.codec.explicit import (
    ErrorResponse,
    ExplicitRequest,
    Response,
    check_response,
    decode_response,
)
from starterbus.transports.devicenet.codec.fragmentation import Fragmenter, decode_fragment, frames_for, is_fragment
from starterbus.transports.devicenet.codec.ids import explicit_request_id, unconnected_request_id
from starterbus.transports.devicenet.master.link import MasterLink, ScannerConfig, Transaction


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

    def _release_request(self, choice: int = EXPLICIT_AND_POLLED) -> ExplicitRequest:
        return self._request(Service.RELEASE, ObjectClass.DEVICENET, 1, None, bytes((choice,)))

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

    def preview_frames(
        self, link: MasterLink, requests: Sequence[tuple[bool, ExplicitRequest]], queued: int = 0
    ) -> list[CanFrame]:
        """The frames of these requests (unconnected?, request) if they were queued on ``link`` after ``queued``
        others, each with the next transaction id, all fragments listed; nothing is queued (what a preview
        shows)."""
        frames, xid = [], link.xid ^ (queued & 1)
        for unconnected, request in requests:
            xid ^= 1
            message = replace(request, mac=self.config.master_mac, xid=xid).encode()
            can_id = unconnected_request_id(link.mac) if unconnected else explicit_request_id(link.mac)
            frames += [CanFrame(can_id, data) for data in frames_for(message)]
        return frames

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
            link.last_explicit_answer_at = now
            if isinstance(response, ErrorResponse):
                error = response.error(transaction.request.service, transaction.request.describe())
                self._finish(link, transaction, now, error=error)
                return
            self._finish(link, transaction, now, response=check_response(transaction.request, response))
        except DeviceNetDecodeError as exc:
            self._finish(link, transaction, now, error=exc)
