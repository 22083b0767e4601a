"""Waiting on an observable in a test: poll a predicate until it holds or the time is up, never a fixed sleep.

One helper for the whole test suite and for plugin authors' tests (re-exported by :mod:`starterbus.testing`):
:func:`wait_until` in a thread, :func:`wait_until_async` on an event loop (its predicate may be a coroutine
function, to await a read). Both return whether the predicate held, so the caller asserts with its own message::

    assert wait_until(lambda: device.status().running, 10), device.status()
"""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Awaitable, Callable

__all__ = ["wait_until", "wait_until_async"]

#: how often the predicate is asked again: short next to any timeout, long next to one evaluation
INTERVAL = 0.01


def wait_until(predicate: Callable[[], object], timeout: float = 5.0, interval: float = INTERVAL) -> bool:
    """Ask ``predicate`` until it is true (truthy) or ``timeout`` seconds have passed; whether it held."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(interval)
    return True


async def wait_until_async(
    predicate: Callable[[], object] | Callable[[], Awaitable[object]],
    timeout: float = 5.0,
    interval: float = INTERVAL,
) -> bool:
    """:func:`wait_until` on the running event loop: other tasks run between the questions."""

    async def holds() -> bool:
        answer = predicate()
        if inspect.isawaitable(answer):
            answer = await answer
        return bool(answer)

    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not await holds():
        if loop.time() > deadline:
            return False
        await asyncio.sleep(interval)
    return True
