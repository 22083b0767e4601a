"""The simulated DP slave: the server half of the telegram codec in front of the shared SimulatedStarter.

One :meth:`SimulatedDpSlave.exchange` is one DP data exchange: it takes the master's output words and returns the
input words. Behaviour (the rules the master's handshake relies on, see ``handshake.py``):

- PZD: the STW goes to ``starter.write_control_word(word, cyclic=True)`` on every exchange (edges act, a held
  start bit does not restart a motor after a fault reset); ZSW is the starter's status word, ACT its phase
  current in 0.1 A.
- PKW: a task is executed once, when the PKW words change; while the master keeps sending the same words the
  slave keeps showing the same response. Task 0 is answered with response 0 ("no response", INDL 0, PWE 0).
  ``latency`` delays every new PKW response by that many exchanges (a slow slave or gateway) so that masters
  can be tested against stale input.
- Refusals of the simulated starter become the model's own response/error numbers (:data:`REFUSAL_ANSWERS`).
- ``fault_hook`` (tests, the conformance kit): called with the output words whenever they change (a new telegram
  reached the slave); the :class:`PkwFault` it returns applies to the PKW task that telegram carries, if it is a
  new task (not "no task"): its response lost (the task is still carried out) or shown ``delay`` seconds late:
  as the answer if the master still sends that task, else for a moment over the answer to the next task the
  master sends (on another INDL).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from starterbus.core import ConfigurationError, DecodeError, Kind, Profile, Refusal, SimulatedStarter, SimulatorRefusal
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, Ppo, ResponseCode, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import NO_RESPONSE, PkwRequest, PkwResponse
from starterbus.transports.profibus_pkw.settings import RESPONSE_2, UNSUPPORTED_TASK, profibus_settings

#: key for the answer to a task code the slave does not know (INDH 4-255 from the master)


@dataclass(frozen=True, slots=True)
class PkwAnswer:
    """How a slave answers a refused task: response 2 (error unused) or response 3 with an error number."""

    response: ResponseCode
    error: int = 0


@dataclass(frozen=True, slots=True)
class PkwFault:
    """What a slave does wrong with one PKW task (the ``fault_hook``'s answer): ``answer`` False carries the task
    out and never shows its response; ``delay`` shows it that many seconds late."""

    answer: bool = True
    delay: float = 0.0


#: how long a late answer to a task the master no longer sends shows over the answer to its next task (s): a few
#: of a master's cycles
LATE_SHOWN = 0.05

FaultHook = Callable[[tuple[int, ...]], "PkwFault | None"]

_R2 = PkwAnswer(ResponseCode.NO_WRITE_PERMISSION)
# Module constants of the enum members read on every exchange: an Enum's class attribute goes through the enum
# type's __getattr__ hook at each access (several times the cost of a global).
_PPO1, _NO_TASK, _WRITE = Ppo.PPO1, TaskCode.NO_TASK, TaskCode.WRITE_PARAMETER
_READ_MEASUREMENT = TaskCode.READ_MEASUREMENT
_TASKS = (TaskCode.READ_PARAMETER, TaskCode.WRITE_PARAMETER, TaskCode.READ_MEASUREMENT)
_MEASUREMENT, _PARAMETER, _VALUE = Kind.MEASUREMENT, Kind.PARAMETER, ResponseCode.VALUE


def _r3(error: int) -> PkwAnswer:
    return PkwAnswer(ResponseCode.CANNOT_EXECUTE, error)


#: Per model: refusal of the simulated starter -> answer. Decisions (docs/profibus.md, "Simulator answers"):
#: a read-only parameter answers response 2 "no write permission" (neither manual ties response 2 to any other
#: condition); everything else is response 3 with the number from the model's own table.
REFUSAL_ANSWERS: Mapping[str, Mapping[Refusal | str, PkwAnswer]] = {
    "jjr5000": {
        Refusal.NOT_AVAILABLE: _r3(2),  # illegal data address
        Refusal.READ_ONLY: _R2,
        Refusal.OUT_OF_RANGE: _r3(3),  # illegal data value
        Refusal.WRITE_PROTECTED: _r3(4),  # parameter modify (0x0147) = 0
        Refusal.WHILE_RUNNING: _r3(3),  # "parameter cannot be modified" is part of error 3's text
        UNSUPPORTED_TASK: _r3(1),  # illegal function
    },
    "jjr8000": {
        Refusal.NOT_AVAILABLE: _r3(0),  # parameter not available
        Refusal.READ_ONLY: _R2,
        Refusal.OUT_OF_RANGE: _r3(2),  # value out of limits
        Refusal.WRITE_PROTECTED: _r3(1),  # value cannot be modified (the model has no write lock)
        Refusal.WHILE_RUNNING: _r3(3),  # cannot modify while running
        UNSUPPORTED_TASK: _r3(4),  # service not supported
    },
}

_KEYWORDS: Mapping[Refusal | str, tuple[str, ...]] = {
    Refusal.NOT_AVAILABLE: ("not available", "address"),
    Refusal.OUT_OF_RANGE: ("out of limits", "limit", "value"),
    Refusal.WRITE_PROTECTED: ("forbidden", "cannot be modified", "protect"),
    Refusal.WHILE_RUNNING: ("while running", "running", "cannot be modified"),
    UNSUPPORTED_TASK: ("not supported", "function"),
}


def refusal_answers(profile: Profile) -> dict[Refusal | str, PkwAnswer]:
    """The answer table for a model.

    Order: the profile's optional ``[transports.profibus-pkw.refusals]`` table (keys: ``not_available``,
    ``read_only``, ``out_of_range``, ``write_protected``, ``while_running``, ``unsupported_task``; values: an
    error number for response 3, or ``"response 2"``), else the built-in table of the model, else the first
    error of the model's table whose English text has a matching keyword (response 2 for read-only).
    """
    settings = profibus_settings(profile)
    errors: Mapping[int, object] = settings.errors
    answers: dict[Refusal | str, PkwAnswer] = dict(REFUSAL_ANSWERS.get(profile.name, {}))
    if not answers:
        answers[Refusal.READ_ONLY] = _R2
        for key, words in _KEYWORDS.items():
            for word in words:
                hit = next((n for n, label in sorted(errors.items()) if word in str(label).lower()), None)
                if hit is not None:
                    answers[key] = _r3(hit)
                    break
            else:
                answers[key] = _r3(min(errors) if errors else 0)
    names: dict[str, Refusal | str] = {r.name.lower(): r for r in Refusal}
    names[UNSUPPORTED_TASK] = UNSUPPORTED_TASK
    for name, value in settings.refusals.items():  # checked when the profile loaded
        answers[names[name]] = _R2 if value == RESPONSE_2 else _r3(int(value))
    return answers


class SimulatedDpSlave:
    """A DP slave of one PPO type around a :class:`SimulatedStarter`. Thread-safe (uses the starter's lock)."""

    def __init__(
        self,
        starter: SimulatedStarter,
        ppo: Ppo | int = Ppo.PPO1,
        *,
        latency: int = 0,
        name: str = "",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.starter = starter
        self.profile = starter.profile
        self.ppo = Ppo(ppo)
        if self.ppo.value not in profibus_settings(self.profile).ppo:
            raise ConfigurationError(f"{self.profile.display_name} does not offer {self.ppo.name} (profile 'ppo')")
        if latency < 0:
            raise ValueError("latency is a number of exchanges >= 0")
        self.latency = latency
        self.name = name
        self._words = self.ppo.words
        self._ppo1 = self.ppo is _PPO1
        self._source = ("", "")  # (slave name, the source of its control words): made again when the name changes
        self.answers = refusal_answers(self.profile)
        self.exchanges = 0
        self.outputs: tuple[int, ...] | None = None  # the last output words received
        self._request: PkwRequest | None = None
        self._shown: PkwResponse = NO_RESPONSE
        self._pending: deque[tuple[int, PkwResponse]] = deque()  # (the exchange it shows from, the response)
        self._clock = clock
        self._held: list[tuple[float, PkwRequest, PkwResponse]] = []  # a fault's late answers: (when, task, response)
        self._overdue: list[PkwResponse] = []  # late answers due, shown when the master sends its next task
        self._flash: tuple[float, PkwResponse] | None = None  # a late answer over the response in force, until
        self.fault_hook: FaultHook | None = None
        self.tasks_executed = 0
        currents = self.profile.phase_currents()
        self._phase_a = currents[0] if currents else None

    # -- one exchange ------------------------------------------------------------------------------------

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        """One data exchange. ``None`` words keep the previous output (an in-process master that leaves the
        control word alone); a ``None`` control word is not applied to the starter."""
        given = tuple(out_words)
        if len(given) != self._words or any(w is not None and not 0 <= w <= 0xFFFF for w in given):
            raise DecodeError(
                f"{self.ppo.name} slave {self.name!r} expects {self.ppo.words} 16-bit output words, got {list(given)}"
            )
        with self.starter.lock:
            if None in given:
                previous = self.outputs or (0,) * self._words
                words = tuple(p if w is None else w for w, p in zip(given, previous, strict=True))
            else:
                words = given  # type: ignore[assignment]  # no None in it
            self.exchanges += 1
            fault = None
            if self.fault_hook is not None and words != self.outputs:
                fault = self.fault_hook(words)
            self.outputs = words
            ppo1 = self._ppo1
            if ppo1:
                self._pkw(PkwRequest(words[0], words[1]), fault)
            stw_index = 2 if ppo1 else 0
            if given[stw_index] is not None:
                self.starter.write_control_word(words[stw_index], cyclic=True, source=self._control_source())
            return self.inputs()

    def _control_source(self) -> str:
        """How the control words of this slave are named in the starter's record (its name may be set later)."""
        name, source = self._source
        if name != self.name or not source:
            where = f" (slave {self.name})" if self.name else ""
            source = f"Profibus {self.ppo.name} STW{where}"
            self._source = (self.name, source)
        return source

    def inputs(self) -> tuple[int, ...]:
        """The input words as they stand (what the next exchange returns before its own effects)."""
        with self.starter.lock:
            zsw = self.starter.status_word()
            act = max(0, min(0xFFFF, round(self.starter.current() * 10)))
            if self._ppo1:
                shown = self._shown if self._flash is None else self._flash[1]
                return (shown.ind, shown.pwe, zsw, act)
            return (zsw, act)

    # -- PKW ---------------------------------------------------------------------------------------------

    def _pkw(self, request: PkwRequest, fault: PkwFault | None = None) -> None:
        pending = self._pending
        if request != self._request:
            self._request = request
            self._flash = None
            response = self.execute(request)
            if fault is None or request.task == _NO_TASK:  # "no response" to "no task" is the handshake's, not a task's
                pending.append((self.exchanges + self.latency, response))
            elif fault.answer:
                self._held.append((self._clock() + fault.delay, request, response))
            if self._overdue and request.task != _NO_TASK:
                self._show_overdue(request)
        while pending and pending[0][0] <= self.exchanges:
            self._shown = pending.popleft()[1]
        if self._held or self._flash is not None:
            self._late(self._clock())

    def _late(self, now: float) -> None:
        """The responses a fault held back, when their time comes: the answer to the task the master still sends
        (a slow slave); else an overdue answer, shown when the master sends its next task."""
        if self._flash is not None and now >= self._flash[0]:
            self._flash = None
        for entry in [held for held in self._held if held[0] <= now]:
            self._held.remove(entry)
            if entry[1] == self._request:
                self._shown = entry[2]
            else:
                self._overdue.append(entry[2])

    def _show_overdue(self, request: PkwRequest) -> None:
        """A late answer shows for :data:`LATE_SHOWN` seconds over the answer to ``request``, the task the master
        sends now: the moment a late answer can be taken for another task's. Not on the late answer's own INDL:
        a slave answers its tasks in order, so an earlier task's answer never follows a later one's there."""
        for late in self._overdue:
            if late.ind & 0xFF != request.indl:
                self._overdue.remove(late)
                self._flash = (self._clock() + LATE_SHOWN, late)
                return

    def execute(self, request: PkwRequest) -> PkwResponse:
        """Carry out one PKW task on the starter now and return the response (no latching)."""
        task = request.task
        index = request.indl
        if task == _NO_TASK:
            return NO_RESPONSE
        if task not in _TASKS:
            return self._refused(UNSUPPORTED_TASK, index)
        kind = _MEASUREMENT if task == _READ_MEASUREMENT else _PARAMETER
        try:
            point = self.starter.point_at(PROTOCOL, kind, index)
            if task == _WRITE:
                self.starter.write(point, request.pwe)
                value = request.pwe
            else:
                value = self.starter.read(point)
        except SimulatorRefusal as refusal:
            return self._refused(refusal.reason, index)
        self.tasks_executed += 1
        return PkwResponse((_VALUE << 8) | index, value & 0xFFFF)

    def _refused(self, why: Refusal | str, index: int) -> PkwResponse:
        answer = self.answers.get(why) or self.answers[UNSUPPORTED_TASK]
        return PkwResponse((answer.response << 8) | index, answer.error)
