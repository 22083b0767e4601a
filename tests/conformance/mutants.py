"""Deliberately broken Modbus RTU transports, one bug each: the conformance kit must fail on every one of them
(``test_kit_catches_mutants.py``). Each row of issue 28's table of what the kit missed has at least one.

A mutant is what the registered ``modbus-rtu`` plugin opens while :func:`installed` is active, so the kit, the
cross-check and the fleet poller all get it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from unittest import mock

from starterbus.core.errors import DecodeError, RemoteDeviceError, StarterbusError, TimeoutError
from starterbus.core.model import PointDef, Reading
from starterbus.core.polling import PlannedRequest
from starterbus.core.profile import Profile
from starterbus.core.status import CW_BUS_CONTROL, Command, Status, status_with_currents
from starterbus.core.transport import Transport, TransportCounters
from starterbus.core.url import DeviceUrl
from starterbus.testing.faults import query_keys, with_query
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadRequest, Request, WriteRequest
from starterbus.transports.modbus.decoder import exception_meaning
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.driver.link import Link
from starterbus.transports.modbus.master.exchange import Exchange
from starterbus.transports.modbus.master.poll_plan import PollPlans
from starterbus.transports.modbus.plugin.rtu import ModbusRtuPlugin
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport
from starterbus.transports.modbus.url import DEFAULT_RETRIES, DEFAULT_TIMEOUT, URL_PARAMETERS, ModbusRtuConfig

Opener = Callable[[DeviceUrl, Profile], Transport]


@dataclass(frozen=True)
class Mutant:
    name: str
    row: str  # the row of issue 28's table it belongs to
    bug: str
    open: Opener


@contextlib.contextmanager
def installed(mutant: Mutant) -> Iterator[None]:
    """The ``modbus-rtu`` plugin opens ``mutant`` inside the context."""

    def open_mutant(self: ModbusRtuPlugin, url: DeviceUrl, profile: Profile) -> Transport:
        return mutant.open(url, profile)

    with mock.patch.object(ModbusRtuPlugin, "open", open_mutant):
        yield


def transport_class(cls: type[ModbusRtuTransport]) -> Opener:
    def opener(url: DeviceUrl, profile: Profile) -> Transport:
        return cls(url, profile)

    return opener


def with_config(change: Callable[[ModbusRtuConfig, DeviceUrl], ModbusRtuConfig]) -> Opener:
    def opener(url: DeviceUrl, profile: Profile) -> Transport:
        return ModbusRtuTransport(url, profile, change(ModbusRtuConfig.from_url(url, profile), url))

    return opener


def policy(config: ModbusRtuConfig, **changes: object) -> ModbusRtuConfig:
    return dataclasses.replace(config, policy=dataclasses.replace(config.policy, **changes))  # type: ignore[arg-type]


# -- status -------------------------------------------------------------------------------------------------------


class StatusWithoutCurrents(ModbusRtuTransport):
    def _read_status(self) -> Status:
        status = super()._read_status()
        return dataclasses.replace(status, currents={})


class CurrentsScaledWrongly(ModbusRtuTransport):
    def _read_status(self) -> Status:
        point = self.profile.role("status_word")
        assert point is not None
        readings = self._read_points([point, *self.profile.phase_currents()])
        scale = self.profile.phase_currents()[0].scale * 10
        return status_with_currents(self.profile, readings[0].raw, [r.raw for r in readings[1:]], scale=scale)


# -- addressing ----------------------------------------------------------------------------------------------------


class UnitIgnored(ModbusRtuTransport):
    """Prepared reads kept for every transport of the class, keyed by register only (not by unit)."""

    shared: dict[tuple[int, int], Exchange] = {}  # noqa: RUF012

    def _read_exchange(self, request: tuple[int, int]) -> Exchange:
        if request not in self.shared:
            self.shared[request] = Exchange(ReadRequest(self.unit, *request), self.config.policy, self._char_time)
        return self.shared[request]


def unit_unchecked(url: DeviceUrl, profile: Profile) -> Transport:
    """Parses the URL with a unit it knows is valid, then takes the one given, unchecked."""
    given = url.query.get("unit", "")
    config = ModbusRtuConfig.from_url(DeviceUrl.parse(with_query(url.text, unit=1)), profile)
    return ModbusRtuTransport(url, profile, dataclasses.replace(config, unit=int(given) if given.isdigit() else 1))


def unknown_parameters_ignored(url: DeviceUrl, profile: Profile) -> Transport:
    known = [k for k in query_keys(url.text) if k in URL_PARAMETERS]
    text = url.text.partition("?")[0] + "?" + "&".join(f"{k}={url.query[k]}" for k in known)
    return ModbusRtuTransport(url, profile, ModbusRtuConfig.from_url(DeviceUrl.parse(text), profile))


# -- writes and commands -------------------------------------------------------------------------------------------


class WritesSentTwice(ModbusRtuTransport):
    def _write_parameter(self, point: PointDef, raw: int) -> None:
        super()._write_parameter(point, raw)
        super()._write_parameter(point, raw)  # "to be sure"


class WrongPreviewValue(ModbusRtuTransport):
    def _preview_write(self, point: PointDef, raw: int) -> list[str]:
        return [WriteRequest(self.unit, self._address(point), (raw + 1) & 0xFFFF).encode().hex(" ").upper()]


class PreviewWithoutBusControl(ModbusRtuTransport):
    def _preview_command(self, command: Command) -> list[str]:
        return [
            WriteRequest(r.unit, r.address, r.value & ~CW_BUS_CONTROL).encode().hex(" ").upper()
            for r in self._control_requests(command)
        ]


class BusControlDropped(ModbusRtuTransport):
    def _control_requests(self, command: Command) -> list[WriteRequest]:
        return [WriteRequest(r.unit, r.address, r.value & ~CW_BUS_CONTROL) for r in super()._control_requests(command)]


class ResetOnlyOnce(ModbusRtuTransport):
    """Skips a reset it has already sent ("nothing changed since")."""

    reset_sent = False

    def _send_command(self, command: Command) -> None:
        if command is Command.FAULT_RESET and self.reset_sent:
            self.control.apply(command)
            return
        super()._send_command(command)
        self.reset_sent = self.reset_sent or command is Command.FAULT_RESET


# -- refusals ------------------------------------------------------------------------------------------------------


class ExceptionCodeLost(ModbusRtuTransport):
    def _remote_error(self, request: Request, response: ExceptionResponse) -> StarterbusError:
        return RemoteDeviceError("modbus-rtu", 4, "server device failure", detail=self.describe())


class GatewayNoAnswerIsARefusal(ModbusRtuTransport):
    def _remote_error(self, request: Request, response: ExceptionResponse) -> StarterbusError:
        meaning = exception_meaning(self.profile, response.code)
        return RemoteDeviceError("modbus-rtu", response.code, meaning, detail=self.describe())


class BusyReadAsZero(ModbusRtuTransport):
    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        try:
            return super()._read_points(points)
        except RemoteDeviceError as exc:
            if exc.code != 6:
                raise
            return [Reading(p, 0) for p in points]


# -- timing: timeouts, retries, late and duplicated answers ------------------------------------------------------------


class KeepsLateAnswersLine(RtuLine):
    """No quarantine after a failed attempt, no input discarded before a request."""

    def failed(self, exchange: Exchange, exc: TimeoutError | DecodeError, attempt: int) -> None:
        if attempt >= exchange.attempts:
            raise exc
        self.retries += 1

    def _wait_quiet(self, exchange: Exchange) -> float:
        return self.clock()


class KeepsLateAnswers(ModbusRtuTransport):
    def _make_line(self) -> RtuLine:
        return KeepsLateAnswersLine(self._connect, self.config.serial)


class BlindLink(Link):
    """Never looks at input outside a transaction: no discarding, no trailing bytes seen."""

    def take_input(self, limit: int = 512) -> bytes:
        return b""

    def wait_readable(self, timeout: float) -> bool:
        time.sleep(max(0.0, min(timeout, 0.05)))
        return False


class KeepsDuplicates(ModbusRtuTransport):
    def _connect(self) -> Link:
        link = super()._connect()
        link.__class__ = BlindLink
        return link


# -- the fleet path: plan, counters, probing, merging ----------------------------------------------------------------


class EmptyPlan(ModbusRtuTransport):
    def plan(self, points: Sequence[PointDef], status: bool) -> list[PlannedRequest]:
        return []


class PlanLies(ModbusRtuTransport):
    """Says one request per point; the poll merges them."""

    def plan(self, points: Sequence[PointDef], status: bool) -> list[PlannedRequest]:
        return [PlannedRequest(f"read {p.key}", 1) for p in points] + ([PlannedRequest("status", 1)] if status else [])


class CountersNeverCounted(ModbusRtuTransport):
    def counters(self) -> TransportCounters:
        return TransportCounters()


class TimeoutsNotCounted(ModbusRtuTransport):
    def counters(self) -> TransportCounters:
        return dataclasses.replace(super().counters(), timeouts=0)


class ProbePolicyIgnored(ModbusRtuTransport):
    @contextlib.contextmanager
    def probe_policy(self, timeout: float) -> Iterator[None]:
        yield


class NoRequestMerging(ModbusRtuTransport):
    def __init__(self, url: DeviceUrl, profile: Profile, config: ModbusRtuConfig | None = None) -> None:
        super().__init__(url, profile, config)
        self.max_read = 1
        self.poll_plans = PollPlans(profile, 1, self.config.serial.baudrate, self.config.serial.silence)


MUTANTS = [
    Mutant("status_without_currents", "status without currents", "the status has no currents",
           transport_class(StatusWithoutCurrents)),
    Mutant("currents_scaled_wrongly", "status wrongly scaled", "currents 10 x too large",
           transport_class(CurrentsScaledWrongly)),
    Mutant("unit_ignored", "unit id ignored", "prepared reads shared across units",
           transport_class(UnitIgnored)),
    Mutant("writes_retried", "writes retried", "retry_writes forced on",
           with_config(lambda c, u: policy(c, retry_writes=True))),
    Mutant("writes_sent_twice", "writes retried", "every write sent twice", transport_class(WritesSentTwice)),
    Mutant("late_answers_kept", "late answers kept", "no quarantine, no discarding",
           transport_class(KeepsLateAnswers)),
    Mutant("duplicates_kept", "late answers kept", "input never discarded, trailing bytes never seen",
           transport_class(KeepsDuplicates)),
    Mutant("exception_code_lost", "exception code lost", "every exception reads 04 server device failure",
           transport_class(ExceptionCodeLost)),
    Mutant("busy_read_as_zero", "exception code lost", "a busy answer read as zeros", transport_class(BusyReadAsZero)),
    Mutant("wrong_preview_value", "wrong preview value", "the preview writes raw + 1",
           transport_class(WrongPreviewValue)),
    Mutant("preview_without_bus_control", "wrong preview value", "a command's preview lacks bit 3",
           transport_class(PreviewWithoutBusControl)),
    Mutant("empty_plan", "empty plan", "plan() is empty", transport_class(EmptyPlan)),
    Mutant("plan_lies", "empty plan", "the plan says one request per point", transport_class(PlanLies)),
    Mutant("counters_never_counted", "counters never counted", "fresh zero counters",
           transport_class(CountersNeverCounted)),
    Mutant("timeouts_not_counted", "counters never counted", "timeouts never counted",
           transport_class(TimeoutsNotCounted)),
    Mutant("probe_policy_ignored", "probe policy ignored", "probes retry at the full timeout",
           transport_class(ProbePolicyIgnored)),
    Mutant("reset_only_once", "a reset that does nothing the second time", "a second reset is not sent",
           transport_class(ResetOnlyOnce)),
    Mutant("bus_control_dropped", "bus-control bit dropped", "commands without bit 3",
           transport_class(BusControlDropped)),
    Mutant("timeout_ignored", "timeouts ignored", "the URL's timeout ignored (0.5 s)",
           with_config(lambda c, u: policy(c, timeout=DEFAULT_TIMEOUT, quarantine=DEFAULT_TIMEOUT))),
    Mutant("retries_ignored", "retries ignored", "the URL's retries ignored (2)",
           with_config(lambda c, u: policy(c, retries=DEFAULT_RETRIES))),
    Mutant("gateway_no_answer_is_a_refusal", "gateway 'target device failed to respond' taken as a refusal",
           "0x0A/0x0B raised as the device's refusal", transport_class(GatewayNoAnswerIsARefusal)),
    Mutant("no_request_merging", "no request merging", "one register per request",
           transport_class(NoRequestMerging)),
    Mutant("unit_range_unchecked", "unit range unchecked", "any unit accepted", unit_unchecked),
    Mutant("unknown_parameters_ignored", "unit range unchecked", "unknown URL parameters accepted",
           unknown_parameters_ignored),
]  # fmt: skip
