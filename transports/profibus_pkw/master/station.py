"""One DP station as a sans-IO engine (docs/engine.md, step 6): the cycle driver's rules without its thread or lock.

A unit is one DP data exchange: :meth:`StationEngine.take_output` gives ``(n, output words)``, the control word
in force (or the step of a command's plan) and the PKW engine's words; the peer answers ``(n, input words)``
(:meth:`~StationEngine.receive`) or fails (:meth:`~StationEngine.refused`). An answer to any exchange but the one
outstanding is stray and counted, never fed to the PKW engine (its freshness proofs count observations).

PZD and PKW are independent: the control word in force goes out on EVERY exchange whatever the PKW engine is
waiting for, so a start or stop is never delayed by a pending or stuck parameter task.

Requests, each a ticket:

- :class:`PkwTask`: one PKW task; the ticket holds its :class:`PkwJob` (``job``), DONE with the job's response,
  FAILED with the job's error;
- :class:`ControlWords`: each word held for ``hold`` exchanges and at least ``pulse`` seconds, the last one then
  in force; done when the plan is empty (a newer command supersedes it: done too, its words are in force);
- :class:`FreshInputs`: the input words of the next exchange (one that starts after the request).

``cycle > 0``: an exchange every ``cycle`` seconds whatever is asked (the deadline is the next cycle); ``cycle ==
0``: exchanges back to back while a ticket waits, none otherwise. Each request has a time limit of its own (rule
6 of docs/engine.md); no clock is read here.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

from starterbus.core import (
    CW_RESET,
    EncodeError,
    StarterbusError,
    Ticket,
    TicketState,
    TimeoutError,
    TransportError,
)
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, Ppo
from starterbus.transports.profibus_pkw.codec.telegram import (
    NO_TASK,
    PkwResponse,
    Ppo1In,
    PzdIn,
    from_words,
)
from starterbus.transports.profibus_pkw.master.handshake import PkwEngine
from starterbus.transports.profibus_pkw.master.station_requests import (
    ControlWords,
    DpIn,
    DpOut,
    FreshInputs,
    PkwTask,
    StationRequest,
    StationTicket,
    output_words_of,
)

#: a deadline that never comes
FOREVER = math.inf
_NEVER = -math.inf
# Module constants of the enum members read on every exchange: an Enum's class attribute goes through the enum
# type's __getattr__ hook at each access (several times the cost of a global).
_PPO1, _QUEUED = Ppo.PPO1, TicketState.QUEUED

__all__ = [
    "ControlWords",
    "DpIn",
    "DpOut",
    "FreshInputs",
    "PkwTask",
    "StationEngine",
    "StationRequest",
    "StationTicket",
    "output_words_of",
]


class StationEngine:
    """The engine of one DP station (one caller at a time: the scheduler's leader). ``control``: the control word
    in force, None while passive (the output word left as it is until the first command)."""

    def __init__(
        self,
        ppo: Ppo,
        pkw: PkwEngine,
        *,
        cycle: float = 0.0,
        hold: int = 3,
        pulse: float = 0.0,
        where: str = "",
        reply_within: float = 1.0,
    ) -> None:
        if cycle < 0 or hold < 1 or pulse < 0:
            raise ValueError("cycle and pulse must be >= 0 and hold >= 1")
        self.ppo, self.pkw, self.cycle, self.hold, self.pulse = ppo, pkw, cycle, hold, pulse
        self._words = ppo.words  # the input words of one exchange
        self._ppo1 = ppo is _PPO1
        self._timed = pkw.limits.stale_time > 0  # inputs fresh by time: on demand, an exchange may wait (_after)
        #: how long a PKW task may wait for the exchanges that apply its own limits
        self.pkw_budget = pkw.limits.timeout + max(cycle, 0.001) * 4 + 1.0
        self.where = where  # the channel, in messages
        self.reply_within = reply_within  # an exchange not answered by then failed (only a peer that drops one)
        self.control: int | None = 0
        self._plan: deque[list[float]] = deque()  # [word, exchanges left, not before (time)]
        self._plan_ticket: StationTicket | None = None
        self._plan_sent = False
        self._before_plan: int | None = 0
        self.attempts = 0  # exchanges started
        self.exchanges = 0  # answered
        self.failures = 0
        self.stray = 0  # answers to no outstanding exchange (dropped)
        self.last_in: tuple[int, ...] | None = None
        self.last_error: StarterbusError | None = None
        self.last_ok = True
        self._out: int = 0  # the exchange outstanding (0: none)
        self._out_at = 0.0
        self._next_at = -math.inf  # cycle > 0: the next exchange
        self._ready_at = 0.0  # cycle == 0: due since
        self._waiting: list[StationTicket] = []
        self._fresh: list[StationTicket] = []  # of which FreshInputs
        self._limit = FOREVER  # the earliest give_up of the waiting tickets
        self._done: list[StationTicket] = []

    # -- what is in force -----------------------------------------------------------------------------------

    def adopt(self, outputs: Sequence[int] | None, inputs: tuple[int, ...]) -> int | None:
        """What a channel showed on open (without writing): its control word is kept in force (the reset bit
        dropped); unknown outputs leave the engine passive on PZD. Returns the word in force."""
        self.last_in = inputs
        if outputs is not None:
            word = outputs[2] if self.ppo is Ppo.PPO1 else outputs[0]
            self.control = word & ~CW_RESET & 0xFFFF
        else:
            self.control = None
        self._before_plan = self.control
        return self.control

    # -- the engine verbs -----------------------------------------------------------------------------------

    @property
    def deadline(self) -> float:
        due = self._limit
        if self._out:
            return min(due, self._out_at + self.reply_within)
        if self.cycle > 0:
            return min(due, self._next_at)
        if self._waiting:
            ready = self._ready_at
            return ready if ready < due else due
        return due

    def submit(self, request: StationRequest, now: float) -> StationTicket:
        ticket = StationTicket(request)
        if isinstance(request, PkwTask):
            if not self._ppo1:
                ticket.failed(EncodeError("PPO3 has no PKW area: parameter tasks need PPO1", field="ppo"), now)
                self._done.append(ticket)
                return ticket
            ticket.job = self.pkw.submit(request.request, request.what)
            ticket.give_up = now + self.pkw_budget
        elif isinstance(request, ControlWords):
            words = request.words
            bad = [w for w in words if not 0 <= w <= 0xFFFF]
            if bad or not words:
                if bad:
                    ticket.failed(EncodeError(f"control word {bad[0]!r} is not 16 bits", field="STW"), now)
                else:
                    ticket.done(None, now)
                self._done.append(ticket)
                return ticket
            old = self._plan_ticket
            if old is not None and not old.ended:  # superseded: its caller returns, its last word is replaced
                self._end(old, now)
            self._before_plan = self.control
            self._plan = deque([[float(w), float(self.hold), now + self.pulse] for w in words])
            self._plan_ticket, self._plan_sent = ticket, False
            self.control = words[-1]
            ticket.give_up = now + request.timeout + len(words) * (self.hold * self.cycle + self.pulse)
        else:
            limits = self.pkw.limits
            ticket.after = self.attempts
            ticket.fresh_after = self.attempts + limits.stale_cycles
            ticket.not_before = now + limits.stale_time if limits.stale_time > 0 else -math.inf
            ticket.give_up = now + request.timeout
            self._fresh.append(ticket)
        if not self._waiting or now < self._ready_at:  # a new request is not held back (_worth_starting)
            self._ready_at = now
        self._waiting.append(ticket)
        self._limit = min(self._limit, ticket.give_up)
        return ticket

    def cancel(self, ticket: Ticket[StationRequest, object], now: float) -> None:
        assert isinstance(ticket, StationTicket), ticket
        if ticket.ended:
            return
        if ticket.job is not None and not ticket.job.done:
            self.pkw.cancel(ticket.job, TransportError(f"{PROTOCOL}: {ticket.job.describe()}: cancelled"), now)
        if ticket is self._plan_ticket:
            if not self._plan_sent:  # nothing of it went out: the word before it stays in force
                self._plan.clear()
                self.control = self._before_plan
            self._plan_ticket = None  # once sent, the plan runs to its end (a reset bit is never left in force)
        ticket.cancelled(now)
        self._forget(ticket)

    def take_output(self, now: float) -> Sequence[DpOut]:
        if self._out:
            return ()
        if self.cycle > 0:
            if now < self._next_at:
                return ()
        elif not self._waiting or now < self._ready_at:
            return ()
        self.attempts = n = self.attempts + 1
        ppo1 = self._ppo1
        pkw = self.pkw.output(now) if ppo1 else NO_TASK
        if self._plan:
            stw: int | None = int(self._plan[0][0])
            self._plan_sent = True
        else:
            stw = self.control
        if self._next_at == _NEVER or now - self._next_at > self.cycle:
            self._next_at = now  # the first exchange, or one after a pause (nobody ran the loop): a new start
        self._out, self._out_at = n, now
        for ticket in self._waiting:
            if ticket.state is _QUEUED and (ticket.job is None or ticket.job.started is not None):
                ticket.sent(now)
        if ppo1:  # output_words_of's, without its call (on every exchange)
            return ((n, (pkw.ind, pkw.pwe, stw, None if stw is None else 0)),)
        return ((n, output_words_of(self.ppo, pkw, stw)),)

    def receive(self, data: DpOut | None, now: float) -> None:
        """``data``: the :data:`DpIn` of an exchange (typed as the unit out: an engine has one unit type)."""
        if data is None:
            return
        n, got = data
        words: tuple[int, ...] = got  # type: ignore[assignment]  # checked below (no cast: a call per exchange)
        if n != self._out or not n:
            self.stray += 1
            return
        self._out = 0
        try:  # count and range (checked here without making a telegram; from_words names what is wrong)
            if len(words) != self._words or not all(0 <= w <= 0xFFFF for w in words):
                if self._ppo1:
                    from_words(Ppo1In, words)
                else:
                    from_words(PzdIn, words)
        except Exception as exc:  # what a third-party channel returned is checked here, typed
            error = exc if isinstance(exc, StarterbusError) else TransportError(f"channel failed: {exc!r}")
            self._failed(n, error, now)
            return
        self.exchanges += 1
        self.last_in = tuple(words)
        self.last_ok = True
        finished = self.pkw.receive(PkwResponse(words[0], words[1]), now) if self._ppo1 else None
        plan = self._plan
        if plan:
            step = plan[0]
            step[1] -= 1
            if step[1] <= 0 and now >= step[2]:
                plan.popleft()
                if plan:
                    plan[0][2] = now + self.pulse
        self._after(n, now, None, finished is not None)

    def refused(self, unit: DpOut, error: StarterbusError, now: float) -> None:
        """The peer raised on the exchange ``unit``: it failed."""
        if unit[0] == self._out and self._out:
            self._out = 0
            self._failed(unit[0], error, now)

    def advance(self, now: float) -> None:
        if self._out and now >= self._out_at + self.reply_within:
            n, self._out = self._out, 0
            self._failed(n, TransportError(f"{PROTOCOL}: DP exchange {n} not answered ({self.where})"), now)
        job = self.pkw.current
        late = job is not None and job.started is not None and now - job.started > self.pkw.limits.timeout
        if late and self.pkw.expire(now) is not None:  # its time limit, without an exchange to apply it
            self._sweep(now)
        if now >= self._limit:
            for ticket in list(self._waiting):
                if now >= ticket.give_up and not ticket.ended:
                    self._give_up(ticket, now)

    def take_completed(self) -> Sequence[StationTicket]:
        done = self._done
        if not done:
            return ()
        self._done = []
        return done

    # -- helpers --------------------------------------------------------------------------------------------

    def close(self, error: StarterbusError, now: float) -> None:
        """Every ticket not ended fails with ``error`` (the station is closed)."""
        for ticket in list(self._waiting):
            if ticket.job is not None and not ticket.job.done:
                self.pkw.cancel(ticket.job, error, now)
            ticket.failed(error, now)
            self._forget(ticket)

    def _failed(self, n: int, error: StarterbusError, now: float) -> None:
        self.failures += 1
        self.last_error = error
        self.last_ok = False
        failed = self.pkw.fail(error, now)
        self._after(n, now, error, bool(failed))

    def _after(self, n: int, now: float, error: StarterbusError | None, job_ended: bool) -> None:
        """Exchange ``n`` ended (``error``: it failed; ``job_ended``: it ended a PKW job): the tickets it ends,
        and when the next one is due."""
        if self.cycle > 0:
            self._next_at = max(self._next_at + self.cycle, now)  # an overrun: at once, without catching up
        self._ready_at = now
        for ticket in self._fresh:
            if n <= ticket.after:
                continue
            if error is not None:
                ticket.failed(error, now)
                job_ended = True
            elif n > ticket.fresh_after and self._out_at >= ticket.not_before:  # exchange n started at _out_at
                ticket.done(self.last_in, now)
                job_ended = True
        plan_ticket = self._plan_ticket
        if plan_ticket is not None and not self._plan:
            plan_ticket.done(None, now)
            job_ended = True
        if job_ended:
            self._sweep(now)
        if self._timed and error is None and not self.cycle and not self._plan and self._waiting:
            self._ready_at = self._worth_starting(now)

    def _worth_starting(self, now: float) -> float:
        """On demand with inputs fresh by time (``stale_time``): when the next exchange is worth starting. An input
        that no waiting ticket can use is not asked for: the PKW engine's (its answer, or the "no response" that
        starts it, must be fresh by time after a mark: the exchange starts half a round trip before, so that its
        input comes after) and a status read's (an exchange started ``stale_time`` after the request, once the
        exchanges it counts have run). What is accepted is the same; the exchanges in between would be spent in
        vain (each one a gateway's FC16 and read). A control word is never held back (no plan runs here)."""
        start = math.inf
        if self.pkw.busy:
            start = self.pkw.useful_from() - (now - self._out_at) / 2
        for ticket in self._fresh:
            start = min(start, ticket.not_before if self.attempts >= ticket.fresh_after else now)
        return start if now < start < math.inf else now

    def _sweep(self, now: float) -> None:
        for ticket in list(self._waiting):
            job = ticket.job
            if job is not None and job.done and not ticket.ended:
                if job.error is None:
                    ticket.done(job.response, now)
                else:
                    ticket.failed(job.error, now)
            if ticket.ended:
                self._forget(ticket)

    def _end(self, ticket: StationTicket, now: float) -> None:
        ticket.done(None, now)
        self._forget(ticket)

    def _forget(self, ticket: StationTicket) -> None:
        if ticket is self._plan_ticket:
            self._plan_ticket = None
        waiting = self._waiting
        if ticket in waiting:
            waiting.remove(ticket)
            self._limit = min(t.give_up for t in waiting) if waiting else FOREVER
        if ticket in self._fresh:
            self._fresh.remove(ticket)
        self._done.append(ticket)

    def _give_up(self, ticket: StationTicket, now: float) -> None:
        request = ticket.request
        job = ticket.job
        if job is not None:  # no exchange came back in time to apply the limits: the channel stalled
            why = TimeoutError(f"{PROTOCOL}: {job.describe()}: no DP exchange within {self.pkw_budget:.2f} s")
            self.pkw.cancel(job, why, now)
            ticket.failed(job.error or why, now)
        elif isinstance(request, ControlWords):
            budget = request.timeout + len(request.words) * (self.hold * self.cycle + self.pulse)
            error = self.last_error
            ticket.failed(
                TimeoutError(
                    f"{PROTOCOL}: control word(s) {', '.join(f'0x{w:04X}' for w in request.words)} not exchanged "
                    f"within {budget:.2f} s" + (f" (last error: {error})" if error else "")
                ),
                now,
            )
        else:
            assert isinstance(request, FreshInputs)
            text = f"{PROTOCOL}: no DP exchange within {request.timeout:.2f} s ({self.where})"
            ticket.failed(TimeoutError(text), now)
        self._forget(ticket)
