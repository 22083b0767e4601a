"""A PKW job and its terms: the task and what became of it (:class:`PkwJob`), its states, the limits it gives up
at (:class:`Limits`) and the slave's refusal (:class:`PkwError`). The handshake that runs jobs is
:mod:`~starterbus.transports.profibus_pkw.master.handshake`, which re-exports these names."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from starterbus.core import RemoteDeviceError, StarterbusError
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, TASK_TEXT, ResponseCode, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import PkwRequest, PkwResponse
from starterbus.transports.profibus_pkw.master.freshness import DEFAULT_INHERITED

__all__ = ["MAX_INHERITED", "JobState", "Limits", "PkwError", "PkwJob"]

MAX_INHERITED = 254  # the start chain reads inherited + 1 INDLs, all different from the task's


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


# Read by PkwJob.done (often): an Enum's class attribute goes through the enum type's __getattr__ hook.
_DONE, _FAILED = JobState.DONE, JobState.FAILED


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
    stale: int = 0  # responses with the task's INDL not fresh after the proof (possibly an older answer)
    mismatched: int = 0  # responses with the task's INDL that do not echo the task
    last_mismatch: bytes = b""  # the last of them (the PKW bytes)
    fences: int = 0  # fence reads sent to lift a quarantine on the task's INDL
    fence_cycles: int = 0  # exchanges spent on them (sending them; clearing between those of the start chain)
    fence_step: int = 0  # of which since the last fence answer: each fence read has max_cycles of its own
    started: float | None = None
    finished: float | None = None

    @property
    def done(self) -> bool:
        state = self.state
        return state is _DONE or state is _FAILED

    def describe(self) -> str:
        task = self.request.task
        text = TASK_TEXT.get(task, str(task)) if isinstance(task, TaskCode) else str(task)
        return self.what or f"{text} INDL {self.request.indl:#04x}"


@dataclass(frozen=True, slots=True)
class Limits:
    """When a PKW job gives up (``max_cycles`` exchanges, ``timeout`` seconds), and how old an input may be:
    at most ``stale_cycles`` exchanges and ``stale_time`` seconds (0 and 0: the input is always current)."""

    max_cycles: int = 50
    timeout: float = 2.0
    stale_cycles: int = 0
    stale_time: float = 0.0
    verify_start: bool = False  # the session's first task waits for the start chain of fences (freshness.py)
    inherited: int = DEFAULT_INHERITED  # with verify_start: tasks an earlier session may have left unanswered

    def __post_init__(self) -> None:
        if self.max_cycles < 2:
            raise ValueError("max_cycles must be at least 2 (one clear cycle and one task cycle)")
        if self.timeout <= 0:
            raise ValueError("timeout must be positive")
        if self.stale_cycles < 0 or self.stale_time < 0:
            raise ValueError("stale_cycles and stale_time must be >= 0")
        if not 0 <= self.inherited <= MAX_INHERITED:
            raise ValueError(f"inherited must be 0..{MAX_INHERITED} (one fence INDL each, and one more)")
