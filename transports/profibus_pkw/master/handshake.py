"""The PKW handshake, sans-IO: which task the master puts in the output area each cycle, and when it is answered.

The vendor protocol has no sequence number: a response is recognised only by its INDL and a non-zero response
code, and the slave keeps showing its last response until it sees the next task. So the master cannot tell the
answer to "read p3" from the answer to the previous "read p3" (or from the old value of p3 when it now writes
p3). Rule used here (documented in docs/profibus.md, "Stale answers"; the bookkeeping is in ``freshness.py``):

    Between two tasks the master sends "no task" (INDH 0) until the input shows "no response" (INDH 0) at a
    moment that PROVES the slave has left the previous task on the same INDL behind: fresh after that task's
    verified answer, or after a later task's verified answer. Only a response fresh after that proof, with the
    task's INDL, a non-zero code and every echoed field matching, answers the task.

"Fresh after" allows for an input up to ``Limits.stale_cycles`` exchanges and ``Limits.stale_time`` seconds old
(a gateway that lags or replays its image). A task that ended WITHOUT a verified answer (timeout, corrupt
answer, broken channel) leaves its INDL quarantined, in both data areas: the next task on it waits until
another exchange is verifiably answered; the engine forces one with a *fence*, a read of another INDL, unless
the orphan's own late answer shows first. "No response" alone never lifts it: a slave still working on the old
task shows "no response" too. With ``Limits.verify_start`` (what the transport uses) the unknown past before the
session counts as such a task on every INDL: the session's first task is preceded by the *start chain*,
``Limits.inherited + 1`` fence reads on INDLs of their own (why that suffices: ``freshness.py``).

Outcomes of a job (each a defined state, never a hang):

- response 1 with the task's INDL (and, for a write, the value written): ``job.response`` holds it;
- response 2 to a write: :class:`PkwError` "no write permission";
- response 3: :class:`PkwError` with the error number in PWE and its meaning from the model's table;
- INDH 4-255 with the task's INDL: :class:`~starterbus.core.errors.DecodeError` (a corrupt answer never yields
  a value);
- responses with another INDL (``job.foreign``), not fresh (``job.stale``) or not echoing the task
  (``job.mismatched``: response 2 to a read, a write echo with another value) are ignored;
- no answer within ``max_cycles`` exchanges (clearing included; each fence read has ``max_cycles`` of its own)
  or ``timeout`` seconds (everything included): :class:`~starterbus.core.errors.TimeoutError`;
- the channel failing: the driver calls :meth:`PkwEngine.fail` with its :class:`TransportError`.

No clocks, sockets or threads here: the driver passes ``now`` in and moves the words.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from starterbus.core import DecodeError, Label, StarterbusError, TimeoutError
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, RESPONSE_TEXT, ResponseCode, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import (
    NO_TASK,
    PkwRequest,
    PkwResponse,
    error_label,
    hex_text,
    pkw_request,
)
from starterbus.transports.profibus_pkw.master.freshness import Freshness, Mark, answers, pkw_bytes
from starterbus.transports.profibus_pkw.master.job import MAX_INHERITED, JobState, Limits, PkwError, PkwJob

__all__ = ["MAX_INHERITED", "JobState", "Limits", "PkwEngine", "PkwError", "PkwJob"]

# Module constants of the members read on every exchange: an Enum's class attribute goes through the enum type's
# __getattr__ hook at each access (several times the cost of a global).
_CLEARING, _SENDING, _DONE, _FAILED = JobState.CLEARING, JobState.SENDING, JobState.DONE, JobState.FAILED
_NO_TASK_CODE, _WRITE = TaskCode.NO_TASK, TaskCode.WRITE_PARAMETER
_VALUE, _CANNOT_EXECUTE = ResponseCode.VALUE, ResponseCode.CANNOT_EXECUTE


@dataclass(slots=True)
class _Fence:
    """A read of another INDL, sent while the current job's INDL is quarantined; its verified answer lifts it."""

    request: PkwRequest
    basis: Mark


@dataclass(slots=True)
class PkwEngine:
    """The master's PKW state machine for one slave. Not thread-safe: the cycle driver serialises calls."""

    errors: Mapping[int, Label] = field(default_factory=dict)  # the model's error-number table
    limits: Limits = field(default_factory=Limits)
    _queue: deque[PkwJob] = field(default_factory=deque)
    _current: PkwJob | None = None
    _book: Freshness = field(init=False)
    _n: int = 0  # inputs received
    _last: tuple[Mark, int] | None = None  # the last observation and its response code
    _basis: Mark = field(default_factory=lambda: Mark(0, 0.0))  # the current job's answers: fresh after this
    _fence: _Fence | None = None
    _chaining: bool = False  # a start-chain fence was answered, the next one is not sent yet
    _sending_from: int = 0  # the inputs received when the current job began sending its task

    def __post_init__(self) -> None:
        limits = self.limits
        self._book = Freshness(
            limits.stale_cycles, limits.stale_time, verify_start=limits.verify_start, inherited=limits.inherited
        )

    # -- requests --------------------------------------------------------------------------------------------

    def submit(self, request: PkwRequest, what: str = "") -> PkwJob:
        if (request.ind >> 8) & 0xFF == _NO_TASK_CODE:  # INDH (request.task without its table)
            raise ValueError("'no task' is what the engine sends between tasks; submit a real task")
        job = PkwJob(request, what)
        self._queue.append(job)
        return job

    def fences_before(self, request: PkwRequest) -> list[PkwRequest]:
        """The fence reads this engine sends before ``request`` if it were next and every fence were answered at
        once (what a preview shows; nothing changes): the rest of the session's start chain, or one fence while
        the task's INDL is quarantined."""
        book, indl = self._book, request.indl
        if book.unknown:
            taken: list[int] = []
            for _ in range(book.inherited + 1 - book.chain):
                fence = book.fence_indl(indl, taken)
                if fence is None:
                    break
                taken.append(fence)
            return [pkw_request(TaskCode.READ_PARAMETER, fence) for fence in taken]
        if book.orphan(indl) is None:
            return []
        fence = book.fence_indl(indl)
        return [] if fence is None else [pkw_request(TaskCode.READ_PARAMETER, fence)]

    @property
    def busy(self) -> bool:
        return self._current is not None or bool(self._queue)

    @property
    def current(self) -> PkwJob | None:
        return self._current

    def pending(self) -> list[PkwJob]:
        return ([self._current] if self._current else []) + list(self._queue)

    def useful_from(self) -> float:
        """When an input can next move the current job on, if it waits for one that is fresh by time after a mark
        (``stale_time``): its answer after its proof, or the "no response" that starts it by rule 2 after the last
        answer on its INDL; inputs received before are spent in vain. -inf: the next one may do (no such wait, a
        count of exchanges still to run, its task or "no task" not yet sent, a fence). A hint for a driver that
        exchanges on demand: what is accepted does not depend on it."""
        job = self._current
        stale_time = self.limits.stale_time
        if job is None or stale_time <= 0:
            return -math.inf
        book = self._book
        if job.state is _SENDING:
            if self._n <= self._sending_from:
                return -math.inf  # the task has not gone out yet
            mark = self._basis
        elif job.state is _CLEARING and self._fence is None and not self._chaining and not book.unknown:
            record = book.records.get(job.request.indl)
            if record is None:  # its INDL unused in this session: answered at the start (Freshness.proof)
                ended = answered = book.start
            else:
                ended, answered = record.ended, record.answered
            if ended is None or answered is None:
                return -math.inf  # quarantined: fences decide
            if book.accepted is not None and book.accepted.n > ended.n:
                return -math.inf  # rule 1: the next "no response" starts it
            mark = answered
        else:
            return -math.inf
        if self._n < mark.n + book.stale_cycles:
            return -math.inf  # the next input counts towards the exchanges the rule needs
        return mark.t + stale_time

    def quarantined(self, indl: int) -> bool:
        """Is INDL ``indl`` blocked by a task that ended without a verified answer?"""
        return self._book.orphan(indl) is not None

    # -- one cycle -------------------------------------------------------------------------------------------

    def output(self, now: float) -> PkwRequest:
        """The PKW words to send this cycle (call once per exchange, before :meth:`receive`)."""
        if self._book.start is None:
            self._book.begin(now)
        job = self._current
        if job is None and self._queue:
            job = self._current = self._queue.popleft()
            job.started = now
            job.state = _CLEARING
            self._fence = None
            self._chaining = False
            if self._last is not None and self._last[1] == 0:
                self._clear(job, self._last[0])
        if job is None:
            return NO_TASK
        job.cycles += 1
        if job.state is _SENDING:
            return job.request
        if self._fence is not None or self._chaining:
            job.fence_cycles += 1
            job.fence_step += 1
            return self._fence.request if self._fence is not None else NO_TASK
        return NO_TASK

    def receive(self, response: PkwResponse, now: float) -> PkwJob | None:
        """Feed the PKW words received in this cycle; returns the job this cycle finished, if any."""
        book = self._book
        if book.start is None:
            book.begin(now)
        self._n += 1
        obs = Mark(self._n, now)
        ind = response.ind
        code = (ind >> 8) & 0xFF
        self._last = (obs, code)
        job = self._current
        if job is None or job.state is not _SENDING:
            if code and book.records:
                book.late(response, obs)
            if job is None:
                return None
            fence = self._fence
            if fence is not None:
                if code and book.fresh(fence.basis, obs) and answers(fence.request, response):
                    book.fenced(fence.request, fence.basis, obs)
                    self._fence = None
                    job.fence_step = 0
                    self._chaining = book.unknown
            elif code == 0:
                self._clear(job, obs)
            return self._check_limits(job, now)
        # SENDING
        if code == 0:
            return self._check_limits(job, now)
        request = job.request
        if ind & 0xFF != request.ind & 0xFF:
            if book.records:
                book.late(response, obs)
            job.foreign += 1
            return self._check_limits(job, now)
        if not book.fresh(self._basis, obs):
            job.stale += 1
            return self._check_limits(job, now)
        if code == _VALUE and (request.ind >> 8 != _WRITE or response.pwe == request.pwe):
            job.response = response  # the common case first: a value that answers the task
            book.answered(request, self._basis, obs)
            return self._finish(job, _DONE, now)
        raw = pkw_bytes(response)
        if code > _CANNOT_EXECUTE:
            job.error = DecodeError(
                f"unknown response code {code} (INDH) to {job.describe()}; no value taken", raw, "INDH"
            )
            return self._finish(job, JobState.FAILED, now)
        if not answers(job.request, response):
            job.mismatched += 1
            job.last_mismatch = raw
            return self._check_limits(job, now)
        job.response = response
        book.answered(request, self._basis, obs)
        if code == ResponseCode.NO_WRITE_PERMISSION:
            job.error = PkwError(
                ResponseCode.NO_WRITE_PERMISSION,
                2,
                RESPONSE_TEXT[ResponseCode.NO_WRITE_PERMISSION],
                f"response 2 to {job.describe()}",
                raw,
            )
        else:
            label = error_label(self.errors, response.pwe)
            zh = f" / {label.zh}" if label.zh else ""
            job.error = PkwError(
                ResponseCode.CANNOT_EXECUTE,
                response.pwe,
                label.en,
                f"response 3 to {job.describe()}{zh}",
                raw,
            )
        return self._finish(job, JobState.FAILED, now)

    def _clear(self, job: PkwJob, obs: Mark) -> None:
        """The input shows "no response" at ``obs``: start the task if that proves the old one is left behind,
        else (its INDL quarantined) start a fence read of another INDL."""
        basis = self._book.proof(job.request.indl, obs)
        if basis is not None:
            self._basis = basis
            self._sending_from = self._n
            job.state = _SENDING
            return
        if self._book.orphan(job.request.indl) is None:
            return  # the previous answer on this INDL may still be shown: wait for a fresh "no response"
        indl = self._book.fence_indl(job.request.indl)
        fence_basis = None if indl is None else self._book.proof(indl, obs, fence=True)
        if indl is not None and fence_basis is not None:
            self._fence = _Fence(pkw_request(TaskCode.READ_PARAMETER, indl), fence_basis)
            self._chaining = False
            job.fences += 1

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
        if job.error is not None:
            ended = Mark(self._n, now)
            if job.state is _SENDING and not isinstance(job.error, PkwError):
                self._book.unanswered(job.request, self._basis, ended)  # sent, never verifiably answered
            if self._fence is not None:
                self._book.unanswered(self._fence.request, self._fence.basis, ended)
                self._fence = None
        self._chaining = False
        job.state = state
        job.finished = now
        self._current = None
        return job

    def _check_limits(self, job: PkwJob, now: float) -> PkwJob | None:
        started = job.started if job.started is not None else now
        why = ""
        limit = self.limits.max_cycles
        if job.cycles - job.fence_cycles >= limit or job.fence_step >= limit:
            why = f"no response within {job.cycles} DP cycles (limit {limit}"
            why += f", and {limit} for each fence read)" if job.fence_cycles else ")"
        elif now - started > self.limits.timeout:
            why = f"no response within {now - started:.3f} s (limit {self.limits.timeout:g} s, {job.cycles} cycles)"
        if not why:
            return None
        stage = ""
        if job.state is JobState.CLEARING:
            blocked = self._book.why_blocked(job.request.indl)
            if blocked is not None:
                stage = f"INDL {job.request.indl:#04x} is quarantined: {blocked}" + (
                    f", and {job.fences} fence read(s) of another INDL got none either" if job.fences else ""
                )
            else:
                stage = "the slave never answered 'no task' with 'no response'"
        extra = f"; ignored {job.foreign} responses for other addresses" if job.foreign else ""
        if job.stale:
            extra += f"; ignored {job.stale} possibly stale responses"
        if job.mismatched:  # a fresh answer that is not this task's: a typed error, never a value
            job.error = DecodeError(
                f"{PROTOCOL}: {job.describe()}: the slave showed {hex_text(job.last_mismatch)} "
                f"{job.mismatched} time(s), which does not echo the task [{hex_text(pkw_bytes(job.request))}] "
                f"(response 2 to a read, or a write echo of another value), and nothing that does; {why}",
                job.last_mismatch,
                "PWE" if job.request.task == TaskCode.WRITE_PARAMETER else "INDH",
            )
            return self._finish(job, JobState.FAILED, now)
        if job.state is JobState.SENDING and job.request.task == TaskCode.WRITE_PARAMETER:
            extra += "; the slave may still carry the write out"
        job.error = TimeoutError(
            f"{PROTOCOL}: {job.describe()}: {why}{'; ' + stage if stage else ''}{extra} "
            f"[task {hex_text(pkw_bytes(job.request))}]"
        )
        return self._finish(job, JobState.FAILED, now)
