"""The one pool of threads of the asyncio edge and of a fleet's jobs: bounded, in order, a thread named after its
work meanwhile, a failure handed to ``on_error``, no thread left once the work is done (linger 0)."""

from __future__ import annotations

import threading

from starterbus.core.worker_pool import WorkerPool
from starterbus.testing import wait_until


def test_work_runs_in_at_most_size_threads_named_after_it() -> None:
    pool = WorkerPool("pool", 2)
    release = threading.Event()
    started: list[tuple[int, str]] = []
    lock = threading.Lock()

    def work(n: int) -> None:
        with lock:
            started.append((n, threading.current_thread().name))
        release.wait(10)

    for n in range(5):
        pool.run(lambda n=n: work(n), f"job-{n}")  # type: ignore[misc]
    assert wait_until(lambda: len(started) == 2)
    assert sorted(started) == [(0, "job-0"), (1, "job-1")] and pool.started == 2 and len(pool.alive) == 2
    release.set()
    assert pool.drain(10)
    assert sorted(started) == [(n, f"job-{n}") for n in range(5)] and pool.started == 2
    assert wait_until(lambda: not pool.alive)  # linger 0: the threads end with the work


def test_work_starts_in_the_order_given() -> None:
    pool = WorkerPool("pool", 1)
    order: list[int] = []
    for n in range(20):
        pool.run(lambda n=n: order.append(n))  # type: ignore[misc]
    assert pool.drain(10) and order == list(range(20))


def test_a_thread_takes_the_pools_name_back_between_pieces_of_work() -> None:
    pool = WorkerPool("pool", 1)
    names = [pool.submit(lambda: threading.current_thread().name, "named").result(10)]
    names.append(pool.submit(lambda: threading.current_thread().name).result(10))
    assert names == ["named", "pool"]


def test_work_that_raises_goes_to_on_error_and_the_pool_goes_on() -> None:
    errors: list[tuple[str, str]] = []
    pool = WorkerPool("pool", 1, on_error=lambda name, exc: errors.append((name, str(exc))))

    def boom() -> None:
        raise ValueError("boom")

    pool.run(boom, "jobs-line0")
    pool.run(boom)
    assert pool.submit(lambda: 42).result(10) == 42
    assert errors == [("jobs-line0", "boom"), ("pool", "boom")]


def test_an_idle_thread_takes_the_next_work_and_ends_after_the_linger() -> None:
    pool = WorkerPool("pool", 4, linger=30.0)
    first = pool.submit(threading.current_thread).result(10)
    assert pool.submit(threading.current_thread).result(10) is first and pool.started == 1
    short = WorkerPool("pool", 4, linger=0.05)
    short.submit(lambda: None).result(10)
    assert wait_until(lambda: not short.alive)


def test_a_future_cancelled_before_its_turn_never_runs() -> None:
    pool = WorkerPool("pool", 1)
    release = threading.Event()
    ran: list[str] = []
    blocker = pool.submit(lambda: release.wait(10))
    withdrawn = pool.submit(lambda: ran.append("withdrawn"))
    assert withdrawn.cancel()
    release.set()
    assert blocker.result(10) is True and pool.drain(10) and ran == []
