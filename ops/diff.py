"""Comparing two parameter sets: backup files, devices, or a profile's defaults.

A side is written on the command line as

* a backup file: ``plant/conveyor-1.toml`` (an existing path);
* a device: ``URL@MODEL`` (``modbus-rtu:///dev/ttyUSB0?unit=2@jjr5000``), or a bare ``URL`` with ``--model``;
* ``defaults`` or ``defaults@MODEL``: the profile's default of every parameter (without a model, the other
  side's model);
* a device name, which ``lookup`` (the caller's: a fleet file's names) turns into the device's URL and model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError
from starterbus.core.fault_codes import value_text
from starterbus.core.model import Value
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.ops import backup as backups


@dataclass(frozen=True, slots=True)
class ParameterSet:
    """Raw parameter words of one model, from one source; ``raws`` may lack keys the source does not know."""

    source: str
    profile: Profile
    raws: Mapping[str, int]
    missing: tuple[str, ...] = ()  # parameters this side has no value for (no printed default)


@dataclass(frozen=True, slots=True)
class Row:
    key: str
    address: str
    label: str
    a: str
    b: str
    raw_a: int | None
    raw_b: int | None

    def as_json(self) -> dict[str, object]:
        return {
            "key": self.key,
            "address": self.address,
            "label": self.label,
            "a": self.a,
            "b": self.b,
            "raw_a": self.raw_a,
            "raw_b": self.raw_b,
        }


#: a device name -> (URL, model); raises ConfigurationError for a name it does not know
Lookup = Callable[[str], tuple[str, str]]


@dataclass(frozen=True, slots=True)
class Spec:
    kind: str  # "file", "device", "defaults"
    text: str
    model: str | None = None
    name: str | None = None  # a device given by name


def parse_spec(text: str, default_model: str | None = None, lookup: Lookup | None = None) -> Spec:
    """Which kind of side ``text`` names (see the module docstring); an unclear text is an error."""
    head, at, tail = text.rpartition("@")
    if text == "defaults" or (at and head == "defaults"):
        return Spec("defaults", text, tail if at else default_model)
    if "://" in text:
        if at and (tail.endswith(".toml") or not any(c in tail for c in "/?=&")):
            return Spec("device", head, tail)
        if default_model is None:
            raise ConfigurationError(f"{text}: a device side needs its model: write URL@MODEL or give --model")
        return Spec("device", text, default_model)
    if Path(text).exists():
        return Spec("file", text)
    if lookup is not None and "/" not in text and not text.endswith(".toml"):  # a name, not a missing file
        url, model = lookup(text)
        return Spec("device", url, model, name=text)
    raise ConfigurationError(
        f"{text}: no such backup file, and not a device URL (URL@MODEL) or `defaults`/`defaults@MODEL`"
    )


def from_defaults(profile: Profile) -> ParameterSet:
    raws = {p.key: p.default for p in profile.parameters if p.default is not None}
    missing = tuple(p.key for p in profile.parameters if p.default is None)
    return ParameterSet(f"defaults of {profile.display_name}", profile, raws, missing)


def from_device(url: str, model: str | Profile, name: str | None = None) -> ParameterSet:
    with open_device(url, model) as device:
        taken = backups.take_backup(device)
    return ParameterSet(name or url, device.profile, taken.raws())


def from_file(path: str) -> ParameterSet:
    taken, profile = backups.load(path)
    return ParameterSet(path, profile, taken.raws())


def load_side(spec: Spec, other_model: str | None = None) -> ParameterSet:
    if spec.kind == "file":
        return from_file(spec.text)
    if spec.kind == "device":
        assert spec.model is not None
        return from_device(spec.text, spec.model, spec.name)
    model = spec.model or other_model
    if model is None:
        raise ConfigurationError("defaults: which model? write defaults@MODEL (or compare with a backup or device)")
    return from_defaults(get_profile(model))


def load_pair(
    text_a: str, text_b: str, model: str | None = None, lookup: Lookup | None = None
) -> tuple[ParameterSet, ParameterSet]:
    spec_a, spec_b = parse_spec(text_a, model, lookup), parse_spec(text_b, model, lookup)
    if spec_a.kind == "defaults" and spec_b.kind != "defaults":
        b = load_side(spec_b)
        return load_side(spec_a, b.profile.name), b
    a = load_side(spec_a)
    return a, load_side(spec_b, a.profile.name)


def _text(profile: Profile, key: str, raw: int | None) -> str:
    if raw is None:
        return "-"
    return value_text(profile, Value.from_raw(profile.points[key], raw))


def compare(a: ParameterSet, b: ParameterSet) -> list[Row]:
    """One row per parameter whose value differs, or that one side has and the other lacks (except defaults
    the profile does not print: those are listed in ``missing``, not as differences)."""
    rows = []
    skip = set(a.missing) | set(b.missing)
    keys = [k for k in dict.fromkeys([*a.raws, *b.raws]) if k not in skip]
    for key in keys:
        raw_a, raw_b = a.raws.get(key), b.raws.get(key)
        if raw_a == raw_b:
            continue
        point = (a.profile if key in a.profile.points else b.profile).points[key]
        rows.append(
            Row(
                key,
                point.address,
                point.name_en,
                _text(a.profile, key, raw_a) if key in a.profile.points else "-",
                _text(b.profile, key, raw_b) if key in b.profile.points else "-",
                raw_a,
                raw_b,
            )
        )
    return rows
