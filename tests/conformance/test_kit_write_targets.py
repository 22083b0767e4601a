"""The kit's write tests never pass silently: a model without printed codes is written with accept_uncertain
and a notice; a writable transport with nothing the kit may write fails, naming the model."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

from starterbus.core.device import Device
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile, load_profile_text
from starterbus.core.registry import get_profile
from starterbus.core.url import DeviceUrl
from starterbus.testing import ConformanceNotice, TransportConformance
from starterbus.tests.stub_transport import StubTransport

JJR5000 = Path(__file__).parents[2] / "core" / "profiles" / "jjr5000.toml"


class Previewing(StubTransport):
    """Addresses every point (its previews work) when ``addressed``; otherwise none."""

    name = "previewing"

    def __init__(self, profile: Profile, addressed: bool = True) -> None:
        super().__init__(DeviceUrl.parse("previewing://here"), profile)
        self.addressed = addressed

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        return [Reading(p, p.raw_min) for p in points]

    def _preview_write(self, point: PointDef, raw: int) -> list[str]:
        if not self.addressed:
            raise self.unsupported(f"reach {point.key}")
        return [f"{point.key}={raw}"]


class Kit(TransportConformance):
    transport = "previewing"


def no_certainty() -> Profile:
    """The JJR5000 as a model that states no certainty: every code and scale is "assumed"."""
    text = JJR5000.read_text(encoding="utf-8")
    assert '\ncertainty = "printed"\n' in text
    return load_profile_text(text.replace('\ncertainty = "printed"\n', "\n", 1), "no-certainty.toml")


def test_printed_codes_are_written_without_notice(recwarn: pytest.WarningsRecorder) -> None:
    profile = get_profile("jjr5000")
    points, uncertain = Kit().write_targets(Device(Previewing(profile), profile))
    assert points and not uncertain and all(p.uncertainty(p.raw_max) is None for p in points)
    assert not [w for w in recwarn if issubclass(w.category, ConformanceNotice)]


def test_a_model_without_printed_codes_is_written_with_accept_uncertain_and_a_notice() -> None:
    profile = no_certainty()
    with pytest.warns(ConformanceNotice, match="JJR5000 states no parameter whose codes are all printed"):
        points, uncertain = Kit().write_targets(Device(Previewing(profile), profile))
    assert points and uncertain


def test_nothing_to_write_fails_naming_the_model() -> None:
    profile = get_profile("jjr5000")
    with pytest.raises(pytest.fail.Exception, match="JJR5000 has no parameter the kit may write"):
        Kit().write_targets(Device(Previewing(profile, addressed=False), profile))
