"""The PKW handshake, sans-IO: which task the master puts in the output area each cycle, and when it is answered.

The vendor protocol has no sequence number: a response is recognised only by its INDL and a non-zero response
code, and the slave keeps showing its last response until it sees the next task. So the master cannot tell the
answer to "read p3" from the answer to the previous "read p3" (or from the old value of p3 when it now writes
p3). Rule used here (the PROFIdrive PKW convention; documented in docs/profibus.md):

    Between two tasks the master sends "no task" (INDH 0) until the input shows "no response" (INDH 0).
    Only a response seen AFTER that clear cycle, with the task's INDL and a non-zero code, answers the task.

A slave's input changes only in reaction to the master's output, so once the "no response" has been seen every
later non-zero response was produced by a task sent after it. Each job therefore takes at least two exchanges
(clear, then task) unless the channel already showed "no response" (an idle cyclic master keeps sending task 0,
so its next job starts at once).

Outcomes of a job (each a defined state, never a hang):

- response 1 with the task's INDL: ``job.response`` holds it (``PWE`` = value; for writes the echo);
- response 2: :class:`PkwError` "no write permission";
- response 3: :class:`PkwError` with the error number in PWE and its meaning from the model's table;
- INDH 4-255 with the task's INDL: :class:`~starterbus.core.errors.DecodeError` (a corrupt answer never yields
  a value);
- responses with another INDL are ignored (counted in ``job.foreign``);
- no answer within ``max_cycles`` exchanges or ``timeout`` seconds (clearing included):
  :class:`~starterbus.core.errors.TimeoutError`;
- the channel failing: the driver calls :meth:`PkwEngine.fail` with its :class:`TransportError`.

No clocks, sockets or threads here: the driver passes ``now`` in and moves the words.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from starterbus.core.errors import DecodeError, RemoteDeviceError, StarterbusError, TimeoutError
from starterbus.core.model import Label
from starterbus.transports.profibus_pkw.telegram import (
    NO_TASK,
    PROTOCOL,
    RESPONSE_TEXT,
    TASK_TEXT,
    PkwRequest,
    PkwResponse,
    ResponseCode,
    TaskCode,
    error_label,
    hex_text,
)


class PkwError(RemoteDeviceError):
    """The slave refused a PKW task: response 2 (no write permission) or 3 (error number in PWE).

    ``response`` is the response code; ``code`` the error number (for response 2, the response code itself),
    ``meaning`` its text from the model's table; ``data`` the four PKW bytes received.
    """

    def __init__(self, response: ResponseCode, code: int, meaning: str, detail: str = "", data: bytes = b"") -> None:
        self.response = response
        super().__init__(PROTOCOL, code, meaning, detail=detail, data=data)


class JobState(str, enum.Enum):
    QUEUED = "queued"
    CLEARING = "clearing"  # sending "no task", waiting for "no response"
    SENDING = "sending"  # sending the task, waiting for its response
    DONE = "done"
    FAILED = "failed"


@dataclass(eq=False, slots=True)
class PkwJob:
    """One task and what became of it."""

    request: PkwRequest
    what: str = ""
    state: JobState = JobState.QUEUED
    response: PkwResponse | None = None
    error: StarterbusError | None = None
    cycles: int = 0  # exchanges from activation to the answer, clearing included
    foreign: int = 0  # non-zero responses with another INDL seen while sending
    started: float | None = None
    finished: float | None = None

    @property
    def done(self) -> bool:
        return self.state in (JobState.DONE, JobState.FAILED)

    def describe(self) -> str:
        task = self.request.task
        text = TASK_TEXT.get(task, str(task)) if isinstance(task, TaskCode) else str(task)
        return self.what or f"{text} INDL {self.request.indl:#04x}"


@dataclass(frozen=True, slots=True)
class Limits:
    """When a PKW job gives up. ``max_cycles`` counts exchanges; ``timeout`` is in seconds."""

    max_cycles: int = 50
    timeout: float = 2.0

    def __post_init__(self) -> None:
        if self.max_cycles < 2:
            raise ValueError("max_cycles must be at least 2 (one clear cycle and one task cycle)")
        if self.timeout <= 0:
            raise ValueError("timeout must be positive")


@dataclass(slots=True)
class PkwEngine:
    """The master's PKW state machine for one slave. Not thread-safe: the cycle driver serialises calls."""

    errors: Mapping[int, Label] = field(default_factory=dict)  # the model's error-number table
    limits: Limits = field(default_factory=Limits)
    _queue: deque[PkwJob] = field(default_factory=deque)
    _current: PkwJob | None = None
    _cleared: bool = False  # the input has shown "no response" since the last task ended

    # -- requests --------------------------------------------------------------------------------------------

    def submit(self, request: PkwRequest, what: str = "") -> PkwJob:
        if request.task == TaskCode.NO_TASK:
            raise ValueError("'no task' is what the engine sends between tasks; submit a real task")
        job = PkwJob(request, what)
        self._queue.append(job)
        return job

    @property
    def busy(self) -> bool:
        return self._current is not None or bool(self._queue)

    @property
    def current(self) -> PkwJob | None:
        return self._current

    def pending(self) -> list[PkwJob]:
        return ([self._current] if self._current else []) + list(self._queue)

    # -- one cycle -------------------------------------------------------------------------------------------

    def output(self, now: float) -> PkwRequest:
        """The PKW words to send this cycle (call once per exchange, before :meth:`receive`)."""
        job = self._current
        if job is None and self._queue:
            job = self._current = self._queue.popleft()
            job.started = now
            job.state = JobState.SENDING if self._cleared else JobState.CLEARING
        if job is None:
            return NO_TASK
        job.cycles += 1
        return job.request if job.state is JobState.SENDING else NO_TASK

    def receive(self, response: PkwResponse, now: float) -> PkwJob | None:
        """Feed the PKW words received in this cycle; returns the job this cycle finished, if any."""
        code = (response.ind >> 8) & 0xFF
        job = self._current
        if job is None:
            self._cleared = code == 0
            return None
        if job.state is JobState.CLEARING:
            if code == 0:
                self._cleared = True
                job.state = JobState.SENDING
            return self._check_limits(job, now)
        # SENDING
        if code == 0:
            return self._check_limits(job, now)
        if response.ind & 0xFF != job.request.indl:
            job.foreign += 1
            return self._check_limits(job, now)
        if code == ResponseCode.VALUE:
            job.response = response
            return self._finish(job, JobState.DONE, now)
        raw = _pkw_bytes(response)
        if code == ResponseCode.NO_WRITE_PERMISSION:
            job.response = response
            job.error = PkwError(
                ResponseCode.NO_WRITE_PERMISSION,
                2,
                RESPONSE_TEXT[ResponseCode.NO_WRITE_PERMISSION],
                f"response 2 to {job.describe()}",
                raw,
            )
        elif code == ResponseCode.CANNOT_EXECUTE:
            job.response = response
            label = error_label(self.errors, response.pwe)
            zh = f" / {label.zh}" if label.zh else ""
            job.error = PkwError(
                ResponseCode.CANNOT_EXECUTE,
                response.pwe,
                label.en,
                f"response 3 to {job.describe()}{zh}",
                raw,
            )
        else:
            job.error = DecodeError(
                f"unknown response code {code} (INDH) to {job.describe()}; no value taken", raw, "INDH"
            )
        return self._finish(job, JobState.FAILED, now)

    def fail(self, error: StarterbusError, now: float, *, all_jobs: bool = False) -> list[PkwJob]:
        """End the current job (and with ``all_jobs`` the queued ones) with ``error``: the channel broke."""
        failed: list[PkwJob] = []
        if self._current is not None:
            job = self._current
            job.error = error
            failed.append(self._finish(job, JobState.FAILED, now))
        while all_jobs and self._queue:
            job = self._queue.popleft()
            job.error = error
            job.state = JobState.FAILED
            job.finished = now
            failed.append(job)
        return failed

    def cancel(self, job: PkwJob, error: StarterbusError, now: float) -> None:
        """End one job (current or queued) with ``error``; a finished job is left alone."""
        if job.done:
            return
        job.error = error
        if job is self._current:
            self._finish(job, JobState.FAILED, now)
            return
        if job in self._queue:
            self._queue.remove(job)
        job.state = JobState.FAILED
        job.finished = now

    def expire(self, now: float) -> PkwJob | None:
        """Apply the time limit without an exchange (a driver whose channel stalls calls this)."""
        return self._check_limits(self._current, now) if self._current is not None else None

    # -- internals -------------------------------------------------------------------------------------------

    def _finish(self, job: PkwJob, state: JobState, now: float) -> PkwJob:
        job.state = state
        job.finished = now
        self._current = None
        self._cleared = False  # the slave now shows this job's response: clear before the next task
        return job

    def _check_limits(self, job: PkwJob, now: float) -> PkwJob | None:
        started = job.started if job.started is not None else now
        why = ""
        if job.cycles >= self.limits.max_cycles:
            why = f"no response within {job.cycles} DP cycles (limit {self.limits.max_cycles})"
        elif now - started > self.limits.timeout:
            why = f"no response within {now - started:.3f} s (limit {self.limits.timeout:g} s, {job.cycles} cycles)"
        if not why:
            return None
        stage = "the slave never answered 'no task' with 'no response'" if job.state is JobState.CLEARING else ""
        extra = f"; ignored {job.foreign} responses for other addresses" if job.foreign else ""
        job.error = TimeoutError(
            f"{PROTOCOL}: {job.describe()}: {why}{'; ' + stage if stage else ''}{extra} "
            f"[task {hex_text(_pkw_bytes(job.request))}]"
        )
        return self._finish(job, JobState.FAILED, now)


def _pkw_bytes(pkw: PkwRequest | PkwResponse) -> bytes:
    return bytes([(pkw.ind >> 8) & 0xFF, pkw.ind & 0xFF, (pkw.pwe >> 8) & 0xFF, pkw.pwe & 0xFF])
