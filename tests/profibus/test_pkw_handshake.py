"""The PKW handshake engine, sans-IO: scripted transcripts of (what the master sends, what the slave shows)."""

from __future__ import annotations

import builtins
from collections.abc import Sequence

import pytest

from starterbus.core.errors import DecodeError, RemoteDeviceError, TimeoutError, TransportError
from starterbus.core.profile import Profile
from starterbus.transports.profibus_pkw.codec.codes import ResponseCode, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import (
    NO_RESPONSE,
    NO_TASK,
    PkwRequest,
    PkwResponse,
    pkw_request,
    pkw_response,
)
from starterbus.transports.profibus_pkw.master.handshake import JobState, Limits, PkwEngine, PkwError, PkwJob

READ_P3 = pkw_request(TaskCode.READ_PARAMETER, 3)
WRITE_P3 = pkw_request(TaskCode.WRITE_PARAMETER, 3, 20)
READ_M3 = pkw_request(TaskCode.READ_MEASUREMENT, 3)


def r(code: int, indl: int = 0, pwe: int = 0) -> PkwResponse:
    return pkw_response(code, indl, pwe)


def run(engine: PkwEngine, script: Sequence[tuple[PkwRequest, PkwResponse]], t0: float = 0.0) -> list[PkwJob]:
    """Feed a transcript: each row is (what the engine must send, what the slave shows in that cycle)."""
    finished = []
    for n, (expected, shown) in enumerate(script):
        sent = engine.output(t0 + n * 0.001)
        assert sent == expected, f"cycle {n}: sent {sent}, expected {expected}"
        job = engine.receive(shown, t0 + n * 0.001)
        if job is not None:
            finished.append(job)
    return finished


def state(job: PkwJob) -> JobState:
    """The job's state now (a call, so that type checkers do not narrow it between cycles)."""
    return job.state


def test_a_read_needs_a_clear_cycle_then_the_task() -> None:
    engine = PkwEngine()
    job = engine.submit(READ_P3)
    assert state(job) is JobState.QUEUED and engine.busy
    done = run(engine, [(NO_TASK, NO_RESPONSE), (READ_P3, r(1, 3, 12))])
    assert done == [job] and state(job) is JobState.DONE and job.response == r(1, 3, 12)
    assert job.cycles == 2 and job.error is None and not engine.busy


def test_an_idle_master_that_already_saw_no_response_sends_at_once() -> None:
    engine = PkwEngine()
    run(engine, [(NO_TASK, NO_RESPONSE)])  # idle cycle
    job = engine.submit(READ_P3)
    run(engine, [(READ_P3, r(1, 3, 12))])
    assert job.done and job.cycles == 1


def test_stale_response_of_the_previous_read_is_not_taken_for_the_write() -> None:
    # The slave still shows "01 03 00 0C" (the old value of p3) while the write of 20 is pending; a slow slave
    # keeps showing it for two more cycles after the master switched to "no task".
    engine = PkwEngine()
    engine.submit(READ_P3)
    write = engine.submit(WRITE_P3)
    old = r(1, 3, 12)
    done = run(
        engine,
        [
            (NO_TASK, NO_RESPONSE),
            (READ_P3, NO_RESPONSE),  # slave lags
            (READ_P3, old),  # read answered
            (NO_TASK, old),  # write job: clearing, slave still shows the read's answer (same INDL, code 1)
            (NO_TASK, old),
            (NO_TASK, NO_RESPONSE),  # cleared
            (WRITE_P3, NO_RESPONSE),
            (WRITE_P3, r(1, 3, 20)),
        ],
    )
    assert [j.request for j in done] == [READ_P3, WRITE_P3]
    assert write.response == r(1, 3, 20) and write.cycles == 5


def test_without_the_clear_rule_a_stale_answer_would_match(profiles: dict[str, Profile]) -> None:
    # Same INDL and code 1 as the pending write: only the clear rule tells them apart.
    stale = r(1, 3, 12)
    assert stale.indl == WRITE_P3.indl and stale.response is ResponseCode.VALUE
    engine = PkwEngine()
    run(engine, [(NO_TASK, stale)])  # a previous master session left the slave showing this
    job = engine.submit(WRITE_P3)
    run(engine, [(NO_TASK, stale), (NO_TASK, stale)])
    assert state(job) is JobState.CLEARING and not job.done


def test_responses_for_another_indl_are_ignored_and_counted() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=4, timeout=100))
    job = engine.submit(READ_P3)
    run(engine, [(NO_TASK, NO_RESPONSE), (READ_P3, r(1, 9, 1)), (READ_P3, r(3, 4, 0))])
    assert not job.done and job.foreign == 2
    run(engine, [(READ_P3, r(1, 3, 7))])
    assert job.response == r(1, 3, 7)


def test_no_write_permission_is_a_remote_device_error() -> None:
    engine = PkwEngine()
    job = engine.submit(WRITE_P3, "write ramp_time (p3) = 20")
    run(engine, [(NO_TASK, NO_RESPONSE), (WRITE_P3, r(2, 3, 0))])
    assert state(job) is JobState.FAILED
    assert isinstance(job.error, PkwError) and isinstance(job.error, RemoteDeviceError)
    assert job.error.response is ResponseCode.NO_WRITE_PERMISSION and job.error.code == 2
    assert job.error.meaning == "no write permission" and job.error.protocol == "profibus-pkw"
    assert job.error.data == bytes.fromhex("02 03 00 00")
    assert "write ramp_time (p3) = 20" in str(job.error)


@pytest.mark.parametrize("model", ["jjr5000", "jjr8000"])
def test_every_error_number_gets_the_models_own_meaning(model: str, profiles: dict[str, Profile]) -> None:
    errors = profiles[model].transport_settings("profibus-pkw")["errors"]
    for number in [*sorted(errors), 99]:
        engine = PkwEngine(errors)
        job = engine.submit(WRITE_P3)
        run(engine, [(NO_TASK, NO_RESPONSE), (WRITE_P3, r(3, 3, number))])
        error = job.error
        assert isinstance(error, PkwError) and error.response is ResponseCode.CANNOT_EXECUTE
        assert error.code == number
        expected = errors[number].en if number in errors else f"unknown error {number}"
        assert error.meaning == expected
        assert error.data == bytes([3, 3, 0, number])
        if number in errors and errors[number].zh:
            assert errors[number].zh in str(error)


def test_jjr5000_and_jjr8000_read_error_3_differently(profiles: dict[str, Profile]) -> None:
    meanings = {}
    for model in ("jjr5000", "jjr8000"):
        engine = PkwEngine(profiles[model].transport_settings("profibus-pkw")["errors"])
        job = engine.submit(pkw_request(TaskCode.WRITE_PARAMETER, 7, 350))
        run(engine, [(NO_TASK, NO_RESPONSE), (job.request, r(3, 7, 3))])
        assert isinstance(job.error, PkwError)
        meanings[model] = job.error.meaning
    assert meanings["jjr8000"] == "cannot modify while running"
    assert meanings["jjr5000"].startswith("illegal data value")


@pytest.mark.parametrize("code", [4, 5, 0x7F, 0xFF])
def test_unknown_response_code_fails_without_a_value(code: int) -> None:
    engine = PkwEngine()
    job = engine.submit(READ_P3)
    run(engine, [(NO_TASK, NO_RESPONSE), (READ_P3, r(code, 3, 1234))])
    assert isinstance(job.error, DecodeError) and job.error.field == "INDH"
    assert job.error.data == bytes([code, 3, 0x04, 0xD2])


@pytest.mark.parametrize("task", [READ_P3, WRITE_P3, READ_M3])
@pytest.mark.parametrize("code", [0, 1, 2, 3, 4])
def test_every_task_response_combination(task: PkwRequest, code: int) -> None:
    engine = PkwEngine(limits=Limits(max_cycles=3, timeout=100))
    job = engine.submit(task)
    write = task.task == TaskCode.WRITE_PARAMETER
    value = task.pwe if write else 5  # a write's answer echoes the value written
    run(engine, [(NO_TASK, NO_RESPONSE), (task, r(code, task.indl, value))])
    if code == 0 or (code == 2 and not write):  # still waiting (response 2 cannot answer a read); then the limit
        assert not job.done and job.mismatched == (code == 2)
        run(engine, [(task, r(0))])
        assert isinstance(job.error, DecodeError if code == 2 else TimeoutError)
    elif code == 1:
        assert state(job) is JobState.DONE and job.response is not None and job.response.pwe == value
    elif code in (2, 3):
        assert isinstance(job.error, PkwError) and job.error.response == code
    else:
        assert isinstance(job.error, DecodeError)
    assert job.done


def test_cycle_limit_is_a_timeout_error_naming_the_task() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=5, timeout=1000))
    job = engine.submit(READ_P3, "read ramp_time (p3)")
    run(engine, [(NO_TASK, NO_RESPONSE)] + [(READ_P3, NO_RESPONSE)] * 4)
    assert isinstance(job.error, TimeoutError) and isinstance(job.error, builtins.TimeoutError)
    assert isinstance(job.error, TransportError)
    assert "5 DP cycles" in str(job.error) and "read ramp_time (p3)" in str(job.error)
    assert "01 03 00 00" in str(job.error)
    assert not engine.busy  # the engine moves on


def test_time_limit_is_a_timeout_error() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=1000, timeout=2.5))
    job = engine.submit(READ_P3)
    engine.output(10.0)
    assert engine.receive(NO_RESPONSE, 10.0) is None
    engine.output(11.0)
    assert engine.receive(NO_RESPONSE, 12.0) is None
    engine.output(12.6)
    assert engine.receive(NO_RESPONSE, 12.6) is job
    assert isinstance(job.error, TimeoutError) and "2.5 s" in str(job.error)


def test_a_slave_that_never_clears_times_out_with_that_reason() -> None:
    engine = PkwEngine(limits=Limits(max_cycles=3, timeout=100))
    job = engine.submit(READ_P3)
    run(engine, [(NO_TASK, r(1, 3, 12))] * 3)
    assert isinstance(job.error, TimeoutError)
    assert "never answered 'no task' with 'no response'" in str(job.error)


def test_after_a_failure_the_next_task_clears_first() -> None:
    engine = PkwEngine()
    engine.submit(WRITE_P3)
    nxt = engine.submit(READ_P3)
    run(engine, [(NO_TASK, NO_RESPONSE), (WRITE_P3, r(3, 3, 2)), (NO_TASK, r(3, 3, 2)), (NO_TASK, NO_RESPONSE)])
    run(engine, [(READ_P3, r(1, 3, 12))])
    assert nxt.response == r(1, 3, 12)


def test_jobs_run_in_order_one_at_a_time() -> None:
    engine = PkwEngine()
    jobs = [engine.submit(pkw_request(TaskCode.READ_PARAMETER, i)) for i in range(3)]
    assert engine.pending() == jobs
    script: list[tuple[PkwRequest, PkwResponse]] = []
    for i in range(3):
        script += [(NO_TASK, NO_RESPONSE), (jobs[i].request, r(1, i, 100 + i))]
    done = run(engine, script)
    assert done == jobs and [j.response.pwe for j in jobs if j.response] == [100, 101, 102]


def test_channel_failure_ends_current_and_optionally_queued_jobs() -> None:
    engine = PkwEngine()
    first = engine.submit(READ_P3)
    second = engine.submit(READ_M3)
    engine.output(0.0)
    error = TransportError("gateway unreachable")
    assert engine.fail(error, 0.5) == [first]
    assert first.error is error and not second.done
    engine.output(1.0)
    engine.fail(error, 1.0, all_jobs=True)
    assert second.error is error and not engine.busy


def test_cancel_a_queued_or_current_job() -> None:
    engine = PkwEngine()
    first = engine.submit(READ_P3)
    second = engine.submit(READ_M3)
    engine.output(0.0)
    engine.cancel(second, TimeoutError("x"), 0.0)
    assert state(second) is JobState.FAILED and engine.pending() == [first]
    engine.cancel(first, TimeoutError("y"), 0.0)
    assert state(first) is JobState.FAILED and not engine.busy
    engine.cancel(first, TimeoutError("z"), 0.0)  # finished jobs stay as they are
    assert str(first.error) == "y"


def test_expire_applies_the_time_limit_without_an_exchange() -> None:
    engine = PkwEngine(limits=Limits(timeout=1.0))
    job = engine.submit(READ_P3)
    engine.output(0.0)
    assert engine.expire(0.5) is None
    assert engine.expire(2.0) is job and isinstance(job.error, TimeoutError)


def test_no_task_cannot_be_submitted_and_limits_are_checked() -> None:
    with pytest.raises(ValueError):
        PkwEngine().submit(PkwRequest(0, 0))
    with pytest.raises(ValueError):
        Limits(max_cycles=1)
    with pytest.raises(ValueError):
        Limits(timeout=0)
