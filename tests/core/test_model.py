"""Engineering-unit conversion and validation of points (the Device facade relies on these)."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from starterbus.core.errors import UnknownPointError, ValidationError
from starterbus.core.model import Value
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile


def test_jjr5000_current_limit_range(jjr5000: Profile) -> None:
    limit = jjr5000.point("current_limit")
    assert (limit.raw_min, limit.raw_max, limit.unit) == (150, 500, "%")
    assert limit.to_raw(380) == 380
    with pytest.raises(ValidationError, match=r"current_limit \(0x0103\): 149 % is out of range 150..500 %"):
        limit.to_raw(149)
    with pytest.raises(ValidationError, match="resolution"):
        limit.to_raw(380.5)
    with pytest.raises(ValidationError, match="not a number"):
        limit.to_raw(float("nan"))


def test_jjr8000_p7_scaling(jjr8000: Profile) -> None:
    p7 = jjr8000.point("p7")
    assert p7.scale == pytest.approx(0.01)
    assert p7.to_engineering(350) == pytest.approx(3.5)
    assert p7.to_raw(3.5) == 350
    assert p7.to_raw("3.50") == 350
    with pytest.raises(ValidationError, match="resolution"):
        p7.to_raw(3.505)
    with pytest.raises(ValidationError, match="out of range"):
        p7.to_raw(5.01)


def test_enum_labels_in_both_languages(jjr5000: Profile) -> None:
    mode = jjr5000.point("start_mode")
    assert mode.enum is not None
    zero = mode.enum.labels[0]
    assert mode.to_raw(zero.en) == 0
    assert mode.to_raw(zero.en.upper()) == 0
    if zero.zh:
        assert mode.to_raw(zero.zh) == 0
    assert mode.to_raw(1) == 1
    with pytest.raises(ValidationError, match="not a choice"):
        mode.to_raw("warp drive")
    with pytest.raises(ValidationError):
        mode.to_raw(7)


def test_value_keeps_its_resolution(jjr8000: Profile) -> None:
    current = jjr8000.point("m2")
    modbus = Value.from_raw(current, 235)
    assert modbus.value == pytest.approx(23.5)
    assert modbus.resolution == pytest.approx(0.1)
    assert modbus.text() == "23.5 A"
    devicenet = Value.from_raw(current, 23, scale=1.0)
    assert devicenet.value == 23
    assert devicenet.resolution == 1.0
    assert devicenet.text() == "23 A"


def test_manual_addresses_resolve(jjr5000: Profile, ssd1: Profile, jjr8000: Profile) -> None:
    assert jjr5000.point("0x0103").key == "current_limit"
    assert jjr5000.point("0x0100").key == "motor_rated_current"
    assert ssd1.point("0x0125").key == "parameter_modify"
    assert jjr8000.point("p7").key == jjr8000.roles["current_limit"]
    assert jjr8000.point("P0").key == "motor_rated_current"
    assert jjr8000.point("m3").key == "phase_b_current"
    assert jjr8000.point("m0x03").key == "phase_b_current"


def test_jjr8000_addresses_read_as_the_manual_prints_them(jjr8000: Profile) -> None:
    """Appendix 2 prints measurement addresses in hex ("0a", "10"), appendix 3 parameter indexes in decimal."""
    assert jjr8000.point("m10").key == "last_fault_code"  # 4011 / 10 最近一个故障码, not 0x0A
    assert jjr8000.point("m0a").key == "max_run_current"  # 400b / 0a 最大运行电流
    assert jjr8000.point("mA").key == "max_run_current"
    assert jjr8000.point("m0x10").key == "last_fault_code"
    assert jjr8000.point("m19").key == "fault_5_current"
    assert jjr8000.point("p10").key == "kick_time"  # 10 冲击时间
    assert jjr8000.point("p007").key == "current_limit"
    assert jjr8000.point("p08").key == "kick_start"
    assert jjr8000.point("p0x0a").key == "kick_time"
    for bad in ("p0a", "m0d", "p19", "p1e", "m", "p", "m1g"):
        with pytest.raises(UnknownPointError):
            jjr8000.point(bad)


@pytest.mark.parametrize(
    ("model", "key", "text", "raw"),
    [
        ("jjr8000", "current_limit", "350%", 350),
        ("jjr8000", "current_limit", "350 %", 350),
        ("jjr8000", "current_limit", "3.5", 350),
        ("jjr8000", "current_limit", "3.5x", 350),
        ("jjr8000", "current_limit", "3.5 x In", 350),
        ("jjr8000", "current_limit", "3.5倍", 350),
        ("jjr5000", "current_limit", "3.8x", 380),
        ("jjr5000", "current_limit", "380%", 380),
        ("jjr5000", "current_limit", "380", 380),
        ("jjr5000", "ramp_time", "30s", 30),
        ("jjr5000", "ramp_time", "30 s", 30),
        ("jjr5000", "ramp_time", "1min", 60),
        ("jjr5000", "motor_rated_current", "380A", 380),
        ("jjr8000", "kick_time", "200ms", 2),
        ("jjr8000", "kick_time", "0.2s", 2),
        ("jjr8000", "analog_output_scale", "2x", 200),
        ("jjr8000", "start_mode", "电压斜坡", 1),
        ("jjr5000", "start_mode", "电压斜坡", 1),
        ("ssd1", "start_mode", "电压斜坡", 1),
        ("jjr8000", "set1_start_mode", "电压斜坡", 0),
        ("jjr8000", "start_mode", "限流", 0),
        ("jjr5000", "start_mode", "Voltage Ramp", 1),
        ("jjr5000", "start_mode", "2", 2),
        ("jjr5000", "relay_k1_contact", "闭路", 0),
    ],
)
def test_values_as_a_user_types_them(model: str, key: str, text: str, raw: int) -> None:
    assert get_profile(model).point(key).to_raw(text) == raw


@pytest.mark.parametrize(
    ("model", "key", "text", "message"),
    [
        ("jjr8000", "current_limit", "350", r"out of range 1\.5\.\.5\.0 x In; did you mean 350% \(= 3\.5 x In\)\?"),
        ("jjr5000", "current_limit", "3.5", r"did you mean 3\.5x \(= 350 %\)\?"),
        ("jjr5000", "ramp_time", "30A", r"30 A is not in s"),
        ("jjr5000", "motor_rated_current", "380 s", r"380 s is not in A"),
        ("jjr5000", "cooling_factor", "4 s", r"has no unit, but 's' was given"),
        ("jjr8000", "kick_time", "0.25s", r"not a multiple of the resolution 0\.1 s"),
        ("jjr8000", "current_limit", "350 %%", r"not in x In"),
        ("jjr5000", "ramp_time", "fast", r"cannot read 'fast' as a value \(a number, optionally with its unit 's'\)"),
        ("jjr5000", "ramp_time", "1e400", r"not a number|far out of range"),
    ],
)
def test_value_entry_errors_say_what_to_type(model: str, key: str, text: str, message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        get_profile(model).point(key).to_raw(text)


def test_unknown_label_lists_the_choices_in_both_languages(jjr8000: Profile) -> None:
    with pytest.raises(ValidationError) as info:
        jjr8000.point("start_mode").to_raw("电压坡")
    message = str(info.value)
    assert "'电压坡' is not a choice" in message
    assert "0 = current limit / 限流" in message and "1 = voltage ramp / 电压" in message
    assert "\n" not in message


def test_unknown_key_suggests_the_nearest_by_edit_distance(jjr5000: Profile, jjr8000: Profile) -> None:
    for profile in (jjr5000, jjr8000):
        with pytest.raises(UnknownPointError) as info:
            profile.point("ramp_tim")
        assert "did you mean ramp_time" in str(info.value)
        assert "control_word" not in str(info.value).split("did you mean")[1].split("?")[0]
    with pytest.raises(UnknownPointError, match="did you mean current_limit"):
        jjr5000.point("curent_limit")
    with pytest.raises(UnknownPointError) as info:
        jjr5000.point("zzzzzzzzzzzz")
    assert "did you mean" not in str(info.value)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture], max_examples=200)
@given(st.data())
def test_raw_engineering_round_trip(any_profile: Profile, data: st.DataObject) -> None:
    point = data.draw(st.sampled_from(list(any_profile.points.values())))
    raw = data.draw(st.integers(point.raw_min, point.raw_max))
    refused = point.writable_values is not None and raw not in point.writable_values
    if (point.enum is not None and raw not in point.enum.labels) or refused:
        with pytest.raises(ValidationError):
            point.to_raw(raw)
        return
    assert point.to_raw(point.to_engineering(raw)) == raw
    assert point.to_raw(f"{point.to_engineering(raw)} {point.unit}") == raw
