"""The asyncio API: an async device and an async fleet (samples as an async stream, guarded remote commands).

Blocking I/O never runs on the event loop: a device's calls run in a worker thread (one at a time per device),
a fleet's polls and commands run in the poller's bus threads and come back through futures and a queue.

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
from collections.abc import AsyncIterator, Callable, Mapping
from types import TracebackType
from typing import TypeVar

from starterbus.core.device import Device, open_device
from starterbus.core.errors import StarterbusError
from starterbus.core.guarded import Outcome
from starterbus.core.model import Value
from starterbus.core.status import Command, Status
from starterbus.core.supervision import ServiceFailed, Supervisor
from starterbus.fleet.config import DeviceConfig, FleetConfig
from starterbus.fleet.poller import FleetPoller, Sample

T = TypeVar("T")


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
    """:class:`~starterbus.core.device.Device` for asyncio code: the same operations, awaited."""

    def __init__(self, device: Device) -> None:
        self.device = device
        self._lock = asyncio.Lock()

    @classmethod
    def open_url(cls, url: str, model: str, **kwargs: object) -> AsyncDevice:
        return cls(open_device(url, model, **kwargs))  # type: ignore[arg-type]

    async def _run(self, fn: Callable[..., T], *args: object, **kwargs: object) -> T:
        async with self._lock:
            return await asyncio.to_thread(functools.partial(fn, *args, **kwargs))

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
    table, then run the guarded path in the device's bus worker (between polls), audited with ``actor``.

    ``supervisor`` (:mod:`starterbus.core.supervision`) watches the poller's threads and whatever tasks the
    application runs beside it (``serve``'s edge node, the OPC UA server); if the poller fails, ``samples()``
    raises :class:`~starterbus.core.supervision.ServiceFailed`. ``sink`` is called in the bus thread with every
    sample before asyncio sees it, as ``poll``'s sinks are (``serve --record`` hands its history recorder).
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
            await asyncio.to_thread(self.poller.stop)
        await asyncio.sleep(0)  # the hand-overs the buses made before they ended come first

    def _on_sample(self, sample: Sample) -> None:  # a bus thread
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
        """Run ``fn(device)`` in the device's bus worker and await its result."""
        if self.poller is None:
            raise StarterbusError("the fleet is not running (use `async with AsyncFleet(...)`)")
        return await asyncio.wrap_future(self.poller.submit(name, fn))

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
