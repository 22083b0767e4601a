"""Stale PKW answers: a timed-out task, a slow slave or a lagging/replaying gateway never lends an answer to
another task (issue 11, item 2). Transcripts against the sans-IO engine, property tests over random schedules
in which every value encodes the slave's execution it belongs to, and a few runs through the cycle driver."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from starterbus.core.errors import DecodeError, TimeoutError
from starterbus.core.model import Kind as PointKind
from starterbus.core.profile import Profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.profibus_pkw.channels import Channel, SimChannel, Snapshot
from starterbus.transports.profibus_pkw.handshake import JobState, Limits, PkwEngine, PkwError, PkwJob
from starterbus.transports.profibus_pkw.link import CyclicLink
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave
from starterbus.transports.profibus_pkw.telegram import (
    NO_RESPONSE,
    NO_TASK,
    PkwRequest,
    PkwResponse,
    TaskCode,
    pkw_request,
    pkw_response,
)

READ_P3 = pkw_request(TaskCode.READ_PARAMETER, 3)
READ_M3 = pkw_request(TaskCode.READ_MEASUREMENT, 3)
READ_P4 = pkw_request(TaskCode.READ_PARAMETER, 4)
WRITE_P3 = pkw_request(TaskCode.WRITE_PARAMETER, 3, 20)
FENCE_P4 = READ_P4  # the fence after a timeout on INDL 3 reads the last INDL answered (4) or the next one


def r(code: int, indl: int = 0, pwe: int = 0) -> PkwResponse:
    return pkw_response(code, indl, pwe)


def run(engine: PkwEngine, script: Sequence[tuple[PkwRequest, PkwResponse]], t0: float = 0.0) -> None:
    """Feed a transcript: each row is (what the engine must send, what the input shows in that cycle)."""
    for n, (expected, shown) in enumerate(script):
        sent = engine.output(t0 + n * 0.001)
        assert sent == expected, f"cycle {n}: sent {sent}, expected {expected}"
        engine.receive(shown, t0 + n * 0.001)


def state(job: PkwJob) -> JobState:
    return job.state


def answer(job: PkwJob) -> PkwResponse | None:
    """The job's response now (a call, so that type checkers do not narrow it between cycles)."""
    return job.response


def timed_out_read_p3(engine: PkwEngine) -> PkwJob:
    """Read p4 answered, then a read of p3 that times out (after max_cycles) while the slave works on it."""
    run(engine, [(NO_TASK, NO_RESPONSE)])
    first = engine.submit(READ_P4)
    run(engine, [(READ_P4, r(1, 4, 40)), (NO_TASK, NO_RESPONSE)])
    assert first.response == r(1, 4, 40)
    job = engine.submit(READ_P3)
    run(engine, [(READ_P3, NO_RESPONSE)] * engine.limits.max_cycles)
    assert isinstance(job.error, TimeoutError) and engine.quarantined(3)
    return job


# -- transcripts ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("task", [READ_P3, READ_M3, WRITE_P3], ids=["read-p3", "read-m3", "write-p3"])
def test_the_late_answer_of_a_timed_out_read_is_never_taken_by_the_next_task_on_its_indl(task: PkwRequest) -> None:
    # The three scenarios: the slave answers the timed-out read of p3 (12) only after the master moved on.
    # The old rule took "no response" as proof and sent the task; the late "01 03 00 0C" then answered it.
    engine = PkwEngine(limits=Limits(max_cycles=8, timeout=100))
    timed_out_read_p3(engine)
    job = engine.submit(task)
    late = r(1, 3, 12)
    fresh = r(1, 3, task.pwe if task.task == TaskCode.WRITE_PARAMETER else 77)
    run(
        engine,
        [
            (FENCE_P4, NO_RESPONSE),  # "no response" proves nothing: INDL 3 is quarantined, a fence read starts
            (FENCE_P4, late),  # the slave finally answers the old read: a value for nobody
            (FENCE_P4, r(1, 4, 41)),  # the fence is answered: the slave has left the old read behind
            (NO_TASK, NO_RESPONSE),
            (task, NO_RESPONSE),
        ],
    )
    assert state(job) is JobState.SENDING and answer(job) is None and job.fences == 1
    run(engine, [(task, fresh)])
    assert answer(job) == fresh and not engine.quarantined(3)


def test_a_slave_that_dropped_the_old_task_costs_one_fence_read() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=8, timeout=100))
    timed_out_read_p3(engine)
    job = engine.submit(READ_M3)
    run(engine, [(FENCE_P4, NO_RESPONSE), (FENCE_P4, r(1, 4, 41)), (NO_TASK, NO_RESPONSE), (READ_M3, r(1, 3, 612))])
    assert job.response == r(1, 3, 612) and job.cycles == 4


def test_a_refused_fence_is_verification_too() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=8, timeout=100))
    timed_out_read_p3(engine)
    job = engine.submit(READ_P3)
    run(engine, [(FENCE_P4, r(3, 4, 0)), (NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 15))])
    assert job.response == r(1, 3, 15)


def test_the_orphans_own_late_answer_then_no_response_also_lifts_the_quarantine() -> None:
    # No fence is possible when the fence's own INDL is not yet fresh; the late answer resolves the orphan.
    engine = PkwEngine(limits=Limits(max_cycles=4, timeout=100))
    job = engine.submit(READ_P3)
    run(engine, [(NO_TASK, NO_RESPONSE)] + [(READ_P3, NO_RESPONSE)] * 3)
    assert isinstance(job.error, TimeoutError) and engine.quarantined(3)
    engine.output(1.0)  # idle: the late answer shows while no job runs
    engine.receive(r(1, 3, 12), 1.0)
    assert not engine.quarantined(3)
    nxt = engine.submit(READ_P3)
    run(engine, [(NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 15))], t0=2.0)
    assert nxt.response == r(1, 3, 15) and nxt.fences == 0


def test_a_job_still_quarantined_at_its_limit_says_so() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=4, timeout=100))
    timed_out_read_p3(engine)
    job = engine.submit(READ_M3)
    run(engine, [(FENCE_P4, NO_RESPONSE)] * 4)
    assert isinstance(job.error, TimeoutError)
    assert "INDL 0x03 is quarantined" in str(job.error) and "01 03 00 00" in str(job.error)
    assert "1 fence read(s)" in str(job.error)
    assert engine.quarantined(3) and engine.quarantined(4)  # the unanswered fence is an orphan too
    nxt = engine.submit(READ_P4)  # INDL 4 blocked as well: its fence reads INDL 5
    run(engine, [(pkw_request(1, 5), r(3, 5, 0)), (NO_TASK, NO_RESPONSE), (READ_P4, r(1, 4, 42))])
    assert nxt.response == r(1, 4, 42) and not engine.quarantined(3)


def test_a_gateway_that_replays_the_previous_input_after_no_response() -> None:
    # The replay: "01 03 00 0C" (p3), then "no response", then the p3 answer again while m3 is asked.
    # With stale_cycles=1 "no response" must be fresh after the p3 answer, and m3's answer fresh after that.
    engine = PkwEngine(limits=Limits(max_cycles=20, timeout=100, stale_cycles=1))
    run(engine, [(NO_TASK, NO_RESPONSE)])
    engine.submit(READ_P3)
    m3 = engine.submit(READ_M3)
    old = r(1, 3, 12)
    run(
        engine,
        [
            (NO_TASK, NO_RESPONSE),  # the idle cycle's "no response" was not fresh after the start; this one is
            (READ_P3, old),  # not fresh after the proof yet: could be older than the task
            (READ_P3, old),  # p3 answered
            (NO_TASK, NO_RESPONSE),  # too close to the answer to prove the slave went on
            (NO_TASK, old),  # the replay
            (NO_TASK, NO_RESPONSE),  # fresh: the clear is proven
            (READ_M3, old),  # replayed again: not fresh after the clear, ignored
            (READ_M3, r(1, 3, 612)),
        ],
    )
    assert m3.response == r(1, 3, 612) and m3.stale == 1


def test_without_a_margin_a_replayed_answer_is_taken() -> None:
    # The boundary of the rule: with stale_cycles=0 the engine trusts that the input is never older than the
    # exchange; a gateway that replays must be configured with its margin (the gateway channel's default is 1).
    engine = PkwEngine(limits=Limits(max_cycles=20, timeout=100))
    engine.submit(READ_P3)
    m3 = engine.submit(READ_M3)
    run(engine, [(NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 12)), (NO_TASK, NO_RESPONSE), (READ_M3, r(1, 3, 12))])
    assert m3.response == r(1, 3, 12)


def test_the_time_margin_counts_too() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=1000, timeout=100, stale_cycles=0, stale_time=0.05))
    job = engine.submit(READ_P3)
    for t in (0.0, 0.02, 0.04):  # "no response" within 50 ms of the start proves nothing
        assert engine.output(t) == NO_TASK
        engine.receive(NO_RESPONSE, t)
    assert engine.output(0.06) == NO_TASK
    engine.receive(NO_RESPONSE, 0.06)  # fresh: 60 ms after the start
    for t in (0.07, 0.1):  # an answer within 50 ms of the proof may be older than the task
        assert engine.output(t) == READ_P3
        engine.receive(r(1, 3, 12), t)
    assert job.stale == 2 and not job.done
    engine.output(0.12)
    engine.receive(r(1, 3, 12), 0.12)
    assert job.response == r(1, 3, 12)


def test_a_write_echo_of_another_value_is_not_the_answer() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=4, timeout=100))
    job = engine.submit(WRITE_P3)
    run(engine, [(NO_TASK, NO_RESPONSE), (WRITE_P3, r(1, 3, 12)), (WRITE_P3, r(1, 3, 20))])
    assert job.response == r(1, 3, 20) and job.mismatched == 1


def test_a_write_never_echoed_fails_typed_naming_what_was_shown() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=3, timeout=100))
    job = engine.submit(WRITE_P3)
    run(engine, [(NO_TASK, NO_RESPONSE), (WRITE_P3, r(1, 3, 12)), (WRITE_P3, r(1, 3, 12))])
    assert isinstance(job.error, DecodeError) and job.error.data == bytes.fromhex("01 03 00 0C")
    assert "does not echo the task [02 03 00 14]" in str(job.error)
    assert engine.quarantined(3)  # no verified answer


# -- property tests: random slaves and gateways, every value names its execution ----------------------------------


@dataclass
class OrderedSlave:
    """A slow but ordered slave: it takes the master's outputs in order, each response showing after its delay.

    Every execution gets an id; a read answers it as the value (or error number), so a returned value names the
    execution, and the master's output log tells which job that output belonged to."""

    delays: deque[int]
    refusals: deque[bool]
    drop: bool  # a newer output discards responses not yet shown (else they show in order)
    shown: PkwResponse = NO_RESPONSE
    last: PkwRequest | None = None
    queue: deque[tuple[int, PkwResponse]] = field(default_factory=deque)
    execs: list[tuple[PkwRequest, int]] = field(default_factory=list)  # id -> (request, exchange)

    def step(self, k: int, out: PkwRequest) -> PkwResponse:
        if out != self.last:
            self.last = out
            delay = self.delays[0]
            self.delays.rotate(-1)
            if self.drop:
                self.queue.clear()
            ready = max([k + delay] + [q[0] for q in self.queue])
            self.queue.append((ready, self._answer(out, k)))
        while self.queue and self.queue[0][0] <= k:
            self.shown = self.queue.popleft()[1]
        return self.shown

    def _answer(self, out: PkwRequest, k: int) -> PkwResponse:
        if out.task == TaskCode.NO_TASK:
            return NO_RESPONSE
        ident = len(self.execs)
        self.execs.append((out, k))
        refuse = self.refusals[0]
        self.refusals.rotate(-1)
        if refuse:
            return r(2 if out.task == TaskCode.WRITE_PARAMETER and ident % 2 else 3, out.indl, ident)
        return r(1, out.indl, out.pwe if out.task == TaskCode.WRITE_PARAMETER else ident)


def drive(
    jobs: list[PkwRequest],
    slave: OrderedSlave,
    lag: Callable[[int], int],
    limits: Limits,
    *,
    monotonic: bool,
    clock: Callable[[int], float] = lambda k: k * 0.001,
) -> tuple[list[PkwJob], dict[int, PkwJob]]:
    """Run the engine against the slave through an input that lags by ``lag(k)`` exchanges (``monotonic``:
    never showing an older image than before, else any image within the lag: jitter and replays); exchange
    ``k`` happens at ``clock(k)``."""
    engine = PkwEngine(limits=limits)
    submitted = [engine.submit(request, f"job {i}") for i, request in enumerate(jobs)]
    shown: list[PkwResponse] = []
    sent_by: dict[int, PkwJob] = {}
    seen = 0
    for k in range(len(jobs) * limits.max_cycles + 20):
        if not engine.busy:
            break
        out = engine.output(clock(k))
        current = engine.current
        if current is not None and current.state is JobState.SENDING:
            sent_by[k] = current
        shown.append(slave.step(k, out))
        seen = max(seen, k - lag(k)) if monotonic else max(0, k - lag(k))
        engine.receive(shown[seen], clock(k))
    assert not engine.busy
    return submitted, sent_by


def check(submitted: list[PkwJob], sent_by: dict[int, PkwJob], slave: OrderedSlave) -> None:
    """No value (or error number) ever returned belongs to another job."""
    for job in submitted:
        if job.response is None:
            assert isinstance(job.error, TimeoutError | DecodeError), job.error
            continue
        pwe = job.response.pwe
        if job.request.task == TaskCode.WRITE_PARAMETER and job.response.ind >> 8 == 1:
            assert pwe == job.request.pwe  # unique per job; the slave must have executed this job's write
            assert any(req == job.request and sent_by.get(k) is job for req, k in slave.execs)
            continue
        request, k = slave.execs[pwe]
        assert request == job.request and sent_by.get(k) is job, f"{job.describe()} got execution {pwe}"
        assert (job.error is None) == (job.response.ind >> 8 == 1)
        assert job.error is None or isinstance(job.error, PkwError)


TASKS = st.sampled_from(["p3", "m3", "p4", "w3"])


def requests(names: list[str]) -> list[PkwRequest]:
    out = []
    for i, name in enumerate(names):
        if name == "w3":
            out.append(pkw_request(TaskCode.WRITE_PARAMETER, 3, 40000 + i))  # unique per job, no execution id
        else:
            out.append({"p3": READ_P3, "m3": READ_M3, "p4": READ_P4}[name])
    return out


SCHEDULES = dict(
    names=st.lists(TASKS, min_size=1, max_size=12),
    delays=st.lists(st.integers(0, 14), min_size=1, max_size=12),
    refusals=st.lists(st.booleans(), min_size=1, max_size=6),
    drop=st.booleans(),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lags=st.lists(st.integers(0, 3), min_size=1, max_size=12), margin=st.integers(0, 3), **SCHEDULES)
def test_no_value_belongs_to_another_task_with_jitter_and_replays(
    names: list[str], delays: list[int], refusals: list[bool], drop: bool, lags: list[int], margin: int
) -> None:
    # Inputs up to `margin` exchanges old, in any order; the engine is told that margin.
    slave = OrderedSlave(deque(delays), deque(refusals), drop)
    limits = Limits(max_cycles=10, timeout=1e9, stale_cycles=margin)
    submitted, sent_by = drive(
        requests(names), slave, lambda k: min(lags[k % len(lags)], margin), limits, monotonic=False
    )
    check(submitted, sent_by, slave)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    steps=st.lists(st.sampled_from([0.0005, 0.001, 0.004, 0.02]), min_size=1, max_size=12),
    lags=st.lists(st.integers(0, 40), min_size=1, max_size=12),
    **SCHEDULES,
)
def test_no_value_belongs_to_another_task_with_a_time_margin(
    names: list[str], delays: list[int], refusals: list[bool], drop: bool, steps: list[float], lags: list[int]
) -> None:
    # Exchanges at irregular times; the input may be any image up to 10 ms old, however many exchanges that is
    # (a gateway that we poll faster than it cycles); the engine is told stale_time=0.01 and no cycle margin.
    times = [0.0]
    for k in range(1, len(names) * 10 + 21):
        times.append(times[-1] + steps[k % len(steps)])

    def lag(k: int) -> int:
        back = min(lags[k % len(lags)], k)
        while back and times[k] - times[k - back] > 0.01:
            back -= 1
        return back

    slave = OrderedSlave(deque(delays), deque(refusals), drop)
    limits = Limits(max_cycles=10, timeout=1e9, stale_time=0.01)
    submitted, sent_by = drive(requests(names), slave, lag, limits, monotonic=False, clock=lambda k: times[k])
    check(submitted, sent_by, slave)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lags=st.lists(st.integers(0, 8), min_size=1, max_size=12), **SCHEDULES)
def test_no_value_belongs_to_another_task_with_a_lagging_gateway(
    names: list[str], delays: list[int], refusals: list[bool], drop: bool, lags: list[int]
) -> None:
    # A gateway whose image lags by a varying number of exchanges but never goes back: no margin needed.
    slave = OrderedSlave(deque(delays), deque(refusals), drop)
    limits = Limits(max_cycles=10, timeout=1e9)
    submitted, sent_by = drive(requests(names), slave, lambda k: lags[k % len(lags)], limits, monotonic=True)
    check(submitted, sent_by, slave)


def test_a_prompt_slave_answers_every_job() -> None:
    # The property tests above must not pass by timing everything out: with no delay and no lag all succeed.
    names = ["p3", "p3", "m3", "w3", "p4", "m3", "w3", "p3"]
    slave = OrderedSlave(deque([0]), deque([False]), False)
    submitted, sent_by = drive(requests(names), slave, lambda k: 0, Limits(max_cycles=10, timeout=1e9), monotonic=True)
    check(submitted, sent_by, slave)
    assert all(job.error is None for job in submitted)
    assert [job.cycles for job in submitted] == [2] * len(names)


# -- through the cycle driver: the simulated slave behind fault-injecting channels --------------------------------


class StaleInputChannel(Channel):
    """Wraps a channel; returns the input of ``lag(k)`` exchanges ago (``replay_after_clear``: after an input
    showing "no response", the next exchange returns the input before it once, as the issue's gateway did)."""

    def __init__(
        self, inner: Channel, lag: Callable[[int], int] = lambda k: 0, *, replay_after_clear: bool = False
    ) -> None:
        self.inner = inner
        self.ppo = inner.ppo
        self.lag = lag
        self.replay_after_clear = replay_after_clear
        self.history: list[tuple[int, ...]] = []
        self.returned: list[tuple[int, ...]] = []
        self.replays = 0

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        self.history.append(self.inner.exchange(out_words))
        k = len(self.history) - 1
        words = self.history[max(0, k - self.lag(k))]
        last = self.returned[-2:]
        if self.replay_after_clear and len(last) == 2 and last[1][0] == 0 and last[0][0] != 0:
            words = last[0]
            self.replays += 1
        self.returned.append(words)
        return words

    def snapshot(self) -> Snapshot:
        return self.inner.snapshot()


def starter_link(
    profile: Profile, limits: Limits, *, latency: int = 0, wrap: Callable[[Channel], Channel] = lambda c: c
) -> tuple[CyclicLink, SimulatedDpSlave, SimulatedStarter]:
    starter = SimulatedStarter(profile, values={"ramp_time": 12})
    slave = SimulatedDpSlave(starter, latency=latency)
    link = CyclicLink(wrap(SimChannel(slave)), PkwEngine(limits=limits), cycle=0)
    link.open()
    return link, slave, starter


@pytest.mark.parametrize("task", [READ_P3, READ_M3, WRITE_P3], ids=["read-p3", "read-m3", "write-p3"])
def test_after_a_timed_out_read_the_next_task_gets_its_own_answer(jjr8000: Profile, task: PkwRequest) -> None:
    # The simulated slave answers 40 exchanges late (in order); the read of p3 gives up after 30.
    link, slave, starter = starter_link(jjr8000, Limits(max_cycles=30, timeout=100), latency=40)
    try:
        with pytest.raises(TimeoutError):
            link.pkw(READ_P3)
        slave.latency = 0  # from now on prompt; the old read's answer (12) still shows first
        p3 = starter.point_at("profibus", PointKind.PARAMETER, 3)
        starter.write(p3, 15)
        job = link.pkw(task)
        assert job.response is not None
        expected = {READ_P3: 15, READ_M3: 0, WRITE_P3: 20}[task]  # m3 of a stopped motor: 0 A
        assert job.response.pwe == expected and job.fences == 1
        if task == WRITE_P3:
            assert starter.read(p3) == 20
    finally:
        link.close()


def test_a_replaying_gateway_never_lends_p3_to_m3(jjr8000: Profile) -> None:
    replaying: list[StaleInputChannel] = []

    def wrap(channel: Channel) -> Channel:
        replaying.append(StaleInputChannel(channel, replay_after_clear=True))
        return replaying[0]

    link, _, _ = starter_link(jjr8000, Limits(max_cycles=30, timeout=100, stale_cycles=1), wrap=wrap)
    try:
        for _ in range(20):
            p3, m3 = link.pkw(READ_P3), link.pkw(READ_M3)
            assert p3.response is not None and p3.response.pwe == 12
            assert m3.response is not None and m3.response.pwe == 0
        assert replaying[0].replays >= 20  # the gateway did replay the p3 answer
    finally:
        link.close()


def test_a_jittering_gateway_within_the_margin(jjr8000: Profile) -> None:
    lags = [0, 2, 1, 0, 2, 2, 0, 1]
    link, _, starter = starter_link(
        jjr8000,
        Limits(max_cycles=40, timeout=100, stale_cycles=2),
        wrap=lambda c: StaleInputChannel(c, lambda k: lags[k % len(lags)]),
    )
    p3 = starter.point_at("profibus", PointKind.PARAMETER, 3)
    try:
        for value in range(13, 33):
            starter.write(p3, value)  # every read must see the value of its own moment
            read = link.pkw(READ_P3)
            assert read.response is not None and read.response.pwe == value
            m3 = link.pkw(READ_M3)
            assert m3.response is not None and m3.response.pwe == 0
    finally:
        link.close()


def test_the_gateway_url_carries_the_margin(jjr8000: Profile) -> None:
    from starterbus.core.url import DeviceUrl
    from starterbus.transports.profibus_pkw.transport import LinkSettings

    gateway = LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+gateway://127.0.0.1:1502"), jjr8000)
    assert (gateway.limits.stale_cycles, gateway.limits.stale_time) == (1, 0.0)
    sim = LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+sim://?stale_cycles=3&stale_time=0.02"), jjr8000)
    assert (sim.limits.stale_cycles, sim.limits.stale_time) == (3, 0.02)
