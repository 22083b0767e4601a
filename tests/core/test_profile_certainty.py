"""Issue 12: the profiles as the manuals print them, and where every code, scale and default comes from."""

from __future__ import annotations

import json

import pytest

from starterbus.cli.main import main
from starterbus.core.errors import ProfileError, ValidationError
from starterbus.core.model import Certainty
from starterbus.core.profile import Profile, load_profile_text
from starterbus.core.registry import get_profile


def params_json(capsys: pytest.CaptureFixture[str], model: str) -> dict[str, object]:
    assert main(["params", model, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert isinstance(doc, dict)
    return doc


def by_address(doc: dict[str, object], address: str) -> dict[str, object]:
    points = doc["parameters"] + doc["measurements"]  # type: ignore[operator]
    return next(p for p in points if p["address"] == address)


@pytest.mark.parametrize("address", ["p15", "p16", "p17"])
def test_overload_classes_in_printed_order_marked_inferred(capsys: pytest.CaptureFixture[str], address: str) -> None:
    """Appendix 3 prints '10A 20 30 10' with no codes: code n is the n-th printed choice, and says so."""
    point = by_address(params_json(capsys, "jjr8000"), address)
    values = point["enum"]["values"]  # type: ignore[index]
    assert [(code, v["zh"]) for code, v in values.items()] == [("0", "10A"), ("1", "20"), ("2", "30"), ("3", "10")]
    assert {v["certainty"] for v in values.values()} == {"inferred"}
    assert all("print" in v["why"] for v in values.values())
    assert point["certainty"]["codes"] == "inferred"  # type: ignore[index]


def test_overload_class_20_writes_code_1(jjr8000: Profile) -> None:
    p15 = jjr8000.point("p15")
    assert p15.key == "motor_overload_class"
    assert p15.to_raw("class 20") == 1 and p15.to_raw("20") == 1 and p15.to_raw("10") == 3
    assert p15.uncertainty(1) == (
        "p15 motor_overload_class: code 1 (class 20) is inferred from the order appendix 3 prints the choices in "
        "('10A 20 30 10', no codes printed), not printed in the manual"
    )


def test_uncertainty_is_none_only_when_printed(jjr5000: Profile, jjr8000: Profile) -> None:
    assert jjr8000.point("p7").uncertainty(350) is None  # scale printed by example 4
    assert jjr8000.point("p2").uncertainty(1) is None  # '0 限流 1 电压'
    assert jjr5000.point("0x0103").uncertainty(380) is None
    assert jjr5000.point("start_mode").uncertainty(2) is None
    kick = jjr8000.point("p10").uncertainty(2)
    assert kick is not None and kick.startswith("p10 kick_time: the scale x0.1 s (raw 2 = 0.2 s) is assumed")
    assert "\n" not in kick
    for address, code in (("p62", 6), ("p66", 3), ("p67", 2), ("p69", 3)):
        reason = jjr8000.point(address).uncertainty(code)
        assert reason is not None and f"code {code} " in reason and "is assumed" in reason
        assert jjr8000.point(address).uncertainty(0) is None or address == "p69"
    pro = jjr8000.point("p71").uncertainty(0)
    assert pro is not None and "its address p71 is inferred" in pro and "index 70" in pro
    assert jjr8000.point("p0").uncertainty(7) is None
    assert jjr8000.point("p1").uncertainty(9) == (
        "p1 inline_operation: code 9 is not in the manual's table no_yes, not printed in the manual"
    )


@pytest.mark.parametrize("address", ["p10", "p37", "p41", "p42", "p52", "p54", "p105", "p111", "p117"])
def test_fractional_scales_are_assumed(jjr8000: Profile, address: str) -> None:
    point = jjr8000.point(address)
    assert point.scale < 1 and point.scale_source.certainty is Certainty.ASSUMED
    assert point.uncertainty(point.raw_min) is not None


@pytest.mark.parametrize("address", ["0x0148", "0x0149", "0x014A", "0x014B"])
def test_jjr5000_test_programs_are_read_only(capsys: pytest.CaptureFixture[str], address: str) -> None:
    assert by_address(params_json(capsys, "jjr5000"), address)["access"] == "r"
    assert not get_profile("jjr5000").point(address).writable


@pytest.mark.parametrize(("model", "address", "lo"), [("jjr5000", "0x0145", 1), ("ssd1", "0x0126", 0)])
def test_factory_reset_accepts_only_8(model: str, address: str, lo: int) -> None:
    point = get_profile(model).point(address)
    assert point.to_raw(8) == 8 and point.to_raw("8") == 8
    for raw in range(lo, 16):
        if raw != 8:
            with pytest.raises(
                ValidationError, match=rf"only 8 is documented as writable .*恢复出厂值.*; {raw} is refused"
            ):
                point.to_raw(raw)
            with pytest.raises(ValidationError):
                point.check_raw(raw)
        point.check_range(raw)  # any value 0/1-15 may be read back
    doc_point = by_address_json(model, address)
    assert doc_point["writable_values"] == [8]


def by_address_json(model: str, address: str) -> dict[str, object]:
    from starterbus.cli.info import profile_json

    return by_address(profile_json(get_profile(model)), address)


def test_f8_labels_say_what_the_contact_does_on_the_event(jjr5000: Profile) -> None:
    f8 = jjr5000.enums["F8"]
    assert (f8.labels[0].zh, f8.labels[1].zh) == ("闭路", "开路")
    assert f8.labels[0].en == "closes on the event" and f8.labels[1].en == "opens on the event"
    assert jjr5000.point("relay_k1_contact").uncertainty(1) is None


def test_fault_tables_say_where_they_come_from(jjr5000: Profile, ssd1: Profile, jjr8000: Profile) -> None:
    assert all(s.printed for s in jjr8000.fault_sources.values())
    assert jjr5000.fault_sources[5].printed and "81 05 05 64" in jjr5000.fault_sources[5].why
    assert jjr5000.fault_sources[6].certainty is Certainty.ASSUMED and "JJR8000" in jjr5000.fault_sources[6].why
    assert ssd1.fault_sources[5].certainty is Certainty.ASSUMED
    assert jjr5000.faults.labels[5].en == "mains phase loss" and ssd1.faults.labels[5].en == "external fault"
    assert any("code 5" in note and "SSD1" in note for note in jjr5000.notes)
    faults = by_address_json_faults("jjr5000")
    assert faults["5"]["certainty"] == "printed" and faults["6"]["certainty"] == "assumed"


def by_address_json_faults(model: str) -> dict[str, dict[str, str]]:
    from starterbus.cli.info import profile_json

    faults = profile_json(get_profile(model))["faults"]
    assert isinstance(faults, dict)
    return faults


def test_every_non_printed_item_says_why(any_profile: Profile) -> None:
    for point in any_profile.points.values():
        for source in (point.scale_source, point.address_source):
            assert source.printed or source.why, point.key
        if point.enum is not None:
            for code in point.enum.labels:
                source = point.enum.provenance(code)
                assert source.printed or source.why, (point.key, code)


def test_printed_defaults_are_the_menu_factory_values(jjr5000: Profile, ssd1: Profile, jjr8000: Profile) -> None:
    printed = [p.address for p in jjr5000.parameters if p.default_source.printed]
    assert printed == ["0x013E", "0x013F", "0x0140", "0x0141", "0x0142", "0x0143", "0x0144"]
    assert [p.address for p in ssd1.parameters if p.default_source.printed] == [
        "0x011B",
        "0x0121",
        "0x0122",
        "0x0123",
        "0x0124",
    ]
    assert not any(p.default_source.printed for p in jjr8000.parameters)


def test_params_text_lists_what_is_not_printed(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params", "jjr8000"]) == 0
    out = capsys.readouterr().out
    assert "0=class 10A (inferred), 1=class 20 (inferred), 2=class 30 (inferred), 3=class 10 (inferred)" in out
    assert "p15 motor_overload_class: codes 0, 1, 2, 3 inferred from the order appendix 3 prints" in out
    assert "p71 profibus_type: address inferred" in out
    assert "p10 kick_time: scale x0.1 assumed" in out
    assert main(["params", "jjr5000"]) == 0
    assert "writable: only 8" in capsys.readouterr().out


# -- the TOML form ---------------------------------------------------------------------------------------------

TOY = """
schema = 1
[model]
name = "toy"
{model}
[roles]
control_word = "cw"
status_word = "sw"
phase_currents = ["ia"]
rated_current = "rated"
current_limit = "mode"
[transports.acme]
[enums.mode]
{enum}
[[measurements]]
key = "cw"
address = "0x0000"
name_en = "control word"
min = 0
max = 65535
[[measurements]]
key = "sw"
address = "0x0001"
name_en = "status word"
min = 0
max = 65535
[[measurements]]
key = "ia"
address = "0x0002"
name_en = "current"
min = 0
max = 65535
scale = 0.1
unit = "A"
{point}
[[parameters]]
key = "rated"
address = "0x0100"
name_en = "rated current"
min = 1
max = 100
[[parameters]]
key = "mode"
address = "0x0101"
name_en = "mode"
min = 0
max = 2
enum = "mode"
"""
ENUM = '0 = { en = "a", zh = "甲" }\n1 = { en = "b", zh = "乙" }\n2 = { en = "c", zh = "丙" }'


def toy(model: str = 'certainty = "printed"', enum: str = ENUM, point: str = "") -> Profile:
    return load_profile_text(TOY.format(model=model, enum=enum, point=point), "toy.toml")


def test_toml_form_defaults_and_overrides() -> None:
    profile = toy(
        enum='certainty = "inferred from the print order"\n' + ENUM.replace('"乙" }', '"乙", certainty = "printed" }'),
        point='scale_certainty = "assumed (no unit printed)"',
    )
    mode = profile.point("mode")
    assert mode.uncertainty(1) is None
    assert mode.uncertainty(0) == "0x0101 mode: code 0 (a) is inferred from the print order, not printed in the manual"
    assert profile.point("ia").uncertainty(5) == (
        "0x0002 ia: the scale x0.1 A (raw 5 = 0.5 A) is assumed (no unit printed), not printed in the manual"
    )
    assert profile.point("rated").default_source.certainty is Certainty.ASSUMED


def test_a_profile_that_claims_nothing_is_assumed() -> None:
    profile = toy(model="")
    assert "is assumed" in (profile.point("mode").uncertainty(0) or "")
    assert "is assumed" in (profile.point("rated").uncertainty(5) or "")


@pytest.mark.parametrize(
    ("model", "enum", "point", "key", "message"),
    [
        ('certainty = "sure"', ENUM, "", "model.certainty", "does not start with printed, inferred or assumed"),
        ("certainty = 1", ENUM, "", "model.certainty", "is not a text"),
        ('certainty = "printed"', 'certainty = "inferred"\n' + ENUM, "", "enums.mode.certainty", "say why"),
        ('certainty = "printed"', ENUM, 'scale_certainty = "guessed"', "measurements.ia.scale_certainty", "'guessed'"),
        ('certainty = "printed"', ENUM.replace('"甲" }', '"甲", colour = 1 }'), "", "enums.mode.0", "unknown field"),
        ('certainty = "printed"', ENUM, "writable_values = [3]", "measurements.ia.writable_values", "read-only"),
        ('certainty = "printed"', ENUM, "writable_values = []", "measurements.ia.writable_values", "non-empty"),
        ('certainty = "printed"', ENUM, "writable_values = [70000]", "measurements.ia.writable_values", "70000"),
    ],
)
def test_bad_certainty_data_is_a_profile_error(model: str, enum: str, point: str, key: str, message: str) -> None:
    with pytest.raises(ProfileError) as info:
        toy(model, enum, point)
    assert info.value.key == key and info.value.source == "toy.toml"
    assert message in str(info.value)
