"""What a fleet poller gets from a transport: a poll's result, the plan of its requests, the wire counters."""

from __future__ import annotations

import dataclasses
import select
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

from starterbus.core.model import Reading
from starterbus.core.status import Status


@dataclass(frozen=True, slots=True)
class PollResult:
    """One poll of one device: its status (if asked for) and the points asked for, in the order asked."""

    status: Status | None
    readings: list[Reading]


@dataclass(frozen=True, slots=True)
class PlannedRequest:
    """One request of a device's poll plan, for display (``starterbus poll FLEET --plan``).

    ``wire_time``: seconds the request and its answer occupy the line (silences included) at the line's speed;
    None where the transport cannot tell (a cyclic bus whose master refreshes inputs by itself). ``frames``: how
    many frames of it reach the device: 1 for a request and its answer; a cyclic protocol's task may take more
    (PKW: a clear and a task telegram) and a value in every cycle's inputs none.
    """

    text: str
    registers: int
    request_bytes: int = 0
    answer_bytes: int = 0
    wire_time: float | None = None
    frames: int = 1

    def as_json(self) -> dict[str, object]:
        return {
            "request": self.text,
            "registers": self.registers,
            "request_bytes": self.request_bytes,
            "answer_bytes": self.answer_bytes,
            "wire_time": self.wire_time,
            "frames": self.frames,
        }


@dataclass(slots=True)
class TransportCounters:
    """What one transport put on the wire since it was made (counters only grow).

    ``requests`` counts frames sent, retries included; ``transactions`` the calls that sent them; ``timeouts``
    and ``errors`` the transactions that failed (no answer; any failure); ``busy_time`` the time the transport
    held its line (0 if it does not measure it); ``wire_time`` the time its frames and silences occupied the wire.
    """

    transactions: int = 0
    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    errors: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0
    busy_time: float = 0.0
    wire_time: float = 0.0

    def _values(self) -> tuple[int, int, int, int, int, int, int, float, float]:
        return (
            self.transactions, self.requests, self.retries, self.timeouts, self.errors,
            self.bytes_sent, self.bytes_received, self.busy_time, self.wire_time,
        )  # fmt: skip

    def copy(self) -> TransportCounters:
        return TransportCounters(
            self.transactions, self.requests, self.retries, self.timeouts, self.errors,
            self.bytes_sent, self.bytes_received, self.busy_time, self.wire_time,
        )  # fmt: skip

    def add(self, other: TransportCounters) -> None:
        self.transactions += other.transactions
        self.requests += other.requests
        self.retries += other.retries
        self.timeouts += other.timeouts
        self.errors += other.errors
        self.bytes_sent += other.bytes_sent
        self.bytes_received += other.bytes_received
        self.busy_time += other.busy_time
        self.wire_time += other.wire_time

    def minus(self, other: TransportCounters) -> TransportCounters:
        # (each field read where it is used: a specialised read of a slot costs less than a tuple of them)
        return TransportCounters(
            self.transactions - other.transactions, self.requests - other.requests, self.retries - other.retries,
            self.timeouts - other.timeouts, self.errors - other.errors, self.bytes_sent - other.bytes_sent,
            self.bytes_received - other.bytes_received, self.busy_time - other.busy_time,
            self.wire_time - other.wire_time,
        )  # fmt: skip

    def as_json(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = round(value, 6) if isinstance(value, float) else value
        return out


class PollTask(ABC):
    """One poll in progress that a poller advances without blocking, so one thread can keep many lines busy.

    The driver waits until :attr:`fd` is readable or the monotonic time :attr:`wake_at` has come, whichever is
    first, and calls :meth:`advance` with the time it read after waiting; it repeats while :attr:`done` is
    False (``fd`` may change between calls: a reconnect; -1: wait for ``wake_at`` only). Then :meth:`result`
    gives the poll's result or raises its error. The task owns its line from the first :meth:`advance` until
    it is done; :meth:`cancel` gives the line back unfinished (a poller that stops). A fleet runs these methods
    in the scheduler's own thread (docs/engine.md, step 4): they never block nor wait on the loop. Made by
    :meth:`Transport.start_poll <starterbus.core.transport.Transport.start_poll>`.
    """

    fd: int = -1
    wake_at: float = 0.0
    done: bool = False
    #: set by a poller that advances the task from the scheduler's own loop (the fleet), before the first
    #: :meth:`advance`: calling it (in the loop's thread, e.g. from a done callback of a ticket's future) has the
    #: task advanced at the loop's next turn, so a task waiting for the loop's tickets needs no ``fd`` and only
    #: an outer bound as ``wake_at``. None: nobody listens (``fd`` and ``wake_at`` are all a poller looks at).
    on_progress: Callable[[], None] | None = None

    @abstractmethod
    def advance(self, now: float) -> None:
        """Do what is due at ``now`` (read what arrived, send, time out); never blocks."""

    @abstractmethod
    def result(self) -> PollResult:
        """The poll's result once :attr:`done`; raises the poll's error (a ``StarterbusError``)."""

    @abstractmethod
    def cancel(self) -> None:
        """Stop where it is and give the line back (idempotent); :meth:`result` then raises."""


def run_task(task: PollTask, clock: Callable[[], float]) -> PollResult:
    """Drive ``task`` to its end in the calling thread (one task, blocking): what a poller does for many."""
    try:
        while True:
            task.advance(clock())
            if task.done:
                return task.result()
            wait = task.wake_at - clock()
            if wait > 0:
                select.select([task.fd] if task.fd >= 0 else [], [], [], wait)
    finally:
        task.cancel()
