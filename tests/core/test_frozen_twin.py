"""Objects a poll builds without their ``__init__`` (core/frozen_twin.py) are the objects ``__init__`` makes."""

from __future__ import annotations

import dataclasses
import pickle

import pytest

from starterbus.core.frozen_twin import twin
from starterbus.core.model import Kind, Label, PointDef, Reading, Value, readings
from starterbus.core.polling import TransportCounters
from starterbus.core.status import FaultTable, Status, decode_status_word, status_with_currents

CURRENT = PointDef("current_a", Kind.MEASUREMENT, "m1", "电流", "current", 0, 9999, 0.1, "A")
FAULTS = FaultTable({3: Label("overheat", "过热")})


def slow_decode(word: int, bit12: bool, currents: dict[str, Value], extra: dict[str, int] | None) -> Status:
    """The decoding written out with Status's own ``__init__``."""
    fault = bool(word & 0x8000)
    known = 0xE73F | (0x1000 if bit12 else 0)
    return Status(
        fault=fault,
        fault_code=word & 0x3F if fault else None,
        fault_text=FAULTS.text(word & 0x3F) if fault else None,
        starting=bool(word & 0x100),
        running=bool(word & 0x200),
        stopping=bool(word & 0x400),
        ready=bool(word & 0x2000),
        bus_control=bool(word & 0x4000),
        mains_voltage=bool(word & 0x1000) if bit12 else None,
        currents=currents,
        raw={"status_word": word, **(extra or {})},
        unknown_bits=word & ~known & 0xFFFF,
        source="here",
        timestamp=0.0,
    )


@pytest.mark.parametrize("word", [0, 0x2200, 0x8003, 0x9FFF, 0xFFFF, 0x1234, 0x2200])
@pytest.mark.parametrize("bit12", [False, True])
def test_status_is_the_one_init_makes(word: int, bit12: bool) -> None:
    for extra in (None, {"act": 7}):
        for _ in range(2):  # decoded, then taken from what is kept
            made = decode_status_word(word, FAULTS, bit12_is_mains_voltage=bit12, source="here", extra_raw=extra)
            expected = slow_decode(word, bit12, {}, extra)
            assert type(made) is Status
            assert dataclasses.replace(made, timestamp=0.0) == expected
            assert repr(dataclasses.replace(made, timestamp=0.0)) == repr(expected)
            assert made.state is expected.state


def test_status_keeps_the_rules() -> None:
    status = decode_status_word(0x8003, FAULTS)
    with pytest.raises(dataclasses.FrozenInstanceError):
        status.fault = False  # type: ignore[misc]
    assert pickle.loads(pickle.dumps(status)) == status
    assert decode_status_word(0x8063, FAULTS).fault_text == "unknown fault 35"
    for word in (-1, 0x10000):
        with pytest.raises(ValueError, match="not a 16-bit value"):
            decode_status_word(word, FAULTS)
    with pytest.raises(TypeError):
        decode_status_word(5.0, FAULTS)  # type: ignore[arg-type]
    currents = {"a": Value.from_raw(CURRENT, 3)}
    given = decode_status_word(0x2200, FAULTS, currents=currents)
    assert given.currents == currents and given.currents is not currents  # a copy, as before


def test_status_with_currents_scales_them() -> None:
    class Model:
        faults = FAULTS

        class control:  # noqa: N801
            bit12_is_mains_voltage = True

        @staticmethod
        def phase_currents() -> list[PointDef]:
            return [CURRENT, CURRENT]

    status = status_with_currents(Model(), 0x3200, [123, 45], source="here", current_source="wire")
    assert status.currents == {"a": Value(CURRENT, 123, 12.3, 0.1, "wire"), "b": Value(CURRENT, 45, 4.5, 0.1, "wire")}
    assert dataclasses.replace(status, timestamp=0.0) == slow_decode(0x3200, True, dict(status.currents), None)


@pytest.mark.parametrize(("raw", "scale"), [(123, None), (0, None), (9999, 1.0), (17, 0.01), (5, 2.0)])
def test_value_is_the_one_init_makes(raw: int, scale: float | None) -> None:
    made = Value.from_raw(CURRENT, raw, scale, "wire")
    factor = CURRENT.scale if scale is None else scale
    expected = Value(CURRENT, raw, raw if factor == 1 else round(raw * factor, 2), factor, "wire")
    assert type(made) is Value and made == expected and repr(made) == repr(expected)
    assert type(made.value) is type(expected.value)
    assert pickle.loads(pickle.dumps(made)) == made
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.raw = 1  # type: ignore[misc]


def test_readings_are_the_ones_init_makes() -> None:
    other = dataclasses.replace(CURRENT, key="current_b")
    made = readings([CURRENT, other], iter([123, 0]))
    expected = [Reading(CURRENT, 123), Reading(other, 0)]
    assert [type(r) for r in made] == [Reading, Reading] and made == expected and repr(made) == repr(expected)
    assert made[0].scale is None and made[0].value("wire") == Value.from_raw(CURRENT, 123, None, "wire")
    assert pickle.loads(pickle.dumps(made)) == made
    with pytest.raises(dataclasses.FrozenInstanceError):
        made[0].raw = 1  # type: ignore[misc]
    with pytest.raises(ValueError, match="shorter"):  # a point without its word is a defect, never a reading
        readings([CURRENT, other], [123])


def test_a_twin_needs_plain_slots() -> None:
    @dataclasses.dataclass(frozen=True)
    class NoSlots:
        a: int

    @dataclasses.dataclass(frozen=True, slots=True)
    class Checked:
        a: int

        def __post_init__(self) -> None:
            assert self.a >= 0

    with pytest.raises(TypeError, match="no plain __slots__"):
        twin(NoSlots)
    with pytest.raises(TypeError, match="__post_init__"):
        twin(Checked)


def test_counters_arithmetic() -> None:
    after = TransportCounters(5, 4, 3, 2, 1, 10, 20, 0.5, 0.25)
    before = TransportCounters(1, 1, 1, 1, 1, 1, 1, 0.25, 0.125)
    assert after.minus(before) == TransportCounters(4, 3, 2, 1, 0, 9, 19, 0.25, 0.125)
    copied = after.copy()
    assert copied == after and copied is not after
