"""What the LineTask tests share: a task for prepared requests on a scripted line, its outcome as values."""

from __future__ import annotations

from starterbus.core.errors import RemoteDeviceError, StarterbusError
from starterbus.core.polling import PollResult
from starterbus.core.transport import TransportCounters
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadRequest, ReadResponse, Response
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.driver.line_task import LineTask
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy

POLICY = TransactionPolicy(timeout=0.1, retries=1, quarantine=0.3)
READ = ReadRequest(2, 0x0100, 2)


class Poll:
    """A LineTask for ``requests`` on ``line``; an exception answer ends it (as the transport's check does)."""

    def __init__(
        self,
        line: RtuLine,
        *requests: ReadRequest,
        policy: TransactionPolicy = POLICY,
        counters: TransportCounters | None = None,
    ) -> None:
        self.counters = TransportCounters() if counters is None else counters
        self.responses: list[Response] = []
        self.exchanges = [line.prepare(r, policy) for r in requests or (READ,)]
        self.task = LineTask(line, self.exchanges, self.counters, self.check, self.finish)

    @staticmethod
    def check(exchange: Exchange, response: Response) -> None:
        if isinstance(response, ExceptionResponse):
            raise RemoteDeviceError("modbus-rtu", response.code, "refused", data=response.encode())

    def finish(self, responses: list[Response]) -> PollResult:
        self.responses = responses
        return PollResult(None, [])


def values(outcome: PollResult | StarterbusError, poll: Poll) -> list[tuple[int, ...]] | StarterbusError:
    """The registers of each answer, or the error the task ended with."""
    if isinstance(outcome, StarterbusError):
        return outcome
    return [r.values for r in poll.responses if isinstance(r, ReadResponse)]
