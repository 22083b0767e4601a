"""The asyncio API: an async device and an async fleet (samples as an async stream, guarded remote commands).

Blocking I/O never runs on the event loop. A device's operations are jobs with futures (awaited through
:func:`asyncio.wrap_future`): one at a time per device, in the order called, run by the process's small edge pool
(:func:`edge_pool`: at most :data:`POOL_SIZE` threads for every :class:`AsyncDevice`, none per call, ending when
idle: a :class:`~starterbus.core.worker_pool.WorkerPool`, as the fleet's job pool is), where each leads or follows
the I/O scheduler as the sync API does. A fleet's polls run on the scheduler and its commands in the fleet's job
pool; both come back through futures and a queue (``call_soon_threadsafe``).

Cancelling the task that awaits an operation withdraws it if it has not started (nothing was sent); one that
has started (a write may be on the wire) runs to its end, its outcome not awaited by anyone (a failure is logged),
and the device's next operation starts only after it: a device is never left half way through one.

```python
import asyncio
from starterbus.aio import AsyncFleet
from starterbus.fleet.config import load_fleet

async def main() -> None:
    async with AsyncFleet(load_fleet("fleet.toml")) as fleet:
        async for sample in fleet.samples():
            print(sample.device, sample.status.state if sample.status else "offline")

asyncio.run(main())
```
"""

from __future__ import annotations

import asyncio
import functools
import logging
import os
import threading
from collections import deque
from collections.abc import AsyncIterator, Callable, Mapping
from concurrent.futures import Future
from types import TracebackType
from typing import Any, TypeVar

from starterbus.core.device import Device, open_device
from starterbus.core.errors import StarterbusError
from starterbus.core.guarded import Outcome
from starterbus.core.model import Value
from starterbus.core.status import Command, Status
from starterbus.core.supervision import ServiceFailed, Supervisor, describe
from starterbus.core.worker_pool import WorkerPool, settle
from starterbus.fleet.config import DeviceConfig, FleetConfig
from starterbus.fleet.poller import FleetPoller, Sample

log = logging.getLogger(__name__)

T = TypeVar("T")

#: threads of the edge pool at most, whatever the number of devices and awaits
POOL_SIZE = 8
#: the name of the edge pool's threads
POOL_THREAD = "aio-jobs"
#: seconds an idle pool thread waits for more work before it ends (a device awaited every second keeps its thread)
LINGER = 10.0


_pool: list[WorkerPool] = []
_pool_lock = threading.Lock()


def edge_pool() -> WorkerPool:
    """The process's edge pool (made at first use): :data:`POOL_SIZE` threads at most, each ending after
    :data:`LINGER` seconds without work."""
    if not _pool:
        with _pool_lock:
            if not _pool:
                _pool.append(WorkerPool(POOL_THREAD, POOL_SIZE, linger=LINGER))
    return _pool[0]


os.register_at_fork(after_in_child=_pool.clear)  # a child has none of the parent's threads


class SerialJobs:
    """The jobs of one device: one at a time, in the order submitted, in the edge pool. A device with work
    waiting goes back to the end of the pool's queue after each job, so a busy device does not starve others."""

    def __init__(self, pool: Callable[[], WorkerPool] = edge_pool) -> None:
        self._pool = pool
        self._lock = threading.Lock()
        self._queue: deque[tuple[Future[Any], Callable[[], Any]]] = deque()
        self._active = False  # a job of this device is queued in the pool or runs

    @property
    def waiting(self) -> int:
        """Jobs submitted that have not started (a cancelled one counts until its turn comes)."""
        with self._lock:
            return len(self._queue)

    def submit(self, fn: Callable[[], T]) -> Future[T]:
        future: Future[T] = Future()
        with self._lock:
            self._queue.append((future, fn))
            start = not self._active
            self._active = True
        if start:
            self._pool().run(self._next)
        return future

    def _next(self) -> None:
        with self._lock:
            future, fn = self._queue.popleft()
        try:
            settle(future, fn)
        finally:
            with self._lock:
                more = bool(self._queue)
                self._active = more
            if more:
                self._pool().run(self._next)


class SampleStream:
    """The samples of one subscriber of an :class:`AsyncFleet`, in the order the poller produced them (an async
    iterator; :meth:`close` unsubscribes). Raises :class:`~starterbus.core.supervision.ServiceFailed` if the
    service fails."""

    def __init__(self, fleet: AsyncFleet, queue: asyncio.Queue[Sample | None]) -> None:
        self._fleet = fleet
        self._queue = queue

    def __aiter__(self) -> SampleStream:
        return self

    async def __anext__(self) -> Sample:
        while True:
            self._fleet.supervisor.check()
            sample = await self._queue.get()
            if sample is not None:
                return sample

    def drain(self) -> list[Sample]:
        """The samples waiting in the stream, taken without waiting for more."""
        waiting = []
        while not self._queue.empty():
            sample = self._queue.get_nowait()
            if sample is not None:
                waiting.append(sample)
        return waiting

    def close(self) -> None:
        if self._queue in self._fleet._subscribers:
            self._fleet._subscribers.remove(self._queue)


class RemoteNotAllowed(StarterbusError):
    """A remote caller asked for a command or a write the fleet file does not enable for that device."""


class AsyncDevice:
    """:class:`~starterbus.core.device.Device` for asyncio code: the same operations, awaited; each a job of the
    device's :class:`SerialJobs` (``jobs``) in the edge pool. The module's docstring says what a cancelled await
    does."""

    def __init__(self, device: Device) -> None:
        self.device = device
        self.jobs = SerialJobs()

    @classmethod
    def open_url(cls, url: str, model: str, **kwargs: object) -> AsyncDevice:
        return cls(open_device(url, model, **kwargs))  # type: ignore[arg-type]

    async def _run(self, fn: Callable[..., T], *args: object, **kwargs: object) -> T:
        future = self.jobs.submit(functools.partial(fn, *args, **kwargs))
        try:
            return await asyncio.wrap_future(future)
        except asyncio.CancelledError:
            if not future.cancel():  # under way: it runs to its end, and the device's next job waits for it
                future.add_done_callback(functools.partial(self._unawaited, getattr(fn, "__name__", "a call")))
            raise

    def _unawaited(self, what: str, future: Future[Any]) -> None:  # a pool thread
        error = future.exception()
        if error is not None:
            log.warning("%s: %s, whose await was cancelled, failed: %s", self.device.describe(), what, describe(error))

    async def open(self) -> AsyncDevice:
        await self._run(self.device.open)
        return self

    async def close(self) -> None:
        await self._run(self.device.close)

    async def __aenter__(self) -> AsyncDevice:
        return await self.open()

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def read(self, *keys: str) -> dict[str, Value]:
        return await self._run(self.device.read, *keys)

    async def status(self) -> Status:
        return await self._run(self.device.status)

    async def write(self, values: Mapping[str, float | int | str], **kwargs: object) -> list[Outcome]:
        return await self._run(self.device.write_many, values, **kwargs)

    async def command(self, command: Command, **kwargs: object) -> Outcome:
        return await self._run(self.device.command, command, **kwargs)


class AsyncFleet:
    """A running :class:`~starterbus.fleet.poller.FleetPoller` seen from asyncio.

    ``samples()`` streams every poll; ``remote_write`` / ``remote_command`` check the fleet file's ``remote``
    table, then run the guarded path on the device's bus between its polls, audited with ``actor``; the job's
    future is awaited through :func:`asyncio.wrap_future`.

    ``supervisor`` (:mod:`starterbus.core.supervision`) watches the poller's threads and whatever tasks the
    application runs beside it (``serve``'s edge node, the OPC UA server); if the poller fails, ``samples()``
    raises :class:`~starterbus.core.supervision.ServiceFailed`. ``sink`` is called with every sample in the thread
    that polled it (the scheduler's ``starterbus-io``, or the thread of a bus that polls by blocking) before
    asyncio sees it, as ``poll``'s sinks are (``serve --record`` hands its history recorder); each sample then
    reaches the event loop by one ``call_soon_threadsafe`` (docs/engine.md, "Choice", measures that hand-off).
    """

    def __init__(
        self,
        config: FleetConfig,
        *,
        queue_size: int = 10_000,
        supervisor: Supervisor | None = None,
        sink: Callable[[Sample], None] | None = None,
        **poller_kwargs: object,
    ) -> None:
        self.config = config
        self.supervisor = supervisor or Supervisor()
        self.sink = sink
        self._queue_size = queue_size
        self._poller_kwargs = poller_kwargs
        self._subscribers: list[asyncio.Queue[Sample | None]] = []
        self.dropped = 0  # samples a slow subscriber missed (its queue was full)
        self._loop: asyncio.AbstractEventLoop | None = None
        self.poller: FleetPoller | None = None

    async def __aenter__(self) -> AsyncFleet:
        self._loop = asyncio.get_running_loop()
        self.poller = FleetPoller(
            self.config,
            self._on_sample,
            supervisor=self.supervisor,
            **self._poller_kwargs,  # type: ignore[arg-type]
        )
        self.supervisor.on_fatal(self._on_failure)
        self.poller.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop_polling()

    async def stop_polling(self) -> None:
        """Stop polling and wait until every bus is done (again: nothing more happens). Then every sample polled is
        in the subscribers' streams: a service stopping on request publishes or stores them before it goes."""
        if self.poller is not None:
            await asyncio.wrap_future(edge_pool().submit(self.poller.stop))
        await asyncio.sleep(0)  # the hand-overs the buses made before they ended come first

    def _on_sample(self, sample: Sample) -> None:  # the thread that polled it
        try:
            if self.sink is not None:
                self.sink(sample)  # a sink that raises is the bus's failure; the sample still reaches asyncio
        finally:
            loop = self._loop
            if loop is not None and not loop.is_closed():
                loop.call_soon_threadsafe(self._deliver, sample)

    def _deliver(self, sample: Sample | None) -> None:  # the event loop; None: the poller failed
        for queue in self._subscribers:
            if sample is None and queue.full():
                queue.get_nowait()  # room for the end: a reader must not wait for samples that never come
                self.dropped += 1
            try:
                queue.put_nowait(sample)
            except asyncio.QueueFull:
                self.dropped += 1

    def _on_failure(self, _failure: ServiceFailed) -> None:  # any thread
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._deliver, None)

    def subscribe(self) -> SampleStream:
        """Every sample from this call on (registered at once, not at the first iteration: a consumer that
        starts reading later, after a slow start-up, misses nothing); close the stream when done."""
        queue: asyncio.Queue[Sample | None] = asyncio.Queue(self._queue_size)
        self._subscribers.append(queue)
        return SampleStream(self, queue)

    async def samples(self) -> AsyncIterator[Sample]:
        """Every sample from the first iteration on, in the order the poller produced them; raises
        :class:`~starterbus.core.supervision.ServiceFailed` if the service fails."""
        stream = self.subscribe()
        try:
            async for sample in stream:
                yield sample
        finally:
            stream.close()

    def device_config(self, name: str) -> DeviceConfig:
        try:
            return self.config.devices_by_name[name]
        except KeyError:
            raise RemoteNotAllowed(f"no device named {name!r} in {self.config.source}") from None

    async def run(self, name: str, fn: Callable[[Device], T]) -> T:
        """Run ``fn(device)`` on the device's bus between its polls and await its result."""
        poller = self.poller
        if poller is None:
            raise StarterbusError("the fleet is not running (use `async with AsyncFleet(...)`)")
        # a job the fleet would run in the submitting thread (after its end) runs in the pool: never on the loop
        return await asyncio.wrap_future(poller.submit(name, fn, elsewhere=edge_pool().run))

    async def remote_command(self, name: str, command: Command, *, actor: str) -> Outcome:
        if not self.device_config(name).remote.allows_command(command):
            raise RemoteNotAllowed(
                f"{name}: the fleet file does not allow the command {command.value!r} from remote callers "
                f"(add it to remote.commands of this device in {self.config.source})"
            )
        return await self.run(name, lambda device: device.command(command, actor=actor))

    async def remote_write(self, name: str, values: Mapping[str, float | int | str], *, actor: str) -> list[Outcome]:
        config = self.device_config(name)
        for key in values:
            device_key = self._key(config, key)
            if not config.remote.allows_write(device_key):
                raise RemoteNotAllowed(
                    f"{name}: the fleet file does not allow remote writes of {key!r} "
                    f"(add it to remote.write of this device in {self.config.source})"
                )
        return await self.run(name, lambda device: device.write_many(values, actor=actor))

    @staticmethod
    def _key(config: DeviceConfig, key: str) -> str:
        from starterbus.core.registry import get_profile

        return get_profile(config.model).point(key).key
