"""The ``modbus-rtu`` client transport: points, status and commands over FC03/FC06.

Reads are grouped: the registers asked for are sorted, adjacent ones merged into one FC03 request of at most
the profile's ``max_read_registers``, and the values handed back in the order asked. The status is one merged
read of the status word and the phase currents. Commands write the control word (FC06) through the core
:class:`ControlWordState`: the bus-control bit is held, a fault reset is the word with bit 2, then without.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Sequence

from starterbus.core import (
    ALL_CAPABILITIES,
    Capability,
    Command,
    ConfigurationError,
    ControlWordState,
    DeviceUrl,
    PlannedRequest,
    PointDef,
    PollResult,
    PollTask,
    Profile,
    Reading,
    RemoteDeviceError,
    SharedPool,
    StarterbusError,
    Status,
    TimeoutError,
    Transport,
    TransportCounters,
    UnsupportedOperationError,
    readings,
    status_with_currents,
)
from starterbus.transports.modbus.codec.messages import (
    BROADCAST,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteRegistersRequest,
    WriteRequest,
)
from starterbus.transports.modbus.codec.timing import char_time
from starterbus.transports.modbus.decoder import exception_meaning
from starterbus.transports.modbus.driver.line import Exchange, Link, RtuLine
from starterbus.transports.modbus.driver.line_task import LineTask
from starterbus.transports.modbus.master.poll_plan import PollPlan, PollPlans, sort_out
from starterbus.transports.modbus.master.poll_plan import run as run_poll_plan
from starterbus.transports.modbus.settings import PROTOCOL, TRANSPORT, max_read_registers
from starterbus.transports.modbus.url import ModbusRtuConfig

#: one line object per serial port / TCP endpoint in this process
LINES: SharedPool[RtuLine] = SharedPool("modbus-rtu lines")

#: exception codes a gateway sends about the device behind it (0x0A path unavailable, 0x0B target device failed
#: to respond): the device did not answer, it refused nothing (offline and probed, never a refusal)
GATEWAY_CODES = frozenset({0x0A, 0x0B})

#: prepared requests (and read plans) a transport keeps per kind; a poller repeats a handful of them
CACHE_SIZE = 256


def plan_reads(addresses: Sequence[int], limit: int) -> list[tuple[int, int]]:
    """(start, count) requests covering ``addresses``: adjacent registers merged, at most ``limit`` each."""
    plan: list[tuple[int, int]] = []
    for address in sorted(set(addresses)):
        if plan:
            start, count = plan[-1]
            if address == start + count and count < limit:
                plan[-1] = (start, count + 1)
                continue
        plan.append((address, 1))
    return plan


def value_positions(addresses: Sequence[int], plan: Sequence[tuple[int, int]]) -> tuple[int, ...]:
    """Where each address's value is in the values of the ``plan``'s requests, one after another."""
    position: dict[int, int] = {}
    for start, count in plan:
        for address in range(start, start + count):
            position[address] = len(position)
    return tuple(position[address] for address in addresses)


class _KnownPoints:
    """A list of points read before: the prepared requests that read them, where each value is in their answers,
    and the last words read with the readings made of them."""

    __slots__ = ("exchanges", "last", "points", "positions")

    def __init__(self, points: tuple[PointDef, ...], exchanges: list[Exchange], positions: tuple[int, ...]) -> None:
        self.points = points  # held, so that their ids stay theirs
        self.exchanges = exchanges
        self.positions = positions
        self.last: tuple[tuple[int, ...], tuple[Reading, ...]] = ((), ())


def request_text(request: Request) -> str:
    """What ``request`` asks, as a refusal names it."""
    if isinstance(request, ReadRequest):
        return f"FC03 read {request.count} register(s) from 0x{request.address:04X}"
    if isinstance(request, WriteRegistersRequest):
        return f"FC16 write {len(request.values)} register(s) from 0x{request.address:04X}"
    return f"FC06 write 0x{request.value:04X} to 0x{request.address:04X}"


class ModbusRtuTransport(Transport):
    name = TRANSPORT

    def __init__(self, url: DeviceUrl, profile: Profile, config: ModbusRtuConfig | None = None) -> None:
        super().__init__(url, profile)
        self.config = config or ModbusRtuConfig.from_url(url, profile)
        self.unit = self.config.unit
        where = "broadcast" if self.config.broadcast else f"unit {self.unit}"
        self._where = f"{self.config.target} {where}"
        self._source = f"{TRANSPORT} {self._where}"  # a status's source, made once: a poller asks every round
        self.max_read = max_read_registers(profile)
        self.control = ControlWordState()
        self._line: RtuLine | None = None
        control = profile.role("control_word")
        self._control_address = control.address_for(PROTOCOL) if control is not None else None
        self._char_time = char_time(self.config.serial.baudrate)
        self._reads: dict[tuple[int, int], Exchange] = {}  # (address, count) -> the FC03 exchange
        self._writes: dict[tuple[int, int], Exchange] = {}  # (address, value) -> the FC06 exchange
        #: addresses -> the requests that read them and where each value is in their answers
        self._plans: dict[tuple[int, ...], tuple[list[tuple[int, int]], tuple[int, ...]]] = {}
        self.poll_plans = PollPlans(profile, self.max_read, self.config.serial.baudrate, self.config.serial.silence)
        self._counters = TransportCounters()
        self._points: dict[tuple[int, ...], _KnownPoints] = {}  # ids of the points asked for -> their requests
        #: id of a poll plan -> the plan (held: its id stays its own) and its prepared requests
        self._poll_exchanges: dict[int, tuple[PollPlan, tuple[Exchange, ...]]] = {}

    # -- lifecycle ------------------------------------------------------------------------------------------

    def _connect(self) -> Link:
        return self.config.connect()

    def _make_line(self) -> RtuLine:
        config = self.config
        return RtuLine(
            self._connect, config.serial, start_connect=config.start_connect if config.variant == "tcp" else None
        )

    def _open(self) -> None:
        line = LINES.acquire(self.config.line_key, self._make_line)
        try:
            line.check_settings(self.config.serial)
        except ConfigurationError:
            LINES.release(self.config.line_key)
            raise
        self._line = line

    def _close(self) -> None:
        if self._line is not None:
            self._line = None
            LINES.release(self.config.line_key)

    @property
    def line(self) -> RtuLine:
        if self._line is None:
            raise self._not_open()
        return self._line

    @property
    def capabilities(self) -> frozenset[Capability]:
        return ALL_CAPABILITIES

    def describe(self) -> str:
        return self._where

    # -- transactions ------------------------------------------------------------------------------------------

    def _remote_error(self, request: Request, response: ExceptionResponse) -> StarterbusError:
        """The device's refusal; a gateway's 0x0A / 0x0B: no answer from the device behind it (TimeoutError)."""
        what = request_text(request)
        if response.code in GATEWAY_CODES:
            return TimeoutError(
                f"{self.describe()}: no answer from the device behind the gateway: exception 0x{response.code:02X} "
                f"({exception_meaning(self.profile, response.code)}) to {what}"
            )
        return RemoteDeviceError(
            TRANSPORT,
            response.code,
            exception_meaning(self.profile, response.code),
            detail=f"{what} at {self.describe()}",
            data=response.encode(),
        )

    def execute(self, request: Request) -> Response | None:
        """One transaction; an exception answer becomes :class:`RemoteDeviceError`."""
        return self._run(Exchange(request, self.config.policy, self._char_time))

    def _run(self, exchange: Exchange) -> Response | None:
        response = (self._line or self.line).run(exchange, self._counters)  # the property raises "not open"
        self._refuse_exceptions(exchange, response)
        return response

    def _prepare(self, cache: dict[tuple[int, int], Exchange], key: tuple[int, int], request: Request) -> Exchange:
        exchange = Exchange(request, self.config.policy, self._char_time)  # an invalid request raises here
        if len(cache) >= CACHE_SIZE:
            cache.clear()
        cache[key] = exchange
        return exchange

    def _read_exchange(self, request: tuple[int, int]) -> Exchange:
        """The FC03 exchange reading ``(address, count)``, prepared once and kept."""
        return self._reads.get(request) or self._prepare(self._reads, request, ReadRequest(self.unit, *request))

    def _no_broadcast_reads(self) -> None:
        if self.unit == BROADCAST:
            raise ConfigurationError(
                f"{self.url.text}: unit 0 is the broadcast address: no device answers a read (give one device's unit)"
            )

    def read_registers(self, address: int, count: int) -> tuple[int, ...]:
        """Raw FC03 (no splitting): ``count`` registers from ``address``."""
        exchange = self._reads.get((address, count))
        if exchange is None:  # a broadcast transport never gets this far, so never has a read cached
            self._no_broadcast_reads()
            exchange = self._read_exchange((address, count))
        response = (self._line or self.line).run(exchange, self._counters)  # as _run, one call less
        if isinstance(response, ReadResponse):
            return response.values
        assert isinstance(response, ExceptionResponse)
        raise self._remote_error(exchange.request, response)

    def write_register(self, address: int, value: int) -> None:
        """Raw FC06 (checked echo; nothing to check for a broadcast)."""
        exchange = self._writes.get((address, value))
        if exchange is None:
            exchange = self._prepare(self._writes, (address, value), WriteRequest(self.unit, address, value))
        self._run(exchange)

    def preview_register_write(self, address: int, value: int) -> list[str]:
        """The FC06 frame :meth:`write_register` would send (``write --raw --dry-run``)."""
        return [self._frame_text(WriteRequest(self.unit, address, value))]

    # -- Transport operations ----------------------------------------------------------------------------------

    def _address(self, point: PointDef) -> int:
        address: int | None = point.address_for(PROTOCOL)
        if address is None:
            raise UnsupportedOperationError(f"{self.profile.display_name} {point.key} has no Modbus register")
        return address

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        key = tuple(map(id, points))  # the profile's point objects live as long as the transport
        known = self._points.get(key) or self._point_requests(points, key)
        line = self._line or self.line
        values: tuple[int, ...] = ()
        for exchange in known.exchanges:
            response = line.run(exchange, self._counters)  # as _run, one call less
            if not isinstance(response, ReadResponse):
                assert isinstance(response, ExceptionResponse)
                raise self._remote_error(exchange.request, response)
            values += response.values
        last_values, last_readings = known.last
        if values == last_values:  # the same words: the same (immutable) readings
            return list(last_readings)
        made = readings(known.points, [values[i] for i in known.positions])
        known.last = (values, tuple(made))  # one assignment: another thread sees the old pair or the new one
        return made

    def _point_requests(self, points: Sequence[PointDef], key: tuple[int, ...]) -> _KnownPoints:
        self._no_broadcast_reads()
        addresses = tuple(self._address(p) for p in points)
        plan, positions = self._plans.get(addresses) or self._plan(addresses)
        exchanges = [self._read_exchange(request) for request in plan]
        known = _KnownPoints(tuple(points), exchanges, positions)
        if len(self._points) >= CACHE_SIZE:
            self._points.clear()
        self._points[key] = known
        return known

    def _plan(self, addresses: tuple[int, ...]) -> tuple[list[tuple[int, int]], tuple[int, ...]]:
        plan = plan_reads(addresses, self.max_read)
        if len(self._plans) >= CACHE_SIZE:
            self._plans.clear()
        self._plans[addresses] = plan, value_positions(addresses, plan)
        return self._plans[addresses]

    def _write_parameter(self, point: PointDef, raw: int) -> None:
        self.write_register(self._address(point), raw)

    # -- fleet polling: one merged plan per (points, status), see poll_plan.py -----------------------------------

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        self._no_broadcast_reads()
        plan = self.poll_plans.get(points, status)
        return run_poll_plan(self.read_registers, plan, points, self.profile, self._source)

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        line = self._line or self.line
        if line.link.fd < 0:  # pyserial without a file descriptor: blocking reads only
            return None
        self._no_broadcast_reads()
        plan = self.poll_plans.get(points, status)
        kept = self._poll_exchanges.get(id(plan))
        if kept is None or kept[0] is not plan:
            kept = (plan, tuple(self._read_exchange(request) for request in plan.requests))
            if len(self._poll_exchanges) >= CACHE_SIZE:
                self._poll_exchanges.clear()
            self._poll_exchanges[id(plan)] = kept

        def finish(responses: list[Response]) -> PollResult:
            values: tuple[int, ...] = ()
            for response in responses:
                assert isinstance(response, ReadResponse)  # _refuse_exceptions let nothing else through
                values += response.values
            return sort_out(plan, values, points, self.profile, self._source)

        return LineTask(line, kept[1], self._counters, self._refuse_exceptions, finish)

    def _refuse_exceptions(self, exchange: Exchange, response: Response | None) -> None:
        """An exception answer becomes :class:`RemoteDeviceError`."""
        if isinstance(response, ExceptionResponse):
            raise self._remote_error(exchange.request, response)

    def plan(self, points: Sequence[PointDef], status: bool) -> list[PlannedRequest]:
        return self.poll_plans.describe(self.poll_plans.get(points, status), self.unit)

    def counters(self) -> TransportCounters:
        return self._counters

    @contextlib.contextmanager
    def probe_policy(self, timeout: float) -> Iterator[None]:
        """One attempt, at most ``timeout`` s: requests made inside use a policy of their own (fresh caches)."""
        normal = self.config, self._reads, self._writes, self._points, self._poll_exchanges
        policy = dataclasses.replace(self.config.policy, retries=0, timeout=min(timeout, self.config.policy.timeout))
        self.config, self._reads, self._writes, self._points, self._poll_exchanges = (
            dataclasses.replace(self.config, policy=policy),
            {},
            {},
            {},
            {},
        )
        try:
            yield
        finally:
            self.config, self._reads, self._writes, self._points, self._poll_exchanges = normal

    def _read_status(self) -> Status:
        self._no_broadcast_reads()
        status_point = self.profile.role("status_word")
        if status_point is None:
            raise UnsupportedOperationError(f"{self.profile.display_name} has no status word")
        readings = self._read_points([status_point, *self.profile.phase_currents()])
        return status_with_currents(
            self.profile,
            readings[0].raw,
            [r.raw for r in readings[1:]],
            source=self._source,
            current_source=TRANSPORT,
        )

    def _control_requests(self, command: Command) -> list[WriteRequest]:
        if self._control_address is None:
            raise UnsupportedOperationError(f"{self.profile.display_name} has no control word register")
        state = ControlWordState(self.control.bus_control, self.control.run)
        return [WriteRequest(self.unit, self._control_address, word) for word in state.apply(command)]

    def _send_command(self, command: Command) -> None:
        requests = self._control_requests(command)
        for request in requests:
            self.execute(request)
        self.control.apply(command)

    def _frame_text(self, request: Request) -> str:
        """What goes on the wire for ``request``, in hex (a TCP transport's MBAP frame)."""
        return request.encode().hex(" ").upper()

    def _preview_write(self, point: PointDef, raw: int) -> list[str]:
        return [self._frame_text(WriteRequest(self.unit, self._address(point), raw))]

    def _preview_command(self, command: Command) -> list[str]:
        return [self._frame_text(request) for request in self._control_requests(command)]
