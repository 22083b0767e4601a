"""AsyncDevice's operations as jobs with futures: serialised per device in the order called, a cancelled await
never leaves the device half way through an operation, a bounded pool of threads (none per call), errors typed."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from starterbus.aio import POOL_SIZE, POOL_THREAD, AsyncDevice, AsyncFleet, SerialJobs, edge_pool
from starterbus.core.device import Device, open_device
from starterbus.core.errors import UnknownPointError
from starterbus.core.guarded import Proposal
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.worker_pool import WorkerPool
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller
from starterbus.testing import wait_until
from starterbus.testing.waits import wait_until_async
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

UNITS = (4, 5, 6)


@pytest.fixture
def sim() -> Iterator[tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]]]:
    profile = get_profile("ssd1")
    starters = {unit: SimulatedStarter(profile) for unit in UNITS}
    simulator = ModbusRtuSimulator(starters, pty=True).start()
    try:
        yield simulator, starters
    finally:
        simulator.close()


NESTED = threading.local()  # a write's read-back calls read: only the outermost call is an operation


def recording(fn: Callable[..., Any], log: list[tuple[str, object]], threads: list[threading.Thread]) -> Any:
    """``fn`` noting its start and end (with its first argument) and the thread it ran in."""

    def call(*args: Any, **kwargs: Any) -> Any:
        if getattr(NESTED, "depth", 0):
            return fn(*args, **kwargs)
        what = args[0] if args else fn.__name__
        log.append(("start", what))
        threads.append(threading.current_thread())
        NESTED.depth = 1
        try:
            return fn(*args, **kwargs)
        finally:
            NESTED.depth = 0
            log.append(("end", what))

    return call


def test_concurrent_awaits_on_one_device_run_one_at_a_time_in_order_each_with_its_answer(
    sim: tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]],
) -> None:
    simulator, starters = sim
    log: list[tuple[str, object]] = []
    threads: list[threading.Thread] = []

    async def scenario() -> list[Any]:
        async with AsyncDevice.open_url(simulator.client_urls()[4], "ssd1") as device:
            device.device.read = recording(device.device.read, log, threads)  # type: ignore[method-assign]
            device.device.write_many = recording(device.device.write_many, log, threads)  # type: ignore[method-assign]
            calls = []
            for value in range(20, 30):  # each read must see the write just before it, and only that one
                calls += [device.write({"ramp_time": value}), device.read("ramp_time")]
            answers: list[Any] = await asyncio.gather(*calls)
            return answers

    answers = asyncio.run(scenario())
    for index, value in enumerate(range(20, 30)):
        (outcome,) = answers[2 * index]
        assert outcome.ok
        assert answers[2 * index + 1]["ramp_time"].raw == value, (index, answers[2 * index + 1])
    starts = [what for event, what in log if event == "start"]
    assert len(starts) == 20 and all(log[i][0] == "start" and log[i + 1][0] == "end" for i in range(0, 40, 2))
    assert {t.name for t in threads} == {POOL_THREAD}  # never the event loop's thread
    assert starters[4].params["ramp_time"] == 29


def test_a_cancelled_await_withdraws_what_has_not_started_and_lets_what_has_run_to_its_end(
    sim: tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]],
) -> None:
    simulator, starters = sim
    entered, release = threading.Event(), threading.Event()
    proposals: list[Proposal] = []

    def confirm(proposal: Proposal) -> bool:  # holds the first write in its job, before anything is sent
        proposals.append(proposal)
        entered.set()
        return release.wait(10)

    device = AsyncDevice(open_device(simulator.client_urls()[5], "ssd1", confirm=confirm))

    async def scenario() -> int:
        await device.open()
        try:
            under_way = asyncio.create_task(device.write({"ramp_time": 20}))
            assert await wait_until_async(entered.is_set)
            read = asyncio.create_task(device.read("ramp_time"))
            not_started = asyncio.create_task(device.write({"ramp_time": 30}))
            assert await wait_until_async(lambda: device.jobs.waiting == 2)
            under_way.cancel()
            not_started.cancel()
            for task in (under_way, not_started):
                with pytest.raises(asyncio.CancelledError):
                    await task
            assert device.jobs.waiting == 2 and not read.done()  # the read waits for the write under way
            assert starters[5].params["ramp_time"] == 10  # nothing written yet: the write is held in confirm
            release.set()
            value = (await read)["ramp_time"].raw
            assert isinstance(value, int)
            return value
        finally:
            await device.close()

    assert asyncio.run(scenario()) == 20  # the cancelled write ran to its end, before the read
    assert len(proposals) == 1  # the write withdrawn before it started never reached its confirmation
    assert starters[5].params["ramp_time"] == 20


def test_no_thread_per_call_a_bounded_pool_shared_across_event_loops(
    sim: tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]],
) -> None:
    simulator, _ = sim
    devices = [AsyncDevice(open_device(simulator.client_urls()[unit], "ssd1")) for unit in UNITS]
    log: list[tuple[str, object]] = []
    threads: list[threading.Thread] = []  # the thread objects themselves: a new thread is a new object
    for device in devices:
        device.device.status = recording(device.device.status, log, threads)  # type: ignore[method-assign]
    started = edge_pool().started

    async def one(device: AsyncDevice) -> None:
        assert (await device.status()).ready

    async def burst() -> None:
        await asyncio.gather(*(one(device) for device in devices for _ in range(10)))

    for device in devices:
        asyncio.run(device.open())
    try:
        for _ in range(10):  # a new event loop each time: asyncio.to_thread would start a new executor's threads
            asyncio.run(one(devices[0]))
        asyncio.run(burst())
    finally:
        for device in devices:
            asyncio.run(device.close())
    assert len(threads) == 40
    assert len({id(t) for t in threads}) <= POOL_SIZE and {t.name for t in threads} == {POOL_THREAD}
    assert edge_pool().started - started <= POOL_SIZE


def test_errors_come_through_typed_as_raised(sim: tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]]) -> None:
    simulator, _ = sim

    async def scenario() -> None:
        async with AsyncDevice.open_url(simulator.client_urls()[6], "ssd1") as device:
            with pytest.raises(UnknownPointError, match="no_such_point"):
                await device.read("no_such_point")
            assert (await device.status()).ready  # the device goes on after an error

    asyncio.run(scenario())


def test_the_pool_runs_at_most_its_size_at_once_and_its_idle_threads_end() -> None:
    pool = WorkerPool(POOL_THREAD, 2, linger=0.05)
    jobs = [SerialJobs(lambda: pool) for _ in range(4)]
    release = threading.Event()
    running: list[int] = []
    lock = threading.Lock()

    def job(n: int) -> int:
        with lock:
            running.append(n)
        release.wait(10)
        return n

    futures = [jobs[n].submit(lambda n=n: job(n)) for n in range(4)]  # type: ignore[misc]
    assert wait_until(lambda: len(running) == 2)
    assert pool.started == 2 and len(running) == 2  # two devices wait for a thread, none started for them
    release.set()
    assert [f.result(10) for f in futures] == [0, 1, 2, 3] and pool.started == 2
    assert wait_until(lambda: not pool.alive)  # lingered, then ended


def test_a_fleet_job_after_the_polls_ended_runs_in_the_pool_not_on_the_event_loop(
    sim: tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]],
) -> None:
    """After the end a fleet runs a job at once in the submitting thread, on its device opened for it: from
    AsyncFleet that must not be the event loop's thread (it would block every other task meanwhile)."""
    simulator, _ = sim
    port = simulator.client_urls()[4].split("://", 1)[1].split("?", 1)[0]
    fleet_file = f"""
[poll]
period = 0.05

[[bus]]
name = "l1"
url = "modbus-rtu://{port}?timeout=0.3"

  [[bus.device]]
  name = "d4"
  model = "ssd1"
  address = 4
"""

    def ramp_time(device: Device) -> tuple[str, object]:
        return threading.current_thread().name, device.read("ramp_time")["ramp_time"].raw

    async def scenario() -> tuple[tuple[str, object], tuple[str, object]]:
        async with AsyncFleet(parse_fleet(fleet_file, "f.toml")) as fleet:
            during = await fleet.run("d4", ramp_time)
            await fleet.stop_polling()
            after = await fleet.run("d4", ramp_time)
        return during, after

    during, after = asyncio.run(scenario())
    assert during[1] == after[1] == 10
    assert during[0] != threading.main_thread().name and after[0] == POOL_THREAD


def test_a_job_the_fleet_would_run_in_the_calling_thread_goes_where_the_caller_says(
    sim: tuple[ModbusRtuSimulator, dict[int, SimulatedStarter]],
) -> None:
    """The window ``AsyncFleet.run`` had (the end coming between its look at ``stopping`` and the submit) is
    closed in the submit itself: a job it would run in the calling thread goes to ``elsewhere`` instead, before
    the start and after the end alike; nothing of it runs in the submitting thread."""
    simulator, _ = sim
    port = simulator.client_urls()[4].split("://", 1)[1].split("?", 1)[0]
    config = parse_fleet(
        f'[poll]\nperiod = 0.05\n\n[[bus]]\nname = "l1"\nurl = "modbus-rtu://{port}?timeout=0.3"\n\n'
        '  [[bus.device]]\n  name = "d4"\n  model = "ssd1"\n  address = 4\n',
        "f.toml",
    )
    threads: list[str] = []

    def ramp_time(device: Device) -> object:
        threads.append(threading.current_thread().name)
        return device.read("ramp_time")["ramp_time"].raw

    poller = FleetPoller(config)
    for moment in ("before the start", "after the end"):
        if moment == "after the end":
            poller.start()
            poller.stop()
        handed: list[Callable[[], None]] = []
        future = poller.submit("d4", ramp_time, elsewhere=handed.append)
        assert len(handed) == 1 and not future.done() and not threads, moment
        worker = threading.Thread(target=handed[0], name=f"elsewhere {moment}")
        worker.start()
        worker.join()
        assert future.result(timeout=5) == 10 and threads == [f"elsewhere {moment}"], moment
        threads.clear()
