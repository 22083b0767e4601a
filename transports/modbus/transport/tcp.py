"""The ``modbus-tcp`` client transport: the Modbus RTU transport's reads, writes, commands, poll plans and
counters, over MBAP to a Modbus TCP gateway (or device) instead of a serial line.

``modbus-tcp://HOST:PORT?unit=N&timeout=1&retries=2&outstanding=1``. Every device of the process that names one
HOST:PORT shares one connection (:data:`GATEWAYS`); what differs from RTU is only how a request travels
(:class:`~starterbus.transports.modbus.driver.tcp_line.MbapConnection`). Every parameter is in ``docs/modbus.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from starterbus.core import (
    ConfigurationError,
    DeviceUrl,
    PointDef,
    PollResult,
    PollTask,
    Profile,
    RemoteDeviceError,
    StarterbusError,
    Status,
    status_with_currents,
)
from starterbus.spaces.modbus import MAX_UNIT, ModbusSettings
from starterbus.transports.modbus.codec.messages import (
    AnyRequest,
    ExceptionResponse,
    ReadResponse,
    Request,
    Response,
)
from starterbus.transports.modbus.codec.timing import silent_interval
from starterbus.transports.modbus.decoder import exception_meaning
from starterbus.transports.modbus.driver.link import SerialSettings
from starterbus.transports.modbus.driver.tcp_line import CONNECTIONS, MbapConnection, MbapPoll, connection_key
from starterbus.transports.modbus.master.exchange import TransactionPolicy
from starterbus.transports.modbus.master.mbap import encode_adu
from starterbus.transports.modbus.master.poll_plan import sort_out
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport, request_text
from starterbus.transports.modbus.url import DEFAULT_RETRIES, ModbusRtuConfig

NAME = "modbus-tcp"
DEFAULT_PORT = 502
DEFAULT_TIMEOUT = 1.0  # a gateway adds its own serial timeout to the device's answer
URL_PARAMETERS = ("unit", "timeout", "retries", "retry_writes", "outstanding", "baudrate")

#: one connection per gateway (HOST:PORT) in this process, shared by every unit behind it (and by Profibus PKW
#: gateway stations mapped on the same HOST:PORT)
GATEWAYS = CONNECTIONS


@dataclass(frozen=True, slots=True)
class ModbusTcpConfig(ModbusRtuConfig):
    """What a ``modbus-tcp`` URL says. ``serial`` describes the line behind the gateway (its baud rate prices a
    poll plan's requests, as on RTU); ``outstanding``: transactions on the connection at once."""

    outstanding: int = 1

    @property
    def line_key(self) -> tuple[str, str, int]:
        return connection_key(self.host, self.port)

    @property
    def target(self) -> str:
        return f"{self.host}:{self.port}"

    @classmethod
    def from_tcp_url(cls, url: DeviceUrl, profile: Profile) -> ModbusTcpConfig:
        url.check_known(URL_PARAMETERS)
        if url.variant:
            raise ConfigurationError(f"{url.text}: {url.scheme} has no variants (write modbus-tcp://HOST:PORT?unit=N)")
        if url.path not in ("", "/"):
            raise ConfigurationError(f"{url.text}: a modbus-tcp URL has no path (got {url.path!r})")
        host, port = url.host_port(DEFAULT_PORT)
        if "unit" not in url.query:
            raise ConfigurationError(f"{url.text}: unit: required URL parameter missing (the unit id, e.g. unit=2)")
        unit = url.get_int("unit", None, 1, MAX_UNIT)
        settings = ModbusSettings.of(profile)
        lo, hi = settings.unit_ids
        if not max(lo, 1) <= unit <= hi:
            raise ConfigurationError(
                f"{url.text}: unit: {unit} is not a {profile.display_name} slave address: "
                f"{profile.display_name} slave addresses are {max(lo, 1)}..{hi}"
            )
        baudrate = url.get_int("baudrate", settings.default_baudrate, 1, 10_000_000)
        timeout = url.get_float("timeout", DEFAULT_TIMEOUT, 0.001, 60.0)
        policy = TransactionPolicy(
            timeout=timeout,
            retries=url.get_int("retries", DEFAULT_RETRIES, 0, 10),
            retry_writes=url.get_bool("retry_writes", False),
            turnaround=0.0,
            quarantine=timeout,
        )
        return cls(
            variant=NAME,
            path="",
            host=host,
            port=port,
            unit=unit,
            serial=SerialSettings(baudrate, "N", 1, 8, silent_interval(baudrate), False),
            policy=policy,
            io="",
            outstanding=url.get_int("outstanding", 1, 1, 64),
        )


def adu_text(request: Request | AnyRequest) -> str:
    """The MBAP ADU ``request`` goes out as, in a preview; its transaction id is given when it is sent (``TT TT``
    here)."""
    pdu = request.encode()[1:-2]  # the RTU frame less its unit id and CRC
    adu = encode_adu(0, request.unit, pdu).hex(" ").upper()
    return f"TT TT{adu[5:]}  (MBAP; TT TT: the transaction id, given when sent)"


class ModbusTcpTransport(ModbusRtuTransport):
    name = NAME

    def __init__(self, url: DeviceUrl, profile: Profile, config: ModbusTcpConfig | None = None) -> None:
        self.tcp = config or ModbusTcpConfig.from_tcp_url(url, profile)
        super().__init__(url, profile, self.tcp)
        self._source = f"{NAME} {self._where}"
        self._gateway: MbapConnection | None = None
        status_word = profile.role("status_word")
        self._status_key = status_word.key if status_word is not None else ""

    def _open(self) -> None:
        tcp = self.tcp
        gateway = GATEWAYS.acquire(
            tcp.line_key, lambda: MbapConnection(tcp.host, tcp.port, tcp.outstanding, tcp.connect_timeout)
        )
        if gateway.outstanding != tcp.outstanding:
            GATEWAYS.release(tcp.line_key)
            raise ConfigurationError(
                f"{self.url.text}: outstanding: {gateway.name} is already open in this process with "
                f"outstanding={gateway.outstanding}: one connection has one setting"
            )
        self._gateway = gateway
        self._line = gateway  # type: ignore[assignment]  # the RTU transport's transactions go through it

    def _close(self) -> None:
        if self._gateway is not None:
            self._gateway = self._line = None
            GATEWAYS.release(self.tcp.line_key)

    def _frame_text(self, request: Request) -> str:
        return adu_text(request)

    def _remote_error(self, request: Request, response: ExceptionResponse) -> StarterbusError:
        """The device's own refusal, in the words of its manual (the gateway's 0x0A / 0x0B never get here)."""
        what = request_text(request)
        return RemoteDeviceError(
            NAME,
            response.code,
            exception_meaning(self.profile, response.code),
            detail=f"{what} at {self.describe()}",
            data=response.encode()[1:-2],
        )

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        """The plan's requests all on the connection at once (up to ``outstanding``), answers sorted out as RTU."""
        self._no_broadcast_reads()
        if self._gateway is None:
            raise self._not_open()
        plan = self.poll_plans.get(points, status)
        exchanges = [self._read_exchange(request) for request in plan.requests]
        values: tuple[int, ...] = ()
        # (answers up to the first refusal, which raises here: the transactions after it were withdrawn)
        for exchange, response in zip(exchanges, self._gateway.run_many(exchanges, self._counters), strict=False):
            self._refuse_exceptions(exchange, response)
            assert isinstance(response, ReadResponse)
            values += response.values
        return sort_out(plan, values, points, self.profile, self._source, NAME)

    def _read_status(self) -> Status:
        status = super()._read_status()  # the currents read as RTU reads them; tagged with this transport
        return status_with_currents(
            self.profile,
            status.raw[self._status_key],
            [c.raw for c in status.currents.values()],
            source=self._source,
            current_source=NAME,
        )

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        """The poll on the fleet's multiplexer: :meth:`_poll` without blocking."""
        self._no_broadcast_reads()
        if self._gateway is None:
            raise self._not_open()
        plan = self.poll_plans.get(points, status)
        exchanges = [self._read_exchange(request) for request in plan.requests]

        def finish(responses: list[Response]) -> PollResult:
            values: tuple[int, ...] = ()
            for response in responses:
                assert isinstance(response, ReadResponse)  # _refuse_exceptions let nothing else through
                values += response.values
            return sort_out(plan, values, points, self.profile, self._source, NAME)

        return MbapPoll(self._gateway, exchanges, self._counters, self._refuse_exceptions, finish)
