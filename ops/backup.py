"""Parameter backups: every readable parameter of a device, as a TOML document a person can read and edit.

A backup holds, per parameter, the engineering ``value`` (a number in ``unit``, or the enum label), the ``raw``
word it came from, the ``unit`` and the manual's ``label``; plus the model, the profile it was read with
(source file and SHA-256), the transport and URL, the device identity where the protocol has one, and the time.

When a person edits a backup, ``value`` is what counts; ``raw`` must then agree with it or be deleted (a
backup whose ``raw`` and ``value`` disagree is refused, naming the key: nothing is guessed).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starterbus.core.device import Device
from starterbus.core.errors import ConfigurationError, UnsupportedOperationError, ValidationError
from starterbus.core.fault_codes import is_fault_code, value_text
from starterbus.core.model import Kind, PointDef, Value
from starterbus.core.outfiles import write_atomically
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.textinput import read_text_file
from starterbus.core.timestamps import iso_time
from starterbus.core.transport import Capability

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

FORMAT = "starterbus-backup"
FORMAT_VERSION = 1


@dataclass(frozen=True, slots=True)
class Entry:
    """One parameter of a backup: the raw word and how it reads."""

    key: str
    raw: int
    text: str


@dataclass(frozen=True, slots=True)
class Backup:
    model: str
    parameters: Mapping[str, Entry]
    taken: str = ""
    transport: str = ""
    url: str = ""
    identity: Mapping[str, object] = field(default_factory=dict)
    history: Mapping[str, str] = field(default_factory=dict)  # the device's own counters and fault history
    profile_source: str = ""
    profile_sha256: str = ""

    def raws(self) -> dict[str, int]:
        return {k: e.raw for k, e in self.parameters.items()}


def profile_digest(profile: Profile) -> str:
    try:
        return hashlib.sha256(Path(profile.source).read_bytes()).hexdigest()
    except OSError:
        return ""


def _history_points(profile: Profile) -> list[PointDef]:
    roles = ("start_count", "run_time", "max_start_current", "max_run_current", "last_fault_code", "last_fault_current")
    keys = [k for r in roles if isinstance(k := profile.roles.get(r), str)]
    keys += [p.key for p in profile.measurements if is_fault_code(profile, p) or p.key.startswith("fault_")]
    return [profile.points[k] for k in dict.fromkeys(keys)]


def take_backup(device: Device) -> Backup:
    """Read every parameter (and the device's own fault history, where it has one) from an open device."""
    profile = device.profile
    transport = device.transport
    if Capability.READ_PARAMETERS not in device.capabilities:
        raise UnsupportedOperationError(
            f"{transport.name} ({transport.describe()}) cannot read parameters, so it cannot back them up "
            "(use a path with a parameter channel: Modbus RTU, or Profibus PPO1 with PKW)"
        )
    values = device.read(*profile.parameters)
    history: dict[str, str] = {}
    if Capability.READ_MEASUREMENTS in device.capabilities:
        hist_points = _history_points(profile)
        if hist_points:
            history = {k: value_text(profile, v) for k, v in device.read(*hist_points).items()}
    identity: dict[str, object] = {}
    try:
        identity = dict(transport.identify())
    except UnsupportedOperationError:
        pass
    return Backup(
        model=profile.name,
        parameters={k: Entry(k, v.raw, value_text(profile, v)) for k, v in values.items()},
        taken=iso_time(),
        transport=transport.name,
        url=transport.url.text,
        identity=identity,
        history=history,
        profile_source=profile.source,
        profile_sha256=profile_digest(profile),
    )


# -- TOML ---------------------------------------------------------------------------------------------------


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    return json.dumps(str(value), ensure_ascii=False)  # a JSON string is a valid TOML basic string


def engineering(point: PointDef, raw: int) -> float | int | str:
    """What a person edits: the enum label, or the number in the point's unit (a bit field stays raw)."""
    value = Value.from_raw(point, raw)
    if value.label is not None:
        return value.label.en
    return raw if point.bits else value.value


def dumps(backup: Backup, profile: Profile) -> str:
    lines = [
        f"# starterbus parameter backup of a {profile.display_name}. To change a value, edit `value` (in `unit`, or",
        "# an enum label) and delete `raw` (or set both). `starterbus restore FILE URL --model "
        f"{profile.name}` writes what differs.",
        f"format = {_toml_value(FORMAT)}",
        f"format_version = {FORMAT_VERSION}",
        f"model = {_toml_value(backup.model)}",
        f"taken = {_toml_value(backup.taken)}",
        f"transport = {_toml_value(backup.transport)}",
        f"url = {_toml_value(backup.url)}",
        f"profile_source = {_toml_value(backup.profile_source)}",
        f"profile_sha256 = {_toml_value(backup.profile_sha256)}",
    ]
    if backup.identity:
        lines += ["", "[identity]"] + [f"{k} = {_toml_value(v)}" for k, v in backup.identity.items()]
    if backup.history:
        lines += ["", "# the device's own counters and fault history when the backup was taken (never restored)"]
        lines += ["[history]"] + [f"{k} = {_toml_value(v)}" for k, v in backup.history.items()]
    for key, entry in backup.parameters.items():
        point = profile.points[key]
        lines += [
            "",
            f"[parameters.{key}]",
            f"address = {_toml_value(point.address)}",
            f"label = {_toml_value(point.name_en)}",
            f"value = {_toml_value(engineering(point, entry.raw))}",
            f"unit = {_toml_value(point.unit)}",
            f"raw = {entry.raw}",
        ]
        if not point.writable:
            lines.append("read_only = true")
    return "\n".join(lines) + "\n"


def save(backup: Backup, profile: Profile, path: str | Path, *, replace: bool = False) -> None:
    """Write the backup file atomically; an existing file is refused unless ``replace``."""
    write_atomically(path, dumps(backup, profile), replace=replace)


def load(path: str | Path) -> tuple[Backup, Profile]:
    """Read and check a backup file against its model's profile; raises the typed errors naming file and key."""
    return loads(read_text_file(path, "backup"), str(path))


def loads(text: str, source: str = "<backup>") -> tuple[Backup, Profile]:
    """:func:`load` of a backup's text (an upload); ``source`` names it in errors."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigurationError(f"{source}: not TOML: {exc}") from exc
    if data.get("format") != FORMAT:
        raise ConfigurationError(f"{source}: not a starterbus backup (format = {data.get('format')!r})")
    model = data.get("model")
    if not isinstance(model, str):
        raise ConfigurationError(f"{source}: model: missing")
    profile = get_profile(model)
    params = data.get("parameters")
    if not isinstance(params, Mapping):
        raise ConfigurationError(f"{source}: [parameters]: missing")
    entries = {}
    for key, table in params.items():
        entries[key] = _entry(profile, source, key, table)
    return (
        Backup(
            model=profile.name,
            parameters=entries,
            taken=str(data.get("taken", "")),
            transport=str(data.get("transport", "")),
            url=str(data.get("url", "")),
            identity=dict(data.get("identity", {})),
            history={str(k): str(v) for k, v in data.get("history", {}).items()},
            profile_source=str(data.get("profile_source", "")),
            profile_sha256=str(data.get("profile_sha256", "")),
        ),
        profile,
    )


def _entry(profile: Profile, source: str, key: str, table: Any) -> Entry:
    where = f"{source}: parameters.{key}"
    if key not in profile.points or profile.points[key].kind is not Kind.PARAMETER:
        raise ValidationError(f"{where}: {profile.name} has no parameter {key!r}")
    point = profile.points[key]
    if not isinstance(table, Mapping) or ("value" not in table and "raw" not in table):
        raise ValidationError(f"{where}: needs `value` (or `raw`)")
    raw_given = table.get("raw")
    if raw_given is not None and (not isinstance(raw_given, int) or isinstance(raw_given, bool)):
        raise ValidationError(f"{where}.raw: {raw_given!r} is not an integer")
    try:
        if "value" in table:
            value = table["value"]
            if point.bits and isinstance(value, int):
                raw = value
                point.check_range(raw)
            elif isinstance(value, (int, float, str)) and not isinstance(value, bool):
                raw = _as_read(point, value)
            else:
                raise ValidationError(f"{key}: {value!r} is not a number or a label")
        else:
            raw = int(raw_given)  # type: ignore[arg-type]
            point.check_range(raw)
    except ValidationError as exc:
        raise ValidationError(f"{source}: {exc}") from exc
    if raw_given is not None and raw_given != raw:
        raise ValidationError(
            f"{where}: value {table['value']!r} is raw {raw} but raw says {raw_given}; "
            "edit one of them and delete the other"
        )
    return Entry(key, raw, value_text(profile, Value.from_raw(point, raw)))


def _as_read(point: PointDef, value: float | int | str) -> int:
    """A value as the device reported it: in range and in the enum, but not held to what may be written (a
    backup records factory_reset as read; restore never writes it)."""
    if point.writable_values is None:
        return point.to_raw(value)
    unrestricted = dataclasses.replace(point, writable_values=None)
    return unrestricted.to_raw(value)
