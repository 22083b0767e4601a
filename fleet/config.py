"""Fleet files: buses and the devices on each, in TOML, validated with errors naming the line and the key.

```toml
[poll]
period = 1.0                # default poll period of every device, s
max_backoff = 30.0          # longest wait between retries of an offline device, s

[[bus]]
name = "line-1"
url = "modbus-rtu:///dev/ttyUSB0?baudrate=9600&parity=E&timeout=0.3"
delay = 0.005               # extra pause between two transactions on this bus (RS485 turnaround), s

  [[bus.device]]
  name = "conveyor"
  model = "jjr5000"
  address = 2               # Modbus unit id / DeviceNet MAC ID (added to the bus URL); Profibus: station number
  period = 1.0
  measurements = ["phase_a_current", "phase_b_current"]
  parameters = ["current_limit"]
  options = { retries = 1 } # extra URL parameters for this device only (e.g. ppo, out, in, assemblies)
  # what remote callers (serve: MQTT DCMD, OPC UA methods and writes) may do; nothing unless listed here
  remote = { commands = ["start", "stop", "reset"], write = ["current_limit"] }
```
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

from starterbus.core.errors import ConfigurationError, StarterbusError
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.status import Command
from starterbus.core.textinput import read_text_file
from starterbus.core.transport import Transport
from starterbus.core.url import DeviceUrl

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_BUS_FIELDS = {"name", "url", "delay", "device"}
_DEVICE_FIELDS = {"name", "model", "address", "period", "measurements", "parameters", "options", "url", "remote"}
_REMOTE_FIELDS = {"commands", "write"}
_REMOTE_COMMANDS = {"start": Command.START, "stop": Command.SOFT_STOP, "reset": Command.FAULT_RESET}


@dataclass(frozen=True, slots=True)
class RemotePolicy:
    """What remote callers (a broker's DCMD, an OPC UA client) may do to one device: nothing by default."""

    commands: frozenset[Command] = frozenset()
    write: frozenset[str] = frozenset()  # parameter keys

    def allows_command(self, command: Command) -> bool:
        return command in self.commands

    def allows_write(self, key: str) -> bool:
        return key in self.write


_POLL_FIELDS = {"period", "max_backoff"}


@dataclass(frozen=True, slots=True)
class DeviceConfig:
    name: str
    bus: str
    model: str
    url: str
    address: int | None
    period: float
    measurements: tuple[str, ...]
    parameters: tuple[str, ...]
    remote: RemotePolicy = RemotePolicy()


@dataclass(frozen=True, slots=True)
class BusConfig:
    name: str
    url: str
    transport: str
    delay: float
    devices: tuple[DeviceConfig, ...]


@dataclass(frozen=True, slots=True)
class FleetConfig:
    buses: tuple[BusConfig, ...]
    period: float = 1.0
    max_backoff: float = 30.0
    source: str = "<fleet>"
    devices_by_name: Mapping[str, DeviceConfig] = field(default_factory=dict)

    @property
    def devices(self) -> list[DeviceConfig]:
        return [d for b in self.buses for d in b.devices]


class _Lines:
    """Line numbers of table headers and keys in a TOML text (tomllib does not report them)."""

    def __init__(self, text: str) -> None:
        self.keys: dict[str, int] = {}
        counters: dict[str, int] = {}
        path = ""
        for n, line in enumerate(text.splitlines(), 1):
            stripped = line.strip()
            header = re.fullmatch(r"\[\[\s*([A-Za-z0-9_.]+)\s*\]\]", stripped)
            if header:
                name = header.group(1)
                if name == "bus":
                    counters["bus"] = counters.get("bus", -1) + 1
                    counters.pop("bus.device", None)
                    path = f"bus[{counters['bus']}]"
                elif name == "bus.device":
                    counters["bus.device"] = counters.get("bus.device", -1) + 1
                    path = f"bus[{counters.get('bus', 0)}].device[{counters['bus.device']}]"
                else:
                    path = name
                self.keys[path] = n
                continue
            table = re.fullmatch(r"\[\s*([A-Za-z0-9_.]+)\s*\]", stripped)
            if table:
                path = table.group(1)
                self.keys[path] = n
                continue
            assign = re.match(r"([A-Za-z0-9_\"-]+)\s*=", stripped)
            if assign:
                key = assign.group(1).strip('"')
                self.keys[f"{path}.{key}" if path else key] = n

    def line(self, path: str) -> int | None:
        while path:
            if path in self.keys:
                return self.keys[path]
            path = path.rsplit(".", 1)[0] if "." in path else ""
        return None


def load_fleet(path: str | Path) -> FleetConfig:
    return parse_fleet(read_text_file(path, "fleet file"), str(path))


def parse_fleet(text: str, source: str = "<fleet>") -> FleetConfig:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigurationError(f"{source}: {exc}") from exc
    return build_fleet(data, source, _Lines(text))


def build_fleet(data: Mapping[str, Any], source: str = "<fleet>", lines: _Lines | None = None) -> FleetConfig:
    """A fleet from parsed TOML data; any problem raises :class:`ConfigurationError` naming file, line and key."""

    def fail(where: str, message: str) -> ConfigurationError:
        line = lines.line(where) if lines is not None else None
        at = f"line {line}: " if line else ""
        return ConfigurationError(f"{source}: {at}{where}: {message}")

    if not isinstance(data, Mapping):
        raise fail("(document)", "must be a table")
    unknown = set(data) - {"poll", "bus"}
    if unknown:
        raise fail(_key(sorted(unknown)[0]), "unknown table (expected [poll] and [[bus]])")
    poll = data.get("poll", {})
    if not isinstance(poll, Mapping):
        raise fail("poll", "must be a table")
    _check_fields(poll, _POLL_FIELDS, "poll", fail)
    period = _positive(poll.get("period", 1.0), "poll.period", fail)
    max_backoff = _positive(poll.get("max_backoff", 30.0), "poll.max_backoff", fail)

    buses_data = data.get("bus")
    if not isinstance(buses_data, list) or not buses_data:
        raise fail("bus", "a fleet needs at least one [[bus]]")
    buses: list[BusConfig] = []
    devices: dict[str, DeviceConfig] = {}
    bus_names: set[str] = set()
    bus_targets: dict[str, str] = {}
    for bi, bus in enumerate(buses_data):
        where = f"bus[{bi}]"
        if not isinstance(bus, Mapping):
            raise fail(where, f"{_shown(bus)} is not a table: write each bus as [[bus]] with name, url and devices")
        _check_fields(bus, _BUS_FIELDS, where, fail)
        name = _name(bus, where, fail)
        if name in bus_names:
            raise fail(f"{where}.name", f"bus {name!r} is defined twice")
        bus_names.add(name)
        url_text = bus.get("url")
        if not isinstance(url_text, str):
            raise fail(f"{where}.url", "required: the bus URL (e.g. modbus-rtu:///dev/ttyUSB0?baudrate=9600)")
        try:
            url = DeviceUrl.parse(url_text)
        except StarterbusError as exc:
            raise fail(f"{where}.url", str(exc)) from None
        target = f"{url.scheme}://{url.host}:{url.port}{url.path}"
        if target in bus_targets:
            raise fail(f"{where}.url", f"same line as bus {bus_targets[target]!r}: put both devices on one bus")
        bus_targets[target] = name
        delay = _non_negative(bus.get("delay", 0.0), f"{where}.delay", fail)
        dev_list = bus.get("device", [])
        if not isinstance(dev_list, list) or not dev_list:
            raise fail(where, f"bus {name!r} has no [[bus.device]]")
        addresses: set[int] = set()
        bus_devices = []
        for di, dev in enumerate(dev_list):
            dwhere = f"{where}.device[{di}]"
            if not isinstance(dev, Mapping):
                raise fail(dwhere, f"{_shown(dev)} is not a table: write each device as [[bus.device]]")
            _check_fields(dev, _DEVICE_FIELDS, dwhere, fail)
            dname = _name(dev, dwhere, fail)
            if dname in devices:
                raise fail(f"{dwhere}.name", f"device {dname!r} is defined twice")
            model = dev.get("model")
            if not isinstance(model, str):
                raise fail(f"{dwhere}.model", "required: the device model (jjr5000, ssd1, jjr8000)")
            try:
                profile = get_profile(model)
            except StarterbusError as exc:
                raise fail(f"{dwhere}.model", str(exc)) from None
            if not profile.supports(url.transport):
                raise fail(f"{dwhere}.model", profile.no_interface(url.transport))
            address = dev.get("address")
            if address is not None and (not isinstance(address, int) or isinstance(address, bool)):
                raise fail(f"{dwhere}.address", f"{address!r} is not an integer")
            if address is not None:
                if address in addresses:
                    raise fail(f"{dwhere}.address", f"address {address} is used twice on bus {name!r}")
                addresses.add(address)
            options = dev.get("options", {})
            if not isinstance(options, Mapping):
                raise fail(f"{dwhere}.options", "must be a table of URL parameters")
            try:
                param, period_param = _url_parameters(url.transport)
            except StarterbusError as exc:
                raise fail(f"{where}.url", str(exc)) from None
            if address is not None and param is None:
                raise fail(
                    f"{dwhere}.address",
                    f"the {url.transport} transport takes no device address (give its URL parameters in options)",
                )
            if param is not None and param in options:
                raise fail(f"{dwhere}.options.{param}", f"give the device's {param} as address = ..., not as an option")
            dperiod = _positive(dev.get("period", period), f"{dwhere}.period", fail)
            if period_param is not None and period_param not in options and period_param not in url.query:
                options = {**options, period_param: f"{dperiod:g}"}  # the transport scans at the fleet's rate
            dev_url = _device_url(url, param, address, options)
            if "url" in dev:
                raise fail(f"{dwhere}.url", "give address/options; the URL comes from the bus")
            try:  # the transport's own URL parsing: every setting the model cannot speak, named
                transport = _check_url(url.transport, dev_url, profile)
            except StarterbusError as exc:
                raise fail(dwhere, str(exc)) from None
            points: dict[str, tuple[str, ...]] = {}
            for kind in ("measurements", "parameters"):
                keys = dev.get(kind, [])
                if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
                    raise fail(f"{dwhere}.{kind}", "must be a list of keys or manual addresses")
                resolved = []
                for k in keys:
                    try:
                        point = profile.point(k)
                    except StarterbusError as exc:
                        raise fail(f"{dwhere}.{kind}", str(exc)) from None
                    if (point.kind.value + "s") != kind:
                        raise fail(
                            f"{dwhere}.{kind}",
                            f"{k!r} is a {point.kind.value}, list it under {point.kind.value}s",
                        )
                    refusal = transport.read_refusal(point)
                    if refusal is not None:
                        raise fail(f"{dwhere}.{kind}", f"{k!r}: {refusal}")
                    resolved.append(point.key)
                points[kind] = tuple(resolved)
            if "measurements" not in dev:
                phases = profile.phase_currents()
                points["measurements"] = tuple(p.key for p in phases if transport.read_refusal(p) is None)
            remote = _remote(dev.get("remote", {}), profile, f"{dwhere}.remote", fail)
            config = DeviceConfig(
                name=dname,
                bus=name,
                model=profile.name,
                url=dev_url,
                address=address,
                period=dperiod,
                measurements=points["measurements"],
                parameters=points["parameters"],
                remote=remote,
            )
            devices[dname] = config
            bus_devices.append(config)
        buses.append(BusConfig(name, url_text, url.transport, delay, tuple(bus_devices)))
    return FleetConfig(tuple(buses), period, max_backoff, source, devices)


def _url_parameters(transport: str) -> tuple[str | None, str | None]:
    """The URL parameters a device's ``address`` and poll ``period`` fill, as the transport's plugin declares."""
    from starterbus.core.registry import get_transport

    plugin = get_transport(transport)
    return plugin.address_parameter, plugin.period_parameter


def _check_url(transport: str, url: str, profile: Profile) -> Transport:
    """What opening the device would refuse in its URL, found without opening anything: the plugin builds the
    transport (``TransportPlugin.open`` checks the URL against the model and opens nothing) and it is dropped."""
    from starterbus.core.registry import get_transport

    return get_transport(transport).open(DeviceUrl.parse(url), profile)


def _device_url(bus: DeviceUrl, param: str | None, address: int | None, options: Mapping[str, Any]) -> str:
    query = dict(bus.query)
    for key, value in options.items():
        query[str(key)] = str(value).lower() if isinstance(value, bool) else str(value)
    if address is not None and param is not None:
        query[param] = str(address)
    base = bus.text.split("?", 1)[0]
    return f"{base}?{urlencode(query)}" if query else base


def _remote(table: object, profile: Profile, where: str, fail: Any) -> RemotePolicy:
    if not isinstance(table, dict):
        raise fail(where, "must be a table: { commands = [...], write = [...] }")
    _check_fields(table, _REMOTE_FIELDS, where, fail)
    commands = table.get("commands", [])
    if not isinstance(commands, list) or not all(isinstance(c, str) and c in _REMOTE_COMMANDS for c in commands):
        raise fail(f"{where}.commands", f"{commands!r} must be a list of: {', '.join(_REMOTE_COMMANDS)}")
    keys = table.get("write", [])
    if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
        raise fail(f"{where}.write", f"{keys!r} must be a list of parameter keys")
    writable = set()
    for key in keys:
        try:
            point = profile.point(key)
        except StarterbusError as exc:
            raise fail(f"{where}.write", str(exc)) from None
        if not point.writable:
            raise fail(f"{where}.write", f"{key!r} is not a writable parameter of {profile.display_name}")
        writable.add(point.key)
    return RemotePolicy(frozenset(_REMOTE_COMMANDS[c] for c in commands), frozenset(writable))


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _key(key: str) -> str:
    return key if re.fullmatch(r"[\w+-]+", key) else repr(key)


def _check_fields(table: Mapping[str, Any], known: set[str], where: str, fail: Any) -> None:
    for key in sorted(set(table) - known):
        raise fail(f"{where}.{_key(key)}", f"unknown setting (known: {', '.join(sorted(known))})")


def _name(table: Mapping[str, Any], where: str, fail: Any) -> str:
    name = table.get("name")
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise fail(f"{where}.name", f"{name!r} is not a name (letters, digits, _ . -)")
    return name


def _positive(value: object, where: str, fail: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
        raise fail(where, f"{_shown(value)} must be a positive number of seconds")
    return float(value)


def _non_negative(value: object, where: str, fail: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
        raise fail(where, f"{_shown(value)} must be zero or a positive number of seconds")
    return float(value)
