"""The PKW station's StationEngine through the engine kit: an exchange's answer is told by the number of the
exchange it answers, so a late or repeated one is stray and never reaches the PKW engine's freshness proofs; and
transcripts of the cycle driver's rules (PZD on every exchange, a command's plan, fresh inputs, the cycle)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest
from hypothesis import given, settings

from starterbus.core.engine import TicketState
from starterbus.core.errors import TimeoutError, TransportError
from starterbus.core.profile import Profile
from starterbus.core.simulator import Phase, SimulatedStarter
from starterbus.testing.engines import EngineKit, Step, schedules
from starterbus.transports.profibus_pkw.codec.codes import Ppo, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import PkwResponse, pkw_request
from starterbus.transports.profibus_pkw.driver.channels import SimChannel
from starterbus.transports.profibus_pkw.driver.link import CyclicLink
from starterbus.transports.profibus_pkw.master.handshake import Limits, PkwEngine
from starterbus.transports.profibus_pkw.master.station import (
    ControlWords,
    DpOut,
    FreshInputs,
    PkwTask,
    StationEngine,
    StationRequest,
)
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

LIMITS = Limits(max_cycles=20, timeout=0.5)


def request(n: int) -> StationRequest:
    """Request ``n``: reads and writes of INDL 1..7, fresh inputs and commands, in turn."""
    kind = n % 4
    if kind == 0:
        return PkwTask(pkw_request(TaskCode.READ_PARAMETER, 1 + n % 7))
    if kind == 1:
        return FreshInputs(0.5)
    if kind == 2:
        return ControlWords((0x000C, 0x0008 | (n & 1)), 0.5)
    return PkwTask(pkw_request(TaskCode.WRITE_PARAMETER, 1 + n % 7, n))


class Slave:
    """An ordered, prompt slave: a read of INDL i is answered with 1000 + i, a write with its echo; the status
    word echoes the control word received."""

    def replies(self, unit: DpOut) -> list[DpOut]:
        n, (ind, pwe, stw, _) = unit
        assert ind is not None and pwe is not None
        task, indl = ind >> 8, ind & 0xFF
        if task == 0:
            answer = (0, 0)
        elif task == TaskCode.WRITE_PARAMETER:
            answer = (0x0100 | indl, pwe)
        else:
            answer = (0x0100 | indl, 1000 + indl)
        return [(n, (*answer, stw or 0, 0))]

    def answers(self, request: StationRequest, result: object) -> bool:
        if isinstance(request, PkwTask):
            assert isinstance(result, PkwResponse)
            task = request.request
            expected = task.pwe if task.task == TaskCode.WRITE_PARAMETER else 1000 + task.indl
            return result.ind & 0xFF == task.indl and result.pwe == expected
        if isinstance(request, FreshInputs):
            return isinstance(result, tuple) and len(result) == 4
        return result is None


def station(cycle: float) -> StationEngine:
    return StationEngine(Ppo.PPO1, PkwEngine(limits=LIMITS), cycle=cycle, hold=2, reply_within=0.05)


ON_DEMAND = EngineKit(lambda: station(0.0), request, Slave(), scale=0.5)
CYCLIC = EngineKit(lambda: station(0.01), request, Slave(), scale=0.5)
#: inputs fresh by time (a gateway's margin): on demand, the station holds back exchanges it could not use
TIMED = Limits(max_cycles=20, timeout=0.5, stale_cycles=1, stale_time=0.002)
ON_DEMAND_TIMED = EngineKit(
    lambda: StationEngine(Ppo.PPO1, PkwEngine(limits=TIMED), cycle=0.0, hold=2, reply_within=0.05),
    request,
    Slave(),
    scale=0.5,
)


@settings(max_examples=150, deadline=None)
@given(schedules())
def test_the_station_engine_on_demand_keeps_every_rule(schedule: list[Step]) -> None:
    ON_DEMAND.check(schedule)


@settings(max_examples=150, deadline=None)
@given(schedules())
def test_the_station_engine_cycling_keeps_every_rule(schedule: list[Step]) -> None:
    CYCLIC.check(schedule)


@settings(max_examples=150, deadline=None)
@given(schedules())
def test_the_station_engine_on_demand_with_a_time_margin_keeps_every_rule(schedule: list[Step]) -> None:
    ON_DEMAND_TIMED.check(schedule)


def test_on_demand_a_read_on_the_same_index_skips_the_exchanges_it_could_not_use() -> None:
    """p3 read again and again with a 2 ms margin (stale_cycles=1), each exchange answered 0.5 ms after it
    starts: "no task" goes out at once, the "no response" that starts the task is asked for so that it comes
    after the margin, the task goes out at once, its answer is asked for so that it comes after the margin: four
    exchanges a read, none of them spent on an input that could not be used, every answer fresh (the engine
    keeps its rule: an earlier exchange is never asked for, the margin decides what is accepted)."""
    engine = StationEngine(Ppo.PPO1, PkwEngine(limits=TIMED), cycle=0.0, hold=2, reply_within=0.05)
    p3 = pkw_request(TaskCode.READ_PARAMETER, 3)
    now, rtt = 0.0, 0.0005
    for _ in range(4):
        ticket = engine.submit(PkwTask(p3), now)
        before = engine.attempts
        while not ticket.ended:
            now = max(now, engine.deadline)
            engine.advance(now)
            (unit,) = engine.take_output(now)
            (reply,) = Slave().replies(unit)
            now += rtt
            engine.receive(reply, now)
            engine.take_completed()
        assert ticket.state is TicketState.DONE and ticket.result == PkwResponse(0x0103, 1003)
        assert engine.attempts - before == 4  # the first read too: an unused INDL counts as answered at the start


def exchange(engine: StationEngine, now: float, slave: Slave | None = None) -> DpOut:
    (unit,) = engine.take_output(now)
    (reply,) = (slave or Slave()).replies(unit)
    engine.receive(reply, now)
    return unit


def test_a_read_is_a_clear_then_the_task_with_the_control_word_on_both() -> None:
    engine = station(0.0)
    engine.adopt((0, 0, 0x0009, 0), (0, 0, 0x0900, 0))
    ticket = engine.submit(request(0), 0.0)
    assert engine.deadline == 0.0  # on demand: due while a ticket waits
    assert exchange(engine, 0.0) == (1, (0, 0, 0x0009, 0))
    assert exchange(engine, 0.001) == (2, (0x0101, 0, 0x0009, 0))
    assert engine.take_completed() == [ticket] and ticket.state is TicketState.DONE
    assert engine.take_output(0.002) == () and engine.deadline == float("inf")  # nothing waits: no exchange


def test_a_late_answer_is_stray_and_never_an_input() -> None:
    engine = station(0.0)
    fresh = engine.submit(FreshInputs(0.5), 0.0)
    (unit,) = engine.take_output(0.0)
    engine.advance(0.06)  # not answered within reply_within: the exchange failed
    assert fresh.state is TicketState.FAILED and isinstance(fresh.error, TransportError)
    (late,) = Slave().replies(unit)
    engine.receive(late, 0.07)
    assert engine.stray == 1 and engine.exchanges == 0 and engine.last_in is None


def test_a_command_plan_holds_each_word_and_a_newer_command_supersedes_it() -> None:
    engine = station(0.0)
    first = engine.submit(ControlWords((0x000C, 0x0008)), 0.0)
    words = [exchange(engine, 0.001 * i)[1][2] for i in range(2)]
    second = engine.submit(ControlWords((0x0009,)), 0.01)
    assert first.state is TicketState.DONE  # superseded: its caller returns, the newer word is in force
    words += [exchange(engine, 0.02 + 0.001 * i)[1][2] for i in range(2)]
    assert words == [0x000C, 0x000C, 0x0009, 0x0009] and second.state is TicketState.DONE
    assert engine.control == 0x0009


def test_a_command_cancelled_before_it_went_out_leaves_the_word_in_force() -> None:
    engine = station(0.0)
    engine.adopt(None, (0, 0, 0x0900, 0))  # passive: the word in the output area is another master's
    ticket = engine.submit(ControlWords((0x0009,)), 0.0)
    engine.cancel(ticket, 0.0)
    assert ticket.state is TicketState.CANCELLED and engine.control is None
    engine.submit(FreshInputs(0.5), 0.0)
    assert exchange(engine, 0.0)[1][2:] == (None, None)  # still passive: nothing written to PZD


def test_cycling_exchanges_every_cycle_and_a_command_times_out_on_a_failing_peer() -> None:
    engine = station(0.01)
    assert engine.take_output(0.0)  # the first exchange at once
    engine.refused((1, ()), TransportError("cable pulled"), 0.001)
    assert engine.deadline == pytest.approx(0.01) and engine.take_output(0.005) == ()
    ticket = engine.submit(ControlWords((0x0009,)), 0.005)
    now = 0.0
    while not ticket.ended:
        now = max(now, engine.deadline)
        engine.advance(now)
        for n, _ in engine.take_output(now):
            engine.refused((n, ()), TransportError("cable pulled"), now)
    assert isinstance(ticket.error, TimeoutError) and "cable pulled" in str(ticket.error)
    assert engine.failures > 10 and now == pytest.approx(0.005 + 2.0 + 2 * 0.01)  # timeout + hold x cycle


def test_after_a_defect_the_fresh_engine_leaves_the_control_word_alone(jjr8000: Profile) -> None:
    sent: list[tuple[int | None, ...]] = []

    class Recording(SimChannel):
        def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
            sent.append(tuple(out_words))
            return super().exchange(out_words)

    starter = SimulatedStarter(jjr8000)
    link = CyclicLink(Recording(SimulatedDpSlave(starter)), PkwEngine(), cycle=0)
    link.open()
    try:
        link.send_control([0x0009])
        assert sent[-1][2] == 0x0009 and starter.phase is Phase.STARTING

        def defect(now: float) -> Sequence[DpOut]:
            raise RuntimeError("a bug")

        link.station.take_output = defect  # type: ignore[method-assign]
        with pytest.raises(TransportError, match="RuntimeError: a bug"):
            link.inputs()
        link.inputs()  # a fresh engine: passive on PZD, so the run it gave is not taken back by a 0
        assert sent[-1][2:] == (None, None) and link.control is None and starter.phase is Phase.STARTING
    finally:
        link.close()


@pytest.mark.parametrize(
    ("stale_cycles", "stale_time", "cycle", "first_fresh"),
    [
        (0, 0.0, 0.001, 1),
        (1, 0.0, 0.001, 2),
        (0, 0.0035, 0.001, 5),
        (4, 0.0065, 0.001, 8),
        (0, 0.0, 0.0, 1),
        (1, 0.0, 0.0, 2),
        (0, 0.0035, 0.0, 2),  # on demand: no exchange between the first and the one that can be used
        (4, 0.0065, 0.0, 5),  # the four the count needs, then the one started 6.5 ms after the request
    ],
)
def test_fresh_inputs_come_from_an_exchange_the_staleness_allows(
    stale_cycles: int, stale_time: float, cycle: float, first_fresh: int
) -> None:
    """A gateway's image lags (its own DP cycle): a status read takes the input of an exchange that started more
    than ``stale_cycles`` exchanges and at least ``stale_time`` seconds after the request, never one before. On
    demand the station asks for no input it could not use (it starts no exchange before it is due)."""
    limits = Limits(max_cycles=20, timeout=0.5, stale_cycles=stale_cycles, stale_time=stale_time)
    engine = StationEngine(Ppo.PPO1, PkwEngine(limits=limits), cycle=cycle, hold=2, reply_within=0.05)
    fresh = engine.submit(FreshInputs(0.5), 0.0)
    n = 0
    starts: list[float] = []
    while not fresh.ended:
        n += 1
        assert n <= 10, "fresh inputs never came"
        starts.append(max(0.001 * (n - 1), engine.deadline))  # exchange n at (n - 1) ms, or when it is due
        exchange(engine, starts[-1])
    assert n == first_fresh and fresh.state is TicketState.DONE and fresh.result == engine.last_in
    assert n > stale_cycles and starts[-1] >= stale_time
