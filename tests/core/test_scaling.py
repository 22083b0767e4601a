"""Scaled values looked up (core/scaling.py) are the values rounding gives, however often asked."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from starterbus.core import scaling
from starterbus.core.scaling import decimals, engineering

FACTORS = st.sampled_from([1, 1.0, 0.1, 0.01, 0.001, 0.5, 2.0, 0.25, 10.0, 0.2, 1 / 3])


@given(st.lists(st.tuples(st.integers(-0x8000, 0xFFFF), FACTORS), max_size=50))
def test_kept_values_are_the_rounded_ones(asked: list[tuple[int, float]]) -> None:
    for raw, factor in asked * 2:  # each twice: computed, then kept
        expected = raw if factor == 1 else round(raw * factor, decimals(factor))
        got = engineering(raw, factor)
        assert got == expected and type(got) is type(expected)


def test_what_is_kept_is_bounded() -> None:
    for raw in range(scaling.VALUES_KEPT + 10):
        assert engineering(raw, 0.1) == round(raw * 0.1, 1)
    assert len(scaling.SCALED[0.1]) <= scaling.VALUES_KEPT
    for i in range(scaling.SCALES_KEPT + 10):
        factor = 0.5 + i / 1000
        assert engineering(7, factor) == round(7 * factor, decimals(factor))
    assert len(scaling.SCALED) <= scaling.SCALES_KEPT
