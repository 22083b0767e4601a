"""Every parser raises only the project's errors, for any input (issue 12, item 5).

Profile builder, fleet builder, URL parser and point lookup are fed the crash inputs a fuzzer found, then
arbitrary TOML-shaped data (nested tables, arrays, scalars) and arbitrary strings.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from starterbus.core.errors import (
    ConfigurationError,
    ProfileError,
    StarterbusError,
    UnknownPointError,
    ValidationError,
)
from starterbus.core.profile import build_profile, load_profile_text
from starterbus.core.registry import get_profile
from starterbus.core.url import DeviceUrl
from starterbus.fleet.config import build_fleet, parse_fleet

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

PROFILES = Path(get_profile("jjr5000").source).parent


def profile_data(model: str) -> dict[str, Any]:
    with (PROFILES / f"{model}.toml").open("rb") as f:
        return dict(tomllib.load(f))


def profile_text(model: str) -> str:
    return (PROFILES / f"{model}.toml").read_text(encoding="utf-8")


# -- the crash inputs of issue 12 ------------------------------------------------------------------------------


def _mutated(model: str, path: list[object], value: object) -> dict[str, Any]:
    data = copy.deepcopy(profile_data(model))
    target: Any = data
    for step in path[:-1]:
        target = target[step]
    target[path[-1]] = value
    return data


@pytest.mark.parametrize(
    ("model", "path", "value", "key", "shown"),
    [
        ("jjr5000", ["parameters", 4, "enum"], [1], "parameters.start_mode.enum", "[1]"),
        ("jjr5000", ["roles", "rated_current"], {"a": 1}, "roles.rated_current", "{'a': 1}"),
        ("jjr5000", ["transports", "modbus"], 5, "transports.modbus", "5"),
        ("jjr5000", ["transports", "modbus", "unit_ids"], 5, "transports.modbus", "unit_ids: 5"),
        ("jjr5000", ["transports", "modbus", "baudrates"], ["r"], "transports.modbus", "baudrates: ['r']"),
        ("jjr5000", ["transports", "modbus", "max_read_registers"], "x", "transports.modbus", "'x'"),
        ("jjr5000", ["transports", "profibus-pkw", "stations"], [5], "transports.profibus-pkw", "stations: [5]"),
        ("jjr8000", ["transports", "devicenet", "mac_ids"], [1, 99], "transports.devicenet", "mac_ids: [1, 99]"),
        ("jjr8000", ["transports", "devicenet", "identity"], 3, "transports.devicenet", "identity: 3"),
        ("jjr5000", ["transports", "modbus", "exceptions"], [1], "transports.modbus.exceptions", "[1]"),
        ("jjr5000", ["control", "locked_while_running"], [{}], "control.locked_while_running", "[{}]"),
        ("jjr5000", ["model", "notes"], 5, "model.notes", "5"),
        ("jjr5000", ["parameters", 0, "scale"], float("nan"), "parameters.motor_rated_current.scale", "nan"),
        ("jjr5000", ["parameters", 0, "min"], True, "parameters.motor_rated_current.min", "True"),
        ("jjr5000", ["faults", "64"], "x", "faults.64", "64"),
        ("jjr5000", ["enums", "F2", "x"], "y", "enums.F2.x", "'x'"),
    ],
)
def test_issue_crash_inputs_are_profile_errors(
    model: str, path: list[object], value: object, key: str, shown: str
) -> None:
    with pytest.raises(ProfileError) as info:
        build_profile(_mutated(model, path, value), f"{model}.toml")
    message = str(info.value)
    assert info.value.source == f"{model}.toml" and info.value.key == key
    assert shown in message and "\n" not in message


def test_transport_settings_are_checked_when_the_profile_loads() -> None:
    text = profile_text("jjr5000").replace("\nunit_ids = [0, 247]\n", "\nunit_ids = 5\n")
    with pytest.raises(ProfileError, match=r"^bad.toml: transports.modbus: unit_ids: 5 is not \[first, last\]"):
        load_profile_text(text, "bad.toml")
    text = profile_text("jjr5000").replace("\nstations = [0, 126]\n", "\nstations = [5]\n")
    with pytest.raises(ProfileError, match=r"transports.profibus-pkw: stations: \[5\]"):
        load_profile_text(text, "bad.toml")
    text = profile_text("jjr5000").replace("\nunit_ids = [0, 247]\n", "\nunit_id = [0, 247]\n")
    with pytest.raises(ProfileError, match=r"unit_id: unknown setting"):
        load_profile_text(text, "bad.toml")


@pytest.mark.parametrize("text", ["p007", "p08", "P0x07", "m0a", "m10"])
def test_manual_addresses_with_leading_zeros_resolve(text: str) -> None:
    assert get_profile("jjr8000").point(text).key


@pytest.mark.parametrize("text", ["p", "p-1", "p1.5", "m0x", "0x", "p99999999999", "p٣", "\x00", ""])
def test_bad_addresses_are_unknown_points(text: str) -> None:
    with pytest.raises(UnknownPointError):
        get_profile("jjr8000").point(text)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("bus = [-1, 55]", r"bus\[0\]: -1 is not a table"),
        ("bus = [[]]", r"bus\[0\]: \[\] is not a table"),
        ('[[bus]]\nname = "a"\nurl = "modbus-rtu:///dev/x"\ndevice = [5]', r"bus\[0\].device\[0\]: 5 is not a table"),
        ("poll = 3", "poll: must be a table"),
        ("[poll]\nperiod = nan", "poll.period: nan must be a positive number"),
        ('[[bus]]\nname = "a"\nurl = "x://[::1"', r"bus\[0\].url: 'x://\[::1': invalid host"),
    ],
)
def test_issue_fleet_crash_inputs_are_configuration_errors(text: str, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message):
        parse_fleet(text, "fleet.toml")


def test_fleet_address_p08_resolves_and_a_typo_suggests() -> None:
    base = (
        '[[bus]]\nname = "a"\nurl = "modbus-rtu:///dev/ttyS9"\n'
        '[[bus.device]]\nname = "d"\nmodel = "jjr8000"\naddress = 2\n'
    )
    assert parse_fleet(base + 'parameters = ["p08"]').devices[0].parameters == ("kick_start",)
    with pytest.raises(ConfigurationError, match="did you mean ramp_time"):
        parse_fleet(base + 'parameters = ["ramp_tim"]')


@pytest.mark.parametrize("text", ["x://[::1", "x://[v6:::]", "x://a℀b", "x://h:99999", "://h", "x://h:port"])
def test_issue_url_crash_inputs_are_configuration_errors(text: str) -> None:
    with pytest.raises(ConfigurationError) as info:
        DeviceUrl.parse(text)
    assert "\n" not in str(info.value)


# -- property tests ------------------------------------------------------------------------------------------

_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.dates(),
    st.datetimes(),
)
_keys = st.one_of(
    st.sampled_from(
        ["schema", "model", "name", "key", "address", "min", "max", "enum", "roles", "transports", "bus", "device"]
    ),
    st.text(max_size=8),
)
toml_like = st.recursive(
    _scalars,
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(_keys, children, max_size=5)),
    max_leaves=25,
)


def _paths(data: Any, prefix: tuple[object, ...] = ()) -> list[tuple[object, ...]]:
    found = [prefix] if prefix else []
    if isinstance(data, dict):
        for k, v in data.items():
            found += _paths(v, (*prefix, k))
    elif isinstance(data, list):
        for i, v in enumerate(data[:3]):
            found += _paths(v, (*prefix, i))
    return found


_PROFILE_DATA = {m: profile_data(m) for m in ("jjr5000", "ssd1", "jjr8000")}
_PROFILE_PATHS = {m: _paths(d) for m, d in _PROFILE_DATA.items()}
_SLOW = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@_SLOW
@given(st.dictionaries(_keys, toml_like, max_size=6))
def test_profile_builder_any_document(data: dict[str, Any]) -> None:
    try:
        build_profile(data, "fuzz.toml")
    except StarterbusError:
        pass


@_SLOW
@given(st.sampled_from(sorted(_PROFILE_DATA)), st.data(), toml_like)
def test_profile_builder_one_value_replaced(model: str, pick: st.DataObject, value: object) -> None:
    """A real profile with one value anywhere in it replaced by arbitrary TOML data."""
    path = pick.draw(st.sampled_from(_PROFILE_PATHS[model]))
    data = _mutated(model, list(path), value)
    try:
        build_profile(data, "fuzz.toml")
    except ProfileError as exc:
        assert str(exc).startswith("fuzz.toml: ") and "\n" not in str(exc)


_FLEET = {
    "poll": {"period": 0.5},
    "bus": [
        {
            "name": "line",
            "url": "modbus-rtu:///dev/ttyS9?baudrate=9600",
            "device": [{"name": "a", "model": "jjr5000", "address": 2, "parameters": ["0x0103"]}],
        }
    ],
}


@_SLOW
@given(st.dictionaries(st.sampled_from(["poll", "bus", "x"]), toml_like, max_size=3))
def test_fleet_builder_any_document(data: dict[str, Any]) -> None:
    try:
        build_fleet(data, "fuzz.toml")
    except ConfigurationError:
        pass


@_SLOW
@given(st.data(), toml_like)
def test_fleet_builder_one_value_replaced(pick: st.DataObject, value: object) -> None:
    path = pick.draw(st.sampled_from(_paths(_FLEET)))
    data = copy.deepcopy(_FLEET)
    target: Any = data
    for step in path[:-1]:
        target = target[step]
    target[path[-1]] = value
    try:
        build_fleet(data, "fuzz.toml")
    except ConfigurationError as exc:
        assert "\n" not in str(exc)


_url_text = st.one_of(
    st.text(max_size=40),
    st.builds(
        lambda scheme, rest: f"{scheme}://{rest}",
        st.sampled_from(["modbus-rtu", "modbus-rtu+tcp", "devicenet", "x", ""]),
        st.text(alphabet=st.characters(codec="utf-8"), max_size=30),
    ),
    st.builds(lambda host: f"x://[{host}]:5/p?a=1", st.text(alphabet="0123456789abcdefv:.%[]", max_size=12)),
)


@settings(max_examples=300, deadline=None)
@given(_url_text)
def test_url_parser_any_text(text: str) -> None:
    try:
        url = DeviceUrl.parse(text)
    except ConfigurationError as exc:
        assert "\n" not in str(exc).replace(text, "")
        return
    for name in url.query:
        _read_all_ways(url, name)


def _read_all_ways(url: DeviceUrl, name: str) -> None:
    """Each typed getter either returns or raises ConfigurationError."""
    for kind in ("int", "str", "float", "bool"):
        try:
            if kind == "int":
                url.get_int(name, 1)
            elif kind == "str":
                url.get_str(name)
            elif kind == "float":
                url.get_float(name, 1.0)
            else:
                url.get_bool(name, False)
        except ConfigurationError:
            pass


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(["jjr5000", "ssd1", "jjr8000"]),
    st.one_of(st.text(max_size=12), st.from_regex(r"[pmPM ]?(0x)?[0-9a-fA-F]{0,5}h?", fullmatch=True)),
)
def test_point_lookup_any_text(model: str, text: str) -> None:
    try:
        point = get_profile(model).point(text)
    except UnknownPointError as exc:
        assert "\n" not in str(exc).replace(text, "")
        return
    assert point.key in get_profile(model).points


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(["jjr5000", "ssd1", "jjr8000"]), st.data(), st.text(max_size=12))
def test_value_entry_any_text(model: str, pick: st.DataObject, text: str) -> None:
    profile = get_profile(model)
    point = pick.draw(st.sampled_from(list(profile.points.values())))
    try:
        raw = point.to_raw(text)
    except ValidationError:
        return
    assert point.raw_min <= raw <= point.raw_max
