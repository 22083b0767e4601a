"""The multiplexer (fleet/mux.py): many Modbus RTU lines polled from one thread, by the rules each bus follows
with a thread of its own (rounds, values, wire counts, jobs, offline devices), on simulators on ptys."""

from __future__ import annotations

import dataclasses
import random
import threading
from typing import TYPE_CHECKING, Any

import pytest

from starterbus.core.device import Device
from starterbus.core.sharing import leases
from starterbus.core.transport import TransportCounters
from starterbus.fleet.bus_worker import BusWorker
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.probing import ProbeSettings
from starterbus.fleet.sample import Sample

if TYPE_CHECKING:
    from starterbus.fleet.demo import DemoFleet
    from starterbus.tests.fleet.conftest import Lines, Samples

DEVICES = {f"b{n}u{u}" for n in range(3) for u in (1, 2, 3)}


def _open_lines(lines: Lines) -> list[str]:
    return [key for key in leases() for sim in lines.sims if sim.client_path in key]


def _wire(sample: Sample) -> tuple[int, ...]:
    assert sample.wire is not None
    return _totals(sample.wire)


def _totals(w: TransportCounters) -> tuple[int, ...]:
    return (w.transactions, w.requests, w.retries, w.timeouts, w.errors, w.bytes_sent, w.bytes_received)


def _seen(sample: Sample) -> tuple[object, ...]:
    """What a sample says about the device and what its poll put on the wire (not when)."""
    values = {k: (v.raw, v.value) for k, v in sample.values.items()}
    status = None if sample.status is None else dataclasses.replace(sample.status, timestamp=0.0)
    return sample.online, sample.error, status, values, _wire(sample)


def _run_rounds(lines: Lines, samples: Samples, multiplex: bool) -> FleetPoller:
    poller = FleetPoller(lines.fleet(), samples, rounds=2, multiplex=multiplex)
    poller.start()
    poller.join(30.0)
    assert not poller.running, "the poller stops by itself after its rounds"
    return poller


def test_one_thread_polls_every_line_for_the_rounds_asked(lines: Lines, samples: Samples) -> None:
    first_limit: dict[str, int] = {}
    threads_alive: list[bool] = []

    def change_after_the_first_poll(sample: Sample) -> None:
        threads_alive.append(any(w.thread.is_alive() for w in poller.workers))
        starter = lines.starter(sample.device)
        if sample.device not in first_limit:
            first_limit[sample.device] = starter.params["current_limit"]
            starter.params["current_limit"] = 150 + 10 * len(first_limit)  # each device a value of its own

    samples.hooks.append(change_after_the_first_poll)
    poller = FleetPoller(lines.fleet(), samples, rounds=2)
    assert poller.mux is not None
    assert [b.worker for b in poller.mux.buses] == poller.workers
    poller.start()
    poller.join(30.0)
    assert not poller.running and not poller.mux.thread.is_alive()
    assert set(samples.threads) == {"starterbus-io"} and threads_alive and not any(threads_alive)
    assert all(w.thread.ident is None for w in poller.workers), "no bus got a thread of its own"
    assert sorted(s.device for s in samples.list) == sorted([*DEVICES, *DEVICES]), "two polls of every device"
    for device in DEVICES:
        first, second = samples.of(device)
        assert first.online and second.online and first.error is None and second.error is None
        assert first.status is not None and first.status.state == "ready"
        assert first.values["current_limit"].raw == first_limit[device]
        assert second.values["current_limit"].raw == lines.starter(device).params["current_limit"]
        assert first.values["current_limit"].raw != second.values["current_limit"].raw
        assert first.values["phase_a_current"].raw == 0
    stats = poller.line_stats()
    for n in range(3):
        bus = [s for s in samples.list if s.bus == f"line{n}"]
        assert stats[f"line{n}"].polls == 6
        assert stats[f"line{n}"].wire.requests == sum(_wire(s)[1] for s in bus) == lines.sims[n].counters.requests
    assert _open_lines(lines) == [], "every device closed at the end"


def test_threads_put_the_same_on_the_wire_and_give_the_same_samples(lines: Lines) -> None:
    from starterbus.tests.fleet.conftest import Samples

    by_mode = {}
    for multiplex in (True, False):
        samples = Samples()
        poller = _run_rounds(lines, samples, multiplex)
        assert (poller.mux is not None) is multiplex
        expected = {"starterbus-io"} if multiplex else {"bus-line0", "bus-line1", "bus-line2"}
        assert set(samples.threads) == expected
        by_device = {d: [_seen(s) for s in samples.list if s.device == d] for d in DEVICES}
        stats = {name: (s.polls, s.probes, _totals(s.wire)) for name, s in poller.line_stats().items()}
        by_mode[multiplex] = by_device, stats
        assert all(len(seen) == 2 and seen[0][0] for seen in by_device.values())
        assert _open_lines(lines) == []
    assert by_mode[True] == by_mode[False]


def test_a_bus_that_polls_only_by_blocking_is_handed_a_thread_and_waited_for(lines: Lines, samples: Samples) -> None:
    # the multiplexed bus has one device, the other three: the multiplexer's thread ends long before the other
    config = lines.fleet(buses=2, units={0: (1,)}, url_params={1: "&io=pyserial"})
    poller = FleetPoller(config, samples, rounds=2)
    assert poller.mux is not None and len(poller.mux.buses) == 2, "judged from the class: both are multiplexed"
    poller.start()
    poller.join(30.0)  # at once: the hand-over comes later, and join waits for that thread too
    assert not poller.running
    assert poller.mux.buses[1].handed_over and not poller.mux.buses[0].handed_over
    assert poller.workers[1].thread.ident is not None and not poller.workers[1].thread.is_alive()
    by_thread = {(s.bus, t) for s, t in zip(samples.list, samples.threads, strict=True)}
    assert by_thread == {("line0", "starterbus-io"), ("line1", "bus-line1")}
    for device in ("b0u1", "b1u1", "b1u2", "b1u3"):
        polls = samples.of(device)
        assert len(polls) == 2 and all(s.online for s in polls), (device, [s.error for s in polls])
        assert polls[-1].values["current_limit"].raw == lines.starter(device).params["current_limit"]
    assert _open_lines(lines) == []


def test_buses_of_every_transport_poll_on_the_scheduler(demo: DemoFleet, samples: Samples) -> None:
    poller = FleetPoller(demo.config, samples, rounds=1)
    assert poller.mux is not None
    # DeviceNet polls as tickets on the scheduler since issue 29's step 5, the Profibus gateways since their
    # channel runs on the Modbus TCP engine: every bus of the demo is multiplexed
    names = ["rtu-line-1", "rtu-line-2", "dp-gateway-1", "dp-gateway-3", "devicenet"]
    assert [b.worker.bus.name for b in poller.mux.buses] == names
    poller.start()
    poller.join(30.0)
    assert not poller.running
    assert sorted(s.device for s in samples.list) == sorted(demo.starters), "one poll of every device"
    assert all(s.online for s in samples.list), [(s.device, s.error) for s in samples.list]
    assert set(samples.threads) == {"starterbus-io"}


def test_a_job_has_the_bus_while_the_other_buses_go_on(lines: Lines, samples: Samples) -> None:
    poller = FleetPoller(lines.fleet(), samples, rounds=30)  # ends by itself: no poll cut short by stop()
    sim = lines.sims[0]
    seen: dict[str, object] = {}

    def job(device: Device) -> tuple[str, int]:
        before = device.transport.counters()
        assert before is not None
        before = before.copy()
        on_line = sim.counters.requests
        mark = samples.mark()
        outcome = device.write("current_limit", 420)
        value = device.read_value("current_limit")
        # the other buses keep polling while this one is lent to the job
        samples.wait_for(lambda ss: sum(1 for s in ss[mark:] if s.bus != "line0") >= 12, timeout=10.0)
        after = device.transport.counters()
        assert after is not None
        seen["job"] = after.minus(before)
        seen["line"] = sim.counters.requests - on_line
        seen["thread"] = threading.current_thread().name
        return outcome.result, value.raw

    with poller:
        samples.wait_for(lambda ss: {s.device for s in ss} == DEVICES)
        future = poller.submit("b0u2", job)
        assert future.result(20.0) == ("ok", 420)
        mark = samples.mark()
        poller.join(30.0)
    assert not poller.running
    assert lines.starter("b0u2").params["current_limit"] == 420
    assert samples.of("b0u2", mark)[0].values["current_limit"].raw == 420, "later polls see what the job wrote"
    delta = seen["job"]
    assert isinstance(delta, TransportCounters) and delta.requests >= 2
    assert seen["line"] == delta.requests, "nothing but the job went over its line while it had the bus"
    assert seen["thread"] == "jobs-line0"
    wire = poller.line_stats()["line0"].wire
    polls = [s for s in samples.list if s.bus == "line0"]
    assert wire.requests == sum(_wire(s)[1] for s in polls) + delta.requests, "the job's requests are counted"
    assert wire.transactions == sum(_wire(s)[0] for s in polls) + delta.transactions
    assert not any(t.name.startswith("jobs-") for t in threading.enumerate())
    assert _open_lines(lines) == []


def test_a_job_waits_for_the_bookkeeping_of_the_poll_before_it(
    lines: Lines, samples: Samples, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A job queued while a poll is on the wire starts after that poll is counted and emitted (not while: its
    transactions would be counted twice, in the poll's sample and in the job)."""
    poller = FleetPoller(lines.fleet(buses=1), samples)
    overlaps: list[str] = []
    end = BusWorker.end

    def ends(worker: BusWorker, *args: Any) -> None:
        overlaps.extend(t.name for t in threading.enumerate() if t.name == f"jobs-{worker.bus.name}")
        end(worker, *args)

    monkeypatch.setattr(BusWorker, "end", ends)
    jobs: list[TransportCounters] = []

    def job(device: Device) -> int:
        before = device.transport.counters()
        assert before is not None
        before = before.copy()
        raw = device.read_value("current_limit").raw
        after = device.transport.counters()
        assert after is not None
        jobs.append(after.minus(before))
        return raw

    with poller:
        for n in range(8):
            mark = samples.mark()
            samples.wait_for(lambda ss: len(ss) > mark)  # noqa: B023 (waited for here, in this iteration)
            device = f"b0u{1 + n % 3}"
            assert poller.submit(device, job).result(10.0) == lines.starter(device).params["current_limit"]
    assert overlaps == []
    assert len(jobs) == 8 and all(j.requests == 1 for j in jobs), "each job's delta: its own read alone"


def test_a_device_that_goes_away_is_probed_and_comes_back_while_its_neighbours_go_on(
    lines: Lines, samples: Samples
) -> None:
    config = lines.fleet("timeout=0.05&retries=2", buses=1, period=0.01)
    probing = ProbeSettings(timeout=0.02, share=0.5)
    poller = FleetPoller(config, samples, probing=probing, rng=random.Random(5))
    sim = lines.sims[0]
    gone = sim.starters[2]
    assert poller.mux is not None
    try:
        with poller:
            samples.wait_for(lambda ss: {s.device for s in ss if s.online} == {"b0u1", "b0u2", "b0u3"})
            del sim.starters[2]
            mark = samples.mark()
            samples.wait_for(
                lambda ss: (
                    len([s for s in ss[mark:] if s.device == "b0u2" and s.probe]) >= 3
                    and all(len([s for s in ss[mark:] if s.device == d]) >= 10 for d in ("b0u1", "b0u3"))
                )
            )
            # its probe timeout: 0.02 s, or longer if a poll of it took longer while online (a loaded machine),
            # at most its own timeout; no good poll of it comes while it is away, so every probe used this one
            (runtime,) = [r for r in poller.runtimes() if r.config.name == "b0u2"]
            probe_timeout = min(probing.timeout_for(runtime.slowest_request) or 0.0, 0.05)
            sim.starters[2] = gone
            back = samples.mark()
            samples.wait_for(lambda ss: any(s.device == "b0u2" and s.online for s in ss[back:]))
    finally:
        sim.starters[2] = gone
    assert set(samples.threads) == {"starterbus-io"}
    away = samples.of("b0u2", mark)
    first = away[0]
    assert not first.online and not first.probe and first.values == {} and first.status is None
    # the poll that finds it gone: the full policy (three attempts) for the request that failed; a poll under
    # way when the unit went had its earlier requests answered
    assert first.wire is not None and (first.wire.timeouts, first.wire.retries) == (1, 2), first.wire
    assert first.wire.requests == first.wire.transactions + 2, "the poll that finds it gone: the full policy"
    probes = [s for s in away if s.probe]
    failed = [p for p in probes if not p.online]
    assert all(p.wire is not None and (p.wire.requests, p.wire.retries) == (1, 0) for p in failed), "one attempt"
    assert all(f"within {probe_timeout:g} s" in (p.error or "") for p in failed), "with the probe timeout"
    returned = next(s for s in away if s.online)
    assert returned.probe and returned.values["current_limit"].raw == gone.params["current_limit"]
    # its neighbours go on: polled all along (above), and a poll of theirs fails only by a timeout on a loaded
    # machine (the simulator's thread held up past three attempts), never by what the absent unit caused
    neighbours = [s for s in samples.list if s.device != "b0u2"]
    missed = [s for s in neighbours if not s.online]
    assert all("no answer" in (s.error or "") or "within" in (s.error or "") for s in missed), missed
    assert len(missed) * 10 <= len(neighbours), [s.error for s in missed]
    assert poller.line_stats()["line0"].probes == len(probes)
