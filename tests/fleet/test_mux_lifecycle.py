"""The multiplexer's life: stopped with polls in flight, a bus's ``delay`` in every mode, nothing woken after
the end, and its selector beyond ``select``'s descriptor limit."""

from __future__ import annotations

import dataclasses
import os
import threading
from concurrent.futures import Future
from typing import TYPE_CHECKING

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.sharing import leases
from starterbus.fleet.bus_worker import BusWorker
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.device_poll import Attempt
from starterbus.fleet.mux import FD_SETSIZE, Waiter
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.sample import Sample

if TYPE_CHECKING:
    from starterbus.tests.fleet.conftest import Lines, Samples


def test_stop_with_polls_in_flight_cancels_them_and_gives_the_line_back(lines: Lines, samples: Samples) -> None:
    """Bus line0 first polls unit 9, which never answers; bus line1 is lent to a job when stop() comes."""
    config = lines.fleet("timeout=2&retries=0", buses=2, units={0: (9, 1)})
    sim = lines.sims[0]
    poller = FleetPoller(config, samples)
    assert poller.mux is not None
    started, release = threading.Event(), threading.Event()

    def job(device: Device) -> int:
        started.set()
        assert release.wait(10.0)
        return device.read_value("current_limit").raw

    # shares line0 with the poller; 2 s: a simulator held up on a loaded machine answered after 0.5 s, and the late
    # answers kept the line from falling silent for the retry ("the line did not fall silent within 2 s")
    kept = open_device(sim.url(1, timeout=2), "jjr5000").open()
    try:
        poller.start()
        try:
            samples.wait_for(lambda ss: sim.counters.requests >= 1 and sum(s.bus == "line1" for s in ss) >= 3)
            future = poller.submit("b1u1", job)
            assert started.wait(10.0)
            stopper = threading.Thread(target=poller.stop)
            stopper.start()
            release.set()
            stopper.join(20.0)
        finally:
            release.set()
            poller.stop()
        assert not poller.running and not poller.mux.thread.is_alive()
        assert not [t.name for t in threading.enumerate() if t.name == "starterbus-io" or t.name.startswith("jobs-")]
        assert future.result(0) == lines.starter("b1u1").params["current_limit"]
        assert not any(s.device == "b0u9" for s in samples.list), "the poll in flight was cancelled: no sample"
        stats = poller.line_stats()["line0"]
        assert stats.wire.requests == sim.counters.requests == 1, "what the cancelled poll sent is counted too"
        assert stats.stopped is not None
        read: list[int] = []  # once the cancelled request's quarantine is over (a late answer could come)
        reader = threading.Thread(target=lambda: read.append(kept.read_value("current_limit").raw), daemon=True)
        reader.start()
        reader.join(10.0)
        assert read == [sim.starters[1].params["current_limit"]], "the line is free for a blocking user"
    finally:  # closing takes the line's lock too: in a thread, so that a lock never given back fails the test
        closer = threading.Thread(target=kept.close, daemon=True)
        closer.start()
        closer.join(10.0)
    assert not closer.is_alive()
    assert not [key for key in leases() if sim.client_path in key]


@pytest.mark.parametrize("mode", ["multiplexed", "threads", "handed-over"])
def test_a_bus_s_delay_comes_after_every_poll_before_polls_and_jobs(
    lines: Lines, samples: Samples, monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    delay = 0.03
    config = lines.fleet(
        buses=1,
        units={0: (1, 2)},
        bus_keys={0: f"delay = {delay}"},
        url_params={0: "&io=pyserial"} if mode == "handed-over" else None,
    )
    poller = FleetPoller(config, samples, rounds=3, multiplex=mode != "threads")
    events: list[tuple[float, str]] = []  # (monotonic time, what) on the bus
    begin, end = BusWorker.begin, BusWorker.end

    def begins(worker: BusWorker, runtime: object) -> Attempt:
        attempt = begin(worker, runtime)  # type: ignore[arg-type]
        events.append((attempt.start, "poll"))
        return attempt

    def ends(worker: BusWorker, attempt: Attempt, *args: object) -> None:
        events.append((poller.clock(), "end"))
        end(worker, attempt, *args)  # type: ignore[arg-type]

    def job(device: Device) -> int:
        events.append((poller.clock(), "job"))
        return device.read_value("current_limit").raw

    jobs: list[Future[int]] = []

    def submit_at_the_first_sample(sample: Sample) -> None:
        if not jobs:  # from the polling thread, just as the poll ends: the job is waiting when the delay starts
            jobs.append(poller.submit("b0u2", job))

    monkeypatch.setattr(BusWorker, "begin", begins)
    monkeypatch.setattr(BusWorker, "end", ends)
    samples.hooks.append(submit_at_the_first_sample)
    poller.start()
    poller.join(30.0)
    assert not poller.running
    assert jobs[0].result(0) == lines.starter("b0u2").params["current_limit"]
    assert len(samples.list) == 6 and all(s.online for s in samples.list)
    if mode == "handed-over":
        assert poller.mux is not None and poller.mux.buses[0].handed_over
    events.sort()
    kinds = [kind for _, kind in events]
    assert kinds.count("job") == 1 and kinds.count("end") == 6
    last_end = None
    for at, kind in events:
        if kind == "end":
            last_end = at
        elif last_end is not None:
            # what follows a poll starts no sooner than the delay after it (1 us: float rounding of the clock)
            assert at - last_end >= delay - 1e-6, (kind, at - last_end, kinds)


@pytest.mark.parametrize("multiplex", [True, False])
def test_stop_from_on_sample_returns_at_once_and_ends_the_poller(
    lines: Lines, samples: Samples, multiplex: bool
) -> None:
    """The polling thread cannot wait for itself, nor for buses waiting to hand it their samples."""
    poller = FleetPoller(lines.fleet(), samples, multiplex=multiplex)
    failed: list[BaseException] = []
    returned = threading.Event()

    def stop_at_the_fifth(sample: Sample) -> None:
        if len(samples.list) == 4:
            try:
                poller.stop(timeout=60.0)
            except BaseException as exc:
                failed.append(exc)
            returned.set()

    samples.hooks.append(stop_at_the_fifth)
    poller.start()
    assert returned.wait(10.0), "stop() from on_sample waited for the poller's threads"
    poller.join(30.0)
    assert failed == [] and not poller.running
    assert len(samples.list) < 5 + len(poller.workers), "each bus ends with the poll it was making"
    assert not [key for key in leases() if any(sim.client_path in key for sim in lines.sims)]


def test_after_the_end_the_poller_wakes_nothing(lines: Lines, samples: Samples) -> None:
    """Once the fleet is over its buses have left the scheduler's loop: a later stop() neither queues anything
    for the loop nor writes to its wake-up pipe (the process's, which outlives the fleet)."""
    poller = FleetPoller(lines.fleet(buses=1), samples, rounds=1)
    assert poller.mux is not None
    poller.start()
    poller.join(30.0)
    assert not poller.running
    loop = poller.mux.loop
    assert not loop.running and not [bus for bus in poller.mux.buses if bus in loop.drivers]
    queued = len(loop._inbox)
    loop._drain()  # the byte of the loop's own stop, if its last turn did not read it
    poller.stop()
    assert len(loop._inbox) == queued
    with pytest.raises(BlockingIOError):
        os.read(loop._wake_r, 16)


@pytest.mark.parametrize("multiplex", [True, False])
def test_a_job_after_the_end_runs_at_once_and_leaves_no_device_open(
    lines: Lines, samples: Samples, multiplex: bool
) -> None:
    poller = FleetPoller(lines.fleet(buses=1), samples, rounds=1, multiplex=multiplex)
    poller.start()
    poller.join(30.0)
    assert not poller.running and all(w.jobs.closed for w in poller.workers)
    future = poller.submit("b0u3", lambda d: d.read_value("current_limit").raw)
    assert future.result(0) == lines.starter("b0u3").params["current_limit"]
    assert not [key for key in leases() if lines.sims[0].client_path in key]
    requests = sum(s.wire.requests for s in samples.list if s.wire is not None)
    assert poller.line_stats()["line0"].wire.requests == lines.sims[0].counters.requests > requests


def test_a_poller_never_started_holds_no_descriptor() -> None:
    config = parse_fleet(
        '[[bus]]\nname = "rtu"\nurl = "modbus-rtu:///dev/null?baudrate=19200"\n'
        '[[bus.device]]\nname = "a"\nmodel = "jjr5000"\naddress = 1\n'
    )
    before = set(os.listdir("/proc/self/fd"))
    poller = FleetPoller(config)
    assert poller.mux is not None
    assert set(os.listdir("/proc/self/fd")) == before


def _in_use(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


def test_the_waiter_takes_descriptors_beyond_select_s_limit() -> None:
    waiter: Waiter[object] = Waiter()
    low_r, low_w = os.pipe()
    high_r, high_w = os.pipe()
    far = next(fd for fd in range(FD_SETSIZE + 500, FD_SETSIZE + 600) if not _in_use(fd))
    os.dup2(high_r, far)
    marker = object()
    try:
        waiter.register(low_r, None)
        assert waiter.wait(0.0) == []
        waiter.register(far, marker)
        assert waiter.wait(0.0) == []
        os.write(high_w, b"x")
        assert waiter.wait(5.0) == [marker]
        os.write(low_w, b"x")
        assert sorted(map(id, waiter.wait(5.0))) == sorted([id(marker), id(None)])
        os.read(far, 1)
        os.read(low_r, 1)
        other_r, other_w = os.pipe()
        os.dup2(other_r, far)  # a line reopened under the same number is watched as the old one was
        os.close(other_r)
        os.write(other_w, b"y")
        assert waiter.wait(5.0) == [marker]
        os.read(far, 1)
        os.close(other_w)
        os.write(low_w, b"x")
        waiter.unregister(far)  # back to select() alone
        assert waiter.wait(5.0) == [None]
        os.read(low_r, 1)
        assert waiter.wait(0.0) == []
    finally:
        waiter.close()
        for fd in (low_r, low_w, high_r, high_w, far):
            os.close(fd)


def test_two_fleets_share_the_loop_and_the_last_one_out_stops_it(lines: Lines) -> None:
    """A fleet that ends while another polls on the same scheduler leaves the loop's thread running for it; the
    last one stops the thread the first one started."""
    from starterbus.tests.fleet.conftest import Samples

    config = lines.fleet(buses=2)
    short, long = Samples(), Samples()
    first = FleetPoller(dataclasses.replace(config, buses=config.buses[:1]), short, rounds=1)
    second = FleetPoller(dataclasses.replace(config, buses=config.buses[1:]), long)
    assert first.mux is not None and second.mux is not None
    first.start()
    second.start()
    try:
        first.join(30.0)
        assert not first.running and len(short.list) == 3
        assert first.mux.thread.is_alive(), "the thread the first fleet started still serves the second"
        mark = long.mark()
        long.wait_for(lambda ss: len(ss) >= mark + 6)  # the second fleet goes on
    finally:
        second.stop()
    assert not second.running and not first.mux.thread.is_alive() and not first.mux.loop.running
    assert all(s.online for s in [*short.list, *long.list])
