"""A simulated Profibus master gateway: a real pymodbus Modbus TCP server in front of simulated DP slaves.

Like a plant's Profibus-to-Modbus-TCP gateway, it has an output image (written by Modbus clients) and an input
image (read by them), and its own DP cycle: every ``cycle`` seconds each station's simulated slave gets its
output words and returns its input words. Station ``k`` (0-based, in the order given) has its outputs at
holding registers ``out + k * words`` and its inputs at ``inp + k * words`` (words = 4 for PPO1, 2 for PPO3).

Reads (FC03 and FC04) of an input register return the input image; reads elsewhere in an output area return the
output image; writes (FC06, FC16) go to the output image. So the output and input areas may share register
numbers (``out=0&in=0``, the usual "read = inputs, write = outputs" gateway layout) or be apart (then the
client can read its outputs back). Anything outside the mapped areas answers exception 02.

``unreachable`` (tests, the conformance kit): a callable given a station's index that says it has left data
exchange; the gateway then answers every request touching that station's registers with exception 0x0B ("gateway
target device failed to respond") and exchanges nothing with it, until the callable says otherwise.
``written`` (tests): called with a station's index and its output words after each Modbus write into them.

Programmatic use (in-process; :meth:`start` returns once the port is bound)::

    sim = ProfibusGatewaySimulator([starter], host="127.0.0.1", port=0, ppo=1).start()
    url = sim.url(0)          # profibus-pkw+gateway://127.0.0.1:PORT?ppo=1&out=0&in=0&unit=1
    ...
    sim.close()
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Sequence
from typing import Any

from starterbus.core import ConfigurationError, RunningSimulator, SimulatedStarter, TransportError
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, Ppo
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

_ILLEGAL_ADDRESS = 2


class ProfibusGatewaySimulator(RunningSimulator):
    """Serve simulated starters as DP stations behind a Modbus TCP gateway on ``host:port`` (0 = any free)."""

    def __init__(
        self,
        starters: SimulatedStarter | SimulatedDpSlave | Sequence[SimulatedStarter | SimulatedDpSlave],
        host: str = "127.0.0.1",
        port: int = 0,
        ppo: Ppo | int = Ppo.PPO1,
        *,
        out: int = 0,
        inp: int = 0,
        cycle: float = 0.005,
        latency: int = 0,
        unit: int = 1,
        stations: Sequence[int] | None = None,
    ) -> None:
        items = [starters] if isinstance(starters, (SimulatedStarter, SimulatedDpSlave)) else list(starters)
        if not items:
            raise ConfigurationError("a gateway needs at least one simulated starter")
        self.ppo = Ppo(ppo)
        self.slaves = [
            s if isinstance(s, SimulatedDpSlave) else SimulatedDpSlave(s, self.ppo, latency=latency) for s in items
        ]
        for slave in self.slaves:
            if slave.ppo is not self.ppo:
                raise ConfigurationError(f"slave {slave.name!r} is {slave.ppo.name}, the gateway maps {self.ppo.name}")
        if cycle <= 0:
            raise ConfigurationError("the gateway's DP cycle must be > 0 s")
        words = self.ppo.words
        self.out, self.inp, self.cycle, self.unit = out, inp, cycle, unit
        self.stations = list(stations) if stations is not None else list(range(1, len(self.slaves) + 1))
        if len(self.stations) != len(self.slaves):
            raise ConfigurationError("give one station address per simulated starter")
        size = max(out, inp) + words * len(self.slaves)
        if size > 0x10000:
            raise ConfigurationError(f"register areas out={out}, in={inp} for {len(self.slaves)} stations exceed 65536")
        self.host = host
        self.requested_port = port
        self.port = port
        self._size = size
        self._out_image = [0] * size
        self._in_image = [0] * size
        self._is_input = [False] * size
        self._is_output = [False] * size
        for k in range(len(self.slaves)):
            for i in range(words):
                self._is_output[out + k * words + i] = True
                self._is_input[inp + k * words + i] = True
        self.cycles = 0
        self.unreachable: Callable[[int], bool] | None = None
        self.written: Callable[[int, tuple[int, ...]], None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stopped: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._server: Any = None

    # -- lifecycle ---------------------------------------------------------------------------------------

    def start(self, timeout: float = 5.0) -> ProfibusGatewaySimulator:
        if self._thread is not None:
            return self
        self._exchange_all()  # the images hold real values before the first client connects
        self._thread = threading.Thread(target=self._thread_main, name=f"{PROTOCOL} gateway", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout) or self._error is not None:
            self.close()
            raise TransportError(
                f"{PROTOCOL} gateway simulator could not listen on {self.host}:{self.requested_port}: "
                f"{self._error or 'timeout'}"
            )
        return self

    def close(self) -> None:
        loop, thread = self._loop, self._thread
        if loop is not None and self._stopped is not None and loop.is_running():
            loop.call_soon_threadsafe(self._stopped.set)
        if thread is not None:
            thread.join(timeout=5.0)
        self._thread = None
        self._loop = None

    def __enter__(self) -> ProfibusGatewaySimulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- addressing ----------------------------------------------------------------------------------------

    def url(self, k: int = 0) -> str:
        words = self.ppo.words
        host = self.host if self.host not in ("", "0.0.0.0") else "127.0.0.1"
        return (
            f"{PROTOCOL}+gateway://{host}:{self.port}?ppo={self.ppo.value}"
            f"&out={self.out + k * words}&in={self.inp + k * words}&unit={self.unit}"
            f"&stale_time={2 * self.cycle:g}"  # the image lags up to a DP cycle: a status read waits past it
        )

    def client_urls(self) -> dict[int, str]:
        return {station: self.url(k) for k, station in enumerate(self.stations)}

    def describe(self) -> list[str]:
        lines = [f"{PROTOCOL}: Modbus TCP gateway {self.host}:{self.port}, {self.ppo.name}, DP cycle {self.cycle:g} s"]
        for k, (slave, station) in enumerate(zip(self.slaves, self.stations, strict=True)):
            lines.append(f"  station {station} ({slave.profile.display_name}): {self.url(k)}")
        return lines

    def output_words(self, k: int = 0) -> tuple[int, ...]:
        words = self.ppo.words
        start = self.out + k * words
        return tuple(self._out_image[start : start + words])

    def input_words(self, k: int = 0) -> tuple[int, ...]:
        words = self.ppo.words
        start = self.inp + k * words
        return tuple(self._in_image[start : start + words])

    # -- the DP side ---------------------------------------------------------------------------------------

    def _exchange_all(self) -> None:
        words = self.ppo.words
        unreachable = self.unreachable
        for k, slave in enumerate(self.slaves):
            if unreachable is not None and unreachable(k):
                continue
            o = self.out + k * words
            i = self.inp + k * words
            self._in_image[i : i + words] = slave.exchange(self._out_image[o : o + words])
        self.cycles += 1

    async def _dp_cycle(self) -> None:
        assert self._stopped is not None
        while not self._stopped.is_set():
            self._exchange_all()
            try:
                await asyncio.wait_for(self._stopped.wait(), self.cycle)
            except asyncio.TimeoutError:
                pass

    # -- the Modbus side -------------------------------------------------------------------------------------

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> Any:
        from pymodbus.constants import ExcCodes

        if address < 0 or address + count > self._size:
            return ExcCodes.ILLEGAL_ADDRESS
        if self.unreachable is not None and any(map(self.unreachable, self._stations_at(address, count))):
            return ExcCodes.GATEWAY_NO_RESPONSE
        if set_values is not None and function_code in (6, 16):
            if not all(self._is_output[address + i] for i in range(count)):
                return ExcCodes.ILLEGAL_ADDRESS
            for i, value in enumerate(set_values):
                self._out_image[address + i] = int(value) & 0xFFFF
            if self.written is not None:
                for k in sorted(self._stations_at(address, count)):
                    self.written(k, self.output_words(k))
            return None
        if function_code not in (3, 4):
            return ExcCodes.ILLEGAL_FUNCTION
        for i in range(count):
            a = address + i
            if self._is_input[a]:
                registers[a - start_address] = self._in_image[a]
            elif self._is_output[a]:
                registers[a - start_address] = self._out_image[a]
            else:
                return ExcCodes.ILLEGAL_ADDRESS
        return None

    def _stations_at(self, address: int, count: int) -> set[int]:
        """The indexes of the stations whose output or input registers ``address`` to ``address + count`` touch."""
        words, stations = self.ppo.words, len(self.slaves)
        touched: set[int] = set()
        for start in (self.out, self.inp):
            first, last = (address - start) // words, (address + count - 1 - start) // words
            touched.update(range(max(first, 0), min(last, stations - 1) + 1))
        return touched

    def _thread_main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import DataType, SimData, SimDevice

        self._stopped = asyncio.Event()
        device = SimDevice(
            id=0,  # every unit id: a gateway answers whatever unit the client uses
            simdata=[SimData(address=0, count=self._size, values=0, datatype=DataType.REGISTERS)],
            action=self._action,
        )
        server: Any = ModbusTcpServer(device, address=(self.host, self.requested_port))
        self._server = server
        await server.serve_forever(background=True)
        listener: Any = server.transport
        if listener is None:
            raise TransportError(f"cannot listen on {self.host}:{self.requested_port}")
        self.port = int(listener.sockets[0].getsockname()[1])
        self._ready.set()
        try:
            await self._dp_cycle()
        finally:
            await server.shutdown()
