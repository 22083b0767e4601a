"""Engineering-unit conversion and validation of points (the Device facade relies on these)."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from starterbus.core.errors import ValidationError
from starterbus.core.model import Value
from starterbus.core.profile import Profile


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
    with pytest.raises(ValidationError, match="not one of|cannot read"):
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


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture], max_examples=200)
@given(st.data())
def test_raw_engineering_round_trip(any_profile: Profile, data: st.DataObject) -> None:
    point = data.draw(st.sampled_from(list(any_profile.points.values())))
    raw = data.draw(st.integers(point.raw_min, point.raw_max))
    if point.enum is not None and raw not in point.enum.labels:
        with pytest.raises(ValidationError):
            point.to_raw(raw)
        return
    assert point.to_raw(point.to_engineering(raw)) == raw
