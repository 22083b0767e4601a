"""starterbus.testing's one wait-until helper: true as soon as the predicate holds, false when the time is up."""

from __future__ import annotations

import asyncio
import itertools

from starterbus.testing import wait_until, wait_until_async


def test_wait_until_asks_until_the_predicate_holds() -> None:
    asked = itertools.count(1)
    assert wait_until(lambda: next(asked) >= 3, timeout=5.0, interval=0.001)
    assert next(asked) == 4  # asked exactly three times


def test_wait_until_gives_up_false_after_the_timeout() -> None:
    assert not wait_until(lambda: False, timeout=0.02, interval=0.001)
    assert wait_until(lambda: [1])  # a truthy value holds


def test_wait_until_async_awaits_a_coroutine_predicate_and_lets_other_tasks_run() -> None:
    async def scenario() -> tuple[bool, bool]:
        seen: list[int] = []

        async def produce() -> None:
            seen.append(1)

        async def arrived() -> bool:
            return bool(seen)

        task = asyncio.get_running_loop().create_task(produce())  # runs only if the wait yields to the loop
        held = await wait_until_async(arrived, timeout=5.0, interval=0.001)
        await task
        return held, await wait_until_async(lambda: False, timeout=0.02, interval=0.001)

    assert asyncio.run(scenario()) == (True, False)
