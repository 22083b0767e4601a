"""Stale PKW answers, transcripts against the sans-IO engine: a timed-out task, a slow slave or a
lagging/replaying gateway never lends an answer to another task (issue 11, item 2; docs/profibus.md, "Stale
answers"). Property tests: test_pkw_stale_properties.py; through the cycle driver: test_pkw_stale_link.py."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from starterbus.core.errors import DecodeError, TimeoutError
from starterbus.transports.profibus_pkw.codec.codes import TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import (
    NO_RESPONSE,
    NO_TASK,
    PkwRequest,
    PkwResponse,
    pkw_request,
    pkw_response,
)
from starterbus.transports.profibus_pkw.master.handshake import JobState, Limits, PkwEngine, PkwJob

READ_P3 = pkw_request(TaskCode.READ_PARAMETER, 3)
READ_M3 = pkw_request(TaskCode.READ_MEASUREMENT, 3)
READ_P4 = pkw_request(TaskCode.READ_PARAMETER, 4)
READ_P5 = pkw_request(TaskCode.READ_PARAMETER, 5)
READ_P6 = pkw_request(TaskCode.READ_PARAMETER, 6)
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


def test_with_verify_start_the_first_task_of_a_session_waits_for_the_start_chain() -> None:
    # An earlier session left "read p3" on the slave; its answer (12) shows after our session started. With the
    # default inherited=2 the first task waits for three fence reads, each on an INDL of its own.
    engine = PkwEngine(limits=Limits(max_cycles=8, timeout=100, verify_start=True))
    assert engine.quarantined(3) and engine.quarantined(200)  # the unknown past blocks every INDL
    job = engine.submit(READ_P3)
    run(
        engine,
        [
            (NO_TASK, NO_RESPONSE),
            (FENCE_P4, r(1, 3, 12)),  # the earlier session's answer: a value for nobody
            (FENCE_P4, r(1, 4, 40)),  # the first fence answered (perhaps by an earlier session's p4)
            (NO_TASK, NO_RESPONSE),
            (READ_P5, r(1, 5, 50)),
            (NO_TASK, NO_RESPONSE),
            (READ_P6, r(1, 6, 60)),  # the third answer on a third INDL: ours, the chain is complete
        ],
    )
    assert not engine.quarantined(3) and not job.done  # the last fence answer is verified: rule 1 holds
    run(engine, [(NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 15))], t0=1.0)
    assert job.response == r(1, 3, 15) and job.fences == 3 and not engine.quarantined(200)


def test_an_earlier_sessions_read_answering_the_first_fence_lends_nothing_later() -> None:
    # The case the property test found: an earlier session's read of p4 answers our first fence (p4), whose own
    # answer (41) shows later. The chain goes on to p5 and p6; a read of p4 after it takes only a fresh answer.
    engine = PkwEngine(limits=Limits(max_cycles=8, timeout=100, verify_start=True, inherited=1))
    p4 = engine.submit(READ_P4, "read p4")
    p3 = engine.submit(READ_P3, "read p3")
    run(
        engine,
        [
            (NO_TASK, NO_RESPONSE),
            (READ_P5, NO_RESPONSE),
            (READ_P5, r(1, 5, 50)),  # an earlier session's p5 or ours: not known, so one more fence
            (NO_TASK, r(1, 5, 51)),  # the first fence's own answer, late: taken for nothing
            (NO_TASK, NO_RESPONSE),
            (READ_P6, r(1, 6, 60)),
            (NO_TASK, NO_RESPONSE),
            (READ_P4, r(1, 4, 44)),
            (NO_TASK, NO_RESPONSE),
            (READ_P3, r(1, 3, 33)),
        ],
    )
    assert p4.response == r(1, 4, 44) and p4.fences == 2 and p3.response == r(1, 3, 33) and p3.fences == 0


def test_inherited_zero_is_the_single_fence_of_before() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=8, timeout=100, verify_start=True, inherited=0))
    job = engine.submit(READ_P3)
    run(
        engine,
        [(NO_TASK, NO_RESPONSE), (FENCE_P4, r(1, 4, 40)), (NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 15))],
    )
    assert job.response == r(1, 3, 15) and job.fences == 1


@pytest.mark.parametrize("inherited", [-1, 255])
def test_inherited_out_of_range_is_refused(inherited: int) -> None:
    with pytest.raises(ValueError, match="inherited must be 0..254"):
        Limits(inherited=inherited)


def test_with_verify_start_a_slave_that_never_answers_says_nothing_was_verified() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=4, timeout=100, verify_start=True))
    job = engine.submit(READ_M3)
    run(engine, [(NO_TASK, NO_RESPONSE)] + [(FENCE_P4, NO_RESPONSE)] * 4)
    assert isinstance(job.error, TimeoutError)
    assert "nothing has been verifiably answered yet in this session (0 of 3 start fence reads answered)" in str(
        job.error
    )
    assert "limit 4, and 4 for each fence read" in str(job.error)


def test_each_start_fence_has_a_budget_of_its_own() -> None:
    # A slave slower than max_cycles for the whole chain but not for one fence: the first task still succeeds.
    engine = PkwEngine(limits=Limits(max_cycles=4, timeout=100, verify_start=True, inherited=1))
    job = engine.submit(READ_P3)
    run(
        engine,
        [(NO_TASK, NO_RESPONSE)]
        + [(FENCE_P4, NO_RESPONSE)] * 3
        + [(FENCE_P4, r(1, 4, 40))]
        + [(NO_TASK, r(1, 4, 40)), (NO_TASK, NO_RESPONSE), (READ_P5, NO_RESPONSE), (READ_P5, r(1, 5, 50))]
        + [(NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 15))],
    )
    assert job.response == r(1, 3, 15) and job.fences == 2 and (job.cycles, job.fence_cycles) == (11, 8)


def test_a_session_whose_fences_were_all_lost_says_to_reopen() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=2, timeout=100, verify_start=True, inherited=0))
    for indl in range(255):  # each job's fence is lost: every INDL but one gets used up
        job = engine.submit(READ_P3)
        for _ in range(3):
            engine.output(0.0)
            engine.receive(NO_RESPONSE, 0.0)
        assert isinstance(job.error, TimeoutError), indl
    job = engine.submit(READ_P3)
    for _ in range(2):
        engine.output(0.0)
        engine.receive(NO_RESPONSE, 0.0)
    assert isinstance(job.error, TimeoutError) and "reopen the session" in str(job.error)
