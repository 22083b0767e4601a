"""The engine kit: any :class:`~starterbus.core.engine.Engine` checked against a scripted peer (docs/engine.md).

A schedule (:func:`schedules`, drawn by hypothesis) submits requests, hands what the engine writes to the peer,
delivers the peer's replies in any order, late, twice or never, looks at the medium and finds nothing, moves the
time by a little or to the engine's deadline, and cancels tickets. :class:`EngineKit` runs it and checks the
rules written once in :mod:`starterbus.core.engine`:

- every ticket ends exactly once, and is completed once (every ticket ends once the time runs on);
- a completed value answers its own request (a late or repeated reply never completes a later ticket);
- ``deadline`` moves forward after ``advance(deadline)`` (no busy loop), and the time never goes back;
- the same inputs give the same outputs and completions (replay).

A plugin's test::

    kit = EngineKit(lambda: MyEngine(timeout=0.1), lambda n: MyRequest(n), MyPeer())

    @given(schedules())
    def test_my_engine_keeps_the_rules(schedule: list[Step]) -> None:
        kit.check(schedule)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

from hypothesis import strategies as st

from starterbus.core.engine import Engine, Ticket, TicketState

__all__ = ["EngineKit", "Peer", "Step", "Transcript", "schedules"]

Req = TypeVar("Req")
Res = TypeVar("Res")
Unit = TypeVar("Unit")
Req_contra = TypeVar("Req_contra", contravariant=True)
Res_contra = TypeVar("Res_contra", contravariant=True)

#: what a schedule can do next
ACTIONS = ("submit", "deliver", "repeat", "nothing", "wait", "deadline", "cancel")


class Peer(Protocol[Req_contra, Res_contra, Unit]):
    """The far end, scripted: its replies to one written unit, and whether a result answers a request."""

    def replies(self, unit: Unit) -> list[Unit]: ...

    def answers(self, request: Req_contra, result: Res_contra) -> bool: ...


@dataclass(frozen=True, slots=True)
class Step:
    """One step of a schedule: ``action`` (one of :data:`ACTIONS`) and a number that picks what it acts on
    (which reply, which ticket) or how long it waits (in thousandths of ``EngineKit.scale``)."""

    action: str
    pick: int = 0


def schedules(max_size: int = 60) -> st.SearchStrategy[list[Step]]:
    """Schedules of up to ``max_size`` steps."""
    step = st.builds(Step, st.sampled_from(ACTIONS), st.integers(0, 3000))
    return st.lists(step, max_size=max_size)


@dataclass(slots=True)
class Transcript:
    """The inputs an engine was given, and what it gave: a replay must give the same."""

    inputs: list[tuple[str, float, object]] = field(default_factory=list)
    outputs: list[tuple[float, tuple[object, ...]]] = field(default_factory=list)
    completions: list[tuple[int, str, object, str]] = field(default_factory=list)


class EngineKit(Generic[Req, Res, Unit]):
    """Runs schedules on fresh engines (``make_engine``); request ``n`` of a run is ``make_request(n)``.
    ``scale``: the engine's time scale in seconds (its timeout): waits are drawn up to 3 of it."""

    def __init__(
        self,
        make_engine: Callable[[], Engine[Req, Res, Unit]],
        make_request: Callable[[int], Req],
        peer: Peer[Req, Res, Unit],
        scale: float = 1.0,
        drain_steps: int = 10_000,
    ) -> None:
        self.make_engine = make_engine
        self.make_request = make_request
        self.peer = peer
        self.scale = scale
        self.drain_steps = drain_steps

    def check(self, schedule: Sequence[Step]) -> Transcript:
        """Run ``schedule``, then the time on until every ticket has ended; then replay it."""
        transcript = self.run(schedule)
        self.replay(transcript)
        return transcript

    def run(self, schedule: Sequence[Step]) -> Transcript:
        run = _Run(self, self.make_engine())
        for step in schedule:
            run.do(step)
        run.drain()
        return run.transcript

    def replay(self, transcript: Transcript) -> None:
        """The recorded inputs on a fresh engine give the recorded outputs and completions."""
        engine = self.make_engine()
        again = Transcript()
        tickets: list[Ticket[Req, Res]] = []
        for op, now, argument in transcript.inputs:
            if op == "submit":
                tickets.append(engine.submit(argument, now))  # type: ignore[arg-type]
            elif op == "receive":
                engine.receive(argument, now)  # type: ignore[arg-type]
            elif op == "advance":
                engine.advance(now)
            elif op == "cancel":
                engine.cancel(tickets[argument], now)  # type: ignore[call-overload]
            elif op == "take":
                again.outputs.append((now, tuple(engine.take_output(now))))
            _record(engine, tickets, again)
        assert again.outputs == transcript.outputs, "replayed, the engine wrote something else"
        assert again.completions == transcript.completions, "replayed, the engine completed something else"


class _Run(Generic[Req, Res, Unit]):
    def __init__(self, kit: EngineKit[Req, Res, Unit], engine: Engine[Req, Res, Unit]) -> None:
        self.kit = kit
        self.engine = engine
        self.now = 0.0
        self.tickets: list[Ticket[Req, Res]] = []
        self.replies: list[Unit] = []  # written by the peer, not yet delivered
        self.delivered: list[Unit] = []
        self.transcript = Transcript()

    def do(self, step: Step) -> None:
        engine, pick = self.engine, step.pick
        if step.action == "submit":
            request = self.kit.make_request(len(self.tickets))
            self.tickets.append(engine.submit(request, self.now))
            self._input("submit", request)
        elif step.action == "deliver" and self.replies:
            unit = self.replies.pop(pick % len(self.replies))
            self.delivered.append(unit)
            self._receive(unit)
        elif step.action == "repeat" and self.delivered:
            self._receive(self.delivered[pick % len(self.delivered)])  # a duplicate, or a late copy
        elif step.action == "nothing":
            engine.receive(None, self.now)
            self._input("receive", None)
        elif step.action == "wait":
            self._to(self.now + pick / 1000 * self.kit.scale)
        elif step.action == "deadline":
            self._to_deadline()
        elif step.action == "cancel" and self.tickets:
            index = pick % len(self.tickets)
            ticket = self.tickets[index]
            if not ticket.ended:
                engine.cancel(ticket, self.now)
                self._input("cancel", index)
        self._write()

    def drain(self) -> None:
        """The time runs on, the peer answers nothing more: every ticket must end."""
        self.replies.clear()
        for _ in range(self.kit.drain_steps):
            if all(t.ended for t in self.tickets):
                return
            if math.isinf(self.engine.deadline):
                break
            self._to_deadline()
            self._write(answer=False)
        open_ = [t for t in self.tickets if not t.ended]
        raise AssertionError(f"{len(open_)} ticket(s) never ended (deadline {self.engine.deadline}): {open_[:3]}")

    def _to_deadline(self) -> None:
        deadline = self.engine.deadline
        if math.isinf(deadline):
            return
        self._to(max(self.now, deadline))
        self._write()
        assert self.engine.deadline > self.now or math.isinf(self.engine.deadline), (
            f"deadline {self.engine.deadline} not moved past {self.now} by advance(): a busy loop"
        )

    def _to(self, now: float) -> None:
        assert now >= self.now
        self.now = now
        self.engine.advance(now)
        self._input("advance", None)

    def _receive(self, unit: Unit) -> None:
        self.engine.receive(unit, self.now)
        self._input("receive", unit)

    def _write(self, answer: bool = True) -> None:
        out = tuple(self.engine.take_output(self.now))
        self.transcript.inputs.append(("take", self.now, None))
        self.transcript.outputs.append((self.now, out))
        self._check()
        if answer:
            for unit in out:
                self.replies.extend(self.kit.peer.replies(unit))

    def _input(self, op: str, argument: object) -> None:
        self.transcript.inputs.append((op, self.now, argument))
        self._check()

    def _check(self) -> None:
        before = len(self.transcript.completions)
        _record(self.engine, self.tickets, self.transcript)
        for index, state, result, _ in self.transcript.completions[before:]:
            ticket = self.tickets[index]
            if state == TicketState.DONE.value:
                assert self.kit.peer.answers(ticket.request, result), (  # type: ignore[arg-type]
                    f"ticket {index} ({ticket.request!r}) completed with {result!r}, which does not answer it"
                )


def _record(engine: Engine[Any, Any, Any], tickets: list[Ticket[Any, Any]], transcript: Transcript) -> None:
    """Take the completed tickets: each ended, each one of ours, each once."""
    seen = {index for index, _, _, _ in transcript.completions}
    for ticket in engine.take_completed():
        assert ticket.ended, f"{ticket!r} completed but not ended"
        index = next((i for i, t in enumerate(tickets) if t is ticket), None)
        assert index is not None, f"{ticket!r} completed but never submitted"
        assert index not in seen, f"ticket {index} completed twice"
        seen.add(index)
        transcript.completions.append((index, ticket.state.value, ticket.result, str(ticket.error or "")))
