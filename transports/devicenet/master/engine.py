"""The DeviceNet master as an engine of the one I/O surface (docs/engine.md): :class:`MasterNode` with tickets.

:class:`MasterEngine` keeps :class:`MasterNode`'s verbs (frames and times in, frames out) and adds the tickets
callers wait on (:mod:`~.requests`): each request starts something in the machine (or nothing) and ends when
the machine's state says so, is refused, or at its own timeout (the engine keeps the timeouts: a waiter has
only an outer bound). The engine settles its open tickets after every frame, tick and submission (one pass over
the open tickets: none while the scan runs unattended). Like the machine, it reads no clock, holds no lock, does
no I/O. A submission first runs the machine's timers that are due, so a caller that comes after a quiet spell
(no loop ran meanwhile) is answered from the present state (a lost slave is seen lost before a request goes
out).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from starterbus.core import CanFrame, StarterbusError, Ticket
from starterbus.transports.devicenet.master.node import MasterNode
from starterbus.transports.devicenet.master.requests import MasterRequest

__all__ = ["MasterEngine"]


class MasterEngine:
    """:class:`MasterNode` behind the engine surface (``submit``, ``receive``, ``advance``, ``take_output``,
    ``take_completed``, ``deadline``, ``wanted``), for a CAN driver."""

    def __init__(self, node: MasterNode) -> None:
        self.node = node
        self._open: list[tuple[Ticket[MasterRequest, Any], float]] = []  # with their timeouts
        self._done: list[Ticket[MasterRequest, Any]] = []
        self._out: list[CanFrame] = []
        self._until = math.inf

    @property
    def wanted(self) -> frozenset[int]:
        return self.node.wanted

    @property
    def deadline(self) -> float:
        deadline = self.node.deadline
        return deadline if deadline < self._until else self._until

    def submit(self, request: MasterRequest, now: float) -> Ticket[MasterRequest, Any]:
        node = self.node
        ticket: Ticket[MasterRequest, Any] = Ticket(request)
        if now >= node.deadline:
            self._out.extend(node.tick(now))
        try:
            request.start(node, now)
        except StarterbusError as exc:
            ticket.failed(exc, now)
            self._done.append(ticket)
            return ticket
        self._out.extend(node.take())
        if now >= node.deadline:
            self._out.extend(node.tick(now))
        ticket.sent(now)
        if not self._settle(ticket, now):
            until = now + request.timeout
            self._open.append((ticket, until))
            self._until = min(self._until, until)
            self._settle_all(now)  # what the request changed may end others
        else:
            self._settle_all(now)
        return ticket

    def cancel(self, ticket: Ticket[MasterRequest, Any], now: float) -> None:
        for index, (open_ticket, _) in enumerate(self._open):
            if open_ticket is ticket:
                del self._open[index]
                ticket.cancelled(now)
                self._done.append(ticket)
                self._until = min((until for _, until in self._open), default=math.inf)
                return

    def receive(self, data: CanFrame | None, now: float) -> None:
        if data is None:
            return
        out = self.node.receive(data.can_id, data.data, now)
        if out:
            self._out.extend(out)
        if self._open:
            self._settle_all(now)

    def advance(self, now: float) -> None:
        node = self.node
        if now >= node.deadline:
            self._out.extend(node.tick(now))
        if self._open:
            self._settle_all(now)
            if now >= self._until:
                self._expire(now)

    def take_output(self, now: float) -> Sequence[CanFrame]:
        out, self._out = self._out, []
        return out

    def take_completed(self) -> Sequence[Ticket[MasterRequest, Any]]:
        done, self._done = self._done, []
        return done

    # -- tickets --------------------------------------------------------------------------------------------------

    def _settle(self, ticket: Ticket[MasterRequest, Any], now: float) -> bool:
        try:
            ended, result = ticket.request.check(self.node, now)
        except StarterbusError as exc:
            ticket.failed(exc, now)
            self._done.append(ticket)
            return True
        if ended:
            ticket.done(result, now)
            self._done.append(ticket)
        return ended

    def _settle_all(self, now: float) -> None:
        still = [(t, until) for t, until in self._open if not self._settle(t, now)]
        if len(still) != len(self._open):
            self._open = still
            self._until = min((until for _, until in still), default=math.inf)
            self._out.extend(self.node.take())

    def _expire(self, now: float) -> None:
        still = []
        for ticket, until in self._open:
            if now < until:
                still.append((ticket, until))
                continue
            try:
                result = ticket.request.expire(self.node, now)
            except StarterbusError as exc:
                ticket.failed(exc, now)
            else:
                ticket.done(result, now)
            self._done.append(ticket)
        self._open = still
        self._until = min((until for _, until in still), default=math.inf)
        self._out.extend(self.node.take())
