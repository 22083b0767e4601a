"""The DeviceNet transport takes the assembly instance numbers and the product name from the profile."""

from __future__ import annotations

from pathlib import Path

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError
from starterbus.core.profile import Profile, load_profile_text
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.settings import profile_identity
from starterbus.transports.devicenet.simulator import DeviceNetSlaveSimulator

JJR8000 = Path(__file__).parents[2] / "core" / "profiles" / "jjr8000.toml"
FAST = "dup_mac_wait=0.05&timeout=0.5&epr=50&poll=10"


def toy() -> Profile:
    """The JJR8000 under another name, with other instance numbers and no product name of its own."""
    text = JJR8000.read_text(encoding="utf-8")
    for old, new in (
        ("input_assemblies = [1, 101]", "input_assemblies = [11, 150]"),
        ("output_assemblies = [2, 102]", "output_assemblies = [12, 160]"),
        ('product_name = "JJR8000", ', ""),
        ('display_name = "JJR8000"', 'display_name = "Toy 8000"'),
    ):
        assert old in text
        text = text.replace(old, new)
    return load_profile_text(text, "toy.toml")


def test_the_identity_names_the_profile_s_product() -> None:
    profile = toy()
    assert profile_identity(profile).product_name == "Toy 8000"
    assert profile_identity(profile, product_name="X").product_name == "X"


@pytest.mark.parametrize(("assemblies", "numbers"), [(AssemblySet.BASIC, (11, 12)), (AssemblySet.EXTENDED, (150, 160))])
def test_the_profile_s_assembly_numbers_are_the_ones_used(
    channel: str, assemblies: AssemblySet, numbers: tuple[int, int]
) -> None:
    profile = toy()
    other = AssemblySet.EXTENDED if assemblies is AssemblySet.BASIC else AssemblySet.BASIC
    starter = SimulatedStarter(profile, ManualClock(0.0))
    where = f"devicenet://virtual/{channel}?mac=7&{FAST}"
    with DeviceNetSlaveSimulator(starter, ("virtual", channel), 7, dup_mac_wait=0.05, assemblies=assemblies):
        with pytest.raises(ConfigurationError, match=r"Toy 8000 assembly sets: basic 11/12, extended 150/160"):
            open_device(f"{where}&assemblies={other.value}", profile).open()
        with open_device(where, profile) as device:
            identity = device.transport.identify()
    assert (identity["input_assembly"], identity["output_assembly"]) == numbers
    assert identity["product_name"] == "Toy 8000"
