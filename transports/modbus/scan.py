"""Finding the Modbus RTU devices on a line: the speed, parity and unit ids they answer at, and their models.

A scan tries each line setting (baud rate, parity, stop bits) in turn; at each it sends one FC03 read of the
status word to every unit id of the range (one attempt, a short timeout). A unit that answers anything (a value
or an exception) is there. Its model is then told from its registers (:func:`identify`):

- **presence**: a register one model has and another has not answers a value on the first and exception 02
  (illegal data address) on the second; the probe set holds, for every pair of installed models, an address
  that only one of them has (chosen from the models' register maps);
- **values**: every probed register the model has must hold a value in that point's range (an enum's codes);
- **the slave-address parameter** (``slave_address``) must hold the unit id the device answered at.

A model is a candidate when every probe agrees with it; one candidate is the answer, several are listed (a
model whose register map another one contains entirely, and whose values fit both, cannot be told apart), none
is "unknown" (a model not installed, a firmware with other ranges). Nothing is written: reads only.

Behind a Modbus TCP gateway (:func:`scan_gateway`) there is no line setting to find: each unit id is read once
through the gateway's one connection; no answer, and the gateway's exceptions 0x0A (path unavailable) and 0x0B
(target device failed to respond), mean nobody there; the model is told the same way.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from itertools import combinations

from starterbus.core import DecodeError, DeviceUrl, PointDef, Profile, RemoteDeviceError, TimeoutError
from starterbus.transports.modbus.codec.messages import ExceptionResponse, ReadRequest, ReadResponse
from starterbus.transports.modbus.codec.timing import char_time, silent_interval
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.driver.link import SerialSettings
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.settings import PROTOCOL
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport
from starterbus.transports.modbus.url import ModbusRtuConfig

ILLEGAL_ADDRESS = 0x02
SLAVE_ADDRESS = "slave_address"
Progress = Callable[[str], None]
#: a register read: its value, or the exception code the device answered
Read = Callable[[int], "int | ExceptionResponse"]


@dataclass(frozen=True, slots=True)
class Setting:
    baudrate: int
    parity: str
    stopbits: int = 1

    def describe(self) -> str:
        return f"{self.baudrate} 8{self.parity}{self.stopbits}"


@dataclass(frozen=True, slots=True)
class Found:
    """A unit that answered: where, and what it is (``model`` None: unknown or ambiguous, see ``candidates``)."""

    unit: int
    setting: Setting | None  # None: behind a Modbus TCP gateway (no line setting to tell)
    model: str | None
    candidates: tuple[str, ...]
    why: str


def register_map(profile: Profile) -> dict[int, PointDef]:
    return {a: p for p in profile.points.values() if (a := p.address_for(PROTOCOL)) is not None}


def probe_addresses(profiles: Sequence[Profile]) -> list[int]:
    """The registers read to tell the models apart: each model's slave-address register, then for every pair of
    models still not told apart by presence an address one of them has and the other has not."""
    maps = {p.name: register_map(p) for p in profiles}
    chosen: list[int] = []
    for profile in profiles:
        point = profile.points.get(SLAVE_ADDRESS)
        address = point.address_for(PROTOCOL) if point is not None else None
        if address is not None and address not in chosen:
            chosen.append(address)
    for first, second in combinations(maps, 2):
        if any((a in maps[first]) != (a in maps[second]) for a in chosen):
            continue
        differing = sorted(set(maps[first]) ^ set(maps[second]))
        if differing:
            chosen.append(differing[0])
    return chosen


def agrees(profile: Profile, unit: int, answers: dict[int, int | ExceptionResponse]) -> str | None:
    """None when every answer fits the model, else why not."""
    registers = register_map(profile)
    for address, answer in answers.items():
        point = registers.get(address)
        if point is None:
            if not (isinstance(answer, ExceptionResponse) and answer.code == ILLEGAL_ADDRESS):
                return f"0x{address:04X} answers, and {profile.display_name} has no such register"
            continue
        if isinstance(answer, ExceptionResponse):
            return f"{profile.display_name} {point.key} (0x{address:04X}) answers exception {answer.code:02X}"
        if not point.raw_min <= answer <= point.raw_max or (point.enum is not None and answer not in point.enum.labels):
            return f"{profile.display_name} {point.key} (0x{address:04X}) holds {answer}, outside its range"
        if point.key == SLAVE_ADDRESS and answer != unit:
            return f"{profile.display_name} {point.key} holds {answer}, not the unit {unit} that answered"
    return None


def identify(read: Read, unit: int, profiles: Sequence[Profile]) -> tuple[str | None, tuple[str, ...], str]:
    """(the model, every candidate, why) from the registers of the unit ``read`` reads."""
    answers = {address: read(address) for address in probe_addresses(profiles)}
    reasons = {p.name: agrees(p, unit, answers) for p in profiles}
    candidates = tuple(name for name, why in reasons.items() if why is None)
    if len(candidates) == 1:
        return candidates[0], candidates, f"its registers fit {candidates[0]} only"
    if candidates:
        return None, candidates, f"its registers fit {', '.join(candidates)}: tell the model in the fleet file"
    return None, (), "; ".join(why for why in reasons.values() if why)


def settings(baudrates: Iterable[int], parities: Iterable[str], stopbits: Iterable[int]) -> list[Setting]:
    return [Setting(b, p, s) for b in baudrates for p in parities for s in stopbits]


def scan_line(
    url: DeviceUrl,
    profiles: Sequence[Profile],
    tries: Sequence[Setting],
    units: Sequence[int],
    *,
    timeout: float = 0.1,
    quick: bool = False,
    progress: Progress = lambda _: None,
) -> list[Found]:
    """Every unit of ``units`` that answers at each setting of ``tries`` on the line of ``url`` (its port or
    TCP endpoint; its query is ignored); with ``quick``, stop at the first setting where any unit answered."""
    base = ModbusRtuConfig.from_url(DeviceUrl.parse(url.text.partition("?")[0] + "?unit=1"), profiles[0])
    status = profiles[0].role("status_word")
    probe = status.address_for(PROTOCOL) if status is not None else 0
    found: list[Found] = []
    for setting in tries:
        progress(f"scan: {setting.describe()}, units {units[0]}-{units[-1]}")
        speed = setting.baudrate
        serial = SerialSettings(speed, setting.parity, setting.stopbits, 8, silent_interval(speed))
        config = dataclasses.replace(base, serial=serial)
        policy = TransactionPolicy(timeout=timeout, retries=0, quarantine=timeout)
        line = RtuLine(config.connect, serial)
        try:
            at_setting = _scan_units(line, policy, setting, units, probe, profiles, progress)
        finally:
            line.close()
        found += at_setting
        if quick and at_setting:
            break
    return found


def _scan_units(
    line: RtuLine,
    policy: TransactionPolicy,
    setting: Setting,
    units: Sequence[int],
    probe: int,
    profiles: Sequence[Profile],
    progress: Progress,
) -> list[Found]:
    wire = char_time(setting.baudrate)

    def read(unit: int, address: int) -> int | ExceptionResponse | None:
        try:
            response = line.run(Exchange(ReadRequest(unit, address, 1), policy, wire))
        except (TimeoutError, DecodeError):
            return None
        if isinstance(response, ReadResponse):
            return response.values[0]
        return response if isinstance(response, ExceptionResponse) else None

    found = []
    for unit in units:
        if read(unit, probe) is None:
            continue

        def register(address: int, unit: int = unit) -> int | ExceptionResponse:
            answer = read(unit, address)
            return ExceptionResponse(unit, 3, 0xFF) if answer is None else answer  # no answer fits no model

        model, candidates, why = identify(register, unit, profiles)
        progress(f"scan: {setting.describe()} unit {unit}: {model or 'model unknown'} ({why})")
        found.append(Found(unit, setting, model, candidates, why))
    return found


def _read_behind_gateway(transport: ModbusRtuTransport, address: int) -> int | ExceptionResponse | None:
    """One register through a gateway: its value, the device's own exception, or None (nobody answered)."""
    try:
        return transport.read_registers(address, 1)[0]
    except RemoteDeviceError as exc:  # the device's own exception (the gateway's 0x0A / 0x0B are TimeoutError)
        return ExceptionResponse(transport.unit, 3, exc.code)
    except (TimeoutError, DecodeError):
        return None


def scan_gateway(
    url: DeviceUrl,
    profiles: Sequence[Profile],
    units: Sequence[int],
    *,
    timeout: float = 0.5,
    progress: Progress = lambda _: None,
) -> list[Found]:
    """Every unit of ``units`` that answers behind the Modbus TCP gateway of ``url`` (``modbus-tcp://HOST:PORT``,
    its query ignored), one connection for the whole scan, each unit's model told from its registers."""
    from starterbus.transports.modbus.transport.tcp import ModbusTcpConfig, ModbusTcpTransport

    base = url.text.partition("?")[0]
    first = DeviceUrl.parse(f"{base}?unit=1&retries=0&timeout={timeout:g}")
    config = ModbusTcpConfig.from_tcp_url(first, profiles[0])
    status = profiles[0].role("status_word")
    probe = status.address_for(PROTOCOL) if status is not None else 0
    found: list[Found] = []
    progress(f"scan: {config.target}, units {units[0]}-{units[-1]}")
    with ModbusTcpTransport(first, profiles[0], config):  # holds the gateway's one connection for the whole scan
        for unit in units:
            transport = ModbusTcpTransport(first, profiles[0], dataclasses.replace(config, unit=unit))
            with transport:
                if _read_behind_gateway(transport, probe) is None:
                    continue

                def register(address: int, at: ModbusRtuTransport = transport) -> int | ExceptionResponse:
                    answer = _read_behind_gateway(at, address)
                    return ExceptionResponse(at.unit, 3, 0xFF) if answer is None else answer  # no answer fits no model

                model, candidates, why = identify(register, unit, profiles)
            progress(f"scan: {config.target} unit {unit}: {model or 'model unknown'} ({why})")
            found.append(Found(unit, None, model, candidates, why))
    return found
