"""The driver of one Modbus TCP connection: :class:`MbapEngine` on a :class:`TcpDriver` of the process's
scheduler, shared by everything this process reaches at that ``HOST:PORT`` (``modbus-tcp`` devices and Profibus
PKW gateway stations alike: ``tcp_line.CONNECTIONS``).

Two rules beyond :class:`~starterbus.core.media.Driver`'s, written here once for every user of a connection:

- **A refused transaction withdraws the rest of its batch** (:meth:`MbapDriver.ends_batch`, the hook of the core's
  batch rule), as a failed one does: an exception answer is DONE for
  the engine (the caller reads it as the device's refusal), but nothing after it in the batch is sent (a poll's
  next read, a gateway station's read after its refused write).
- **A batch submitted in the loop** (:meth:`MbapDriver.submit_then`: a gateway station's DP exchange, made by its
  own driver's step) is told how it ended through a callback, at the step of this driver that ended its last
  ticket (or at once, if the connection crashes).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from starterbus.core import StarterbusError, TcpDriver, Ticket, TicketState, step_error
from starterbus.transports.modbus.codec.messages import ExceptionResponse, Response
from starterbus.transports.modbus.master.exchange import Exchange
from starterbus.transports.modbus.master.mbap import MbapEngine

__all__ = ["Ended", "MbapDriver"]

_DONE = TicketState.DONE

#: how a batch submitted in the loop is told it ended: its tickets, in submission order
Ended = Callable[[list[Ticket[Exchange, Response]]], None]


@dataclass(slots=True)
class _Told:
    """A batch submitted in the loop, with whom to tell when its last ticket ends."""

    tickets: list[Ticket[Exchange, Response]]
    ended: Ended


class MbapDriver(TcpDriver[MbapEngine]):
    """One Modbus TCP connection (``outstanding``: transactions on the wire at once)."""

    def __init__(self, host: str, port: int, outstanding: int, connect_timeout: float) -> None:
        name = f"gateway {host}:{port}"
        super().__init__(host, port, lambda: MbapEngine(outstanding=outstanding, name=name), connect_timeout)
        self.name = name
        self._told: list[_Told] = []

    def submit_then(self, exchanges: Sequence[Exchange], now: float, ended: Ended) -> None:
        """Queue ``exchanges`` as one batch and send what can go (in the loop's thread); ``ended`` gets the
        tickets once every one of them has ended."""
        tickets: list[Ticket[Exchange, Response]] = self.submit(exchanges, now, [None] * len(exchanges))
        self._told.append(_Told(tickets, ended))
        try:  # as the scheduler steps a driver (SchedulerLoop._step): a defect here is the connection's
            self.step(now, False)
        except Exception as exc:
            self.crash(step_error(self.name, exc), now)

    def ends_batch(self, ticket: Ticket[Any, Any]) -> bool:
        """An exception answer withdraws the rest of its batch too (DONE for the engine: the caller's refusal)."""
        return ticket.state is not _DONE or isinstance(ticket.result, ExceptionResponse)

    def complete(self, now: float, done: Sequence[Ticket[Any, Any]] | None = None) -> None:
        """As :meth:`Driver.complete`; then each batch submitted in the loop whose tickets have all ended is told."""
        if done is None:
            done = self.engine.take_completed()
        super().complete(now, done)
        if done and self._told:
            self._tell()

    def crash(self, error: StarterbusError, now: float) -> None:
        super().crash(error, now)
        self._tell()

    def _tell(self) -> None:
        waiting, self._told = self._told, []
        left: list[_Told] = []
        for told in waiting:
            for ticket in told.tickets:
                if not ticket.ended:
                    left.append(told)
                    break
            else:
                told.ended(told.tickets)
        self._told = left + self._told
