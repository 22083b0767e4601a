"""The simulator options of ``starterbus simulate`` (the argparse glue) start a front end a client reaches."""

from __future__ import annotations

import argparse

import pytest
from starterbus_canopen.plugin import PLUGIN

from starterbus.core import ConfigurationError, ManualClock, SimulatedStarter, get_profile, open_device


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("--unit", type=int, action="append")
    PLUGIN.add_simulator_arguments(parser)
    return parser.parse_args(list(argv))


def test_options_start_a_simulator_per_bus(channel: str) -> None:
    profile = get_profile("example_canopen_starter")
    starters = [SimulatedStarter(profile, ManualClock(0.0)), SimulatedStarter(profile, ManualClock(0.0))]
    args = parse("--canopen", f"virtual:{channel}", "--canopen-node", "7", "--canopen-node", "9")
    (sim,) = PLUGIN.start_simulators(args, profile, starters)
    try:
        assert set(sim.client_urls()) == {7, 9}
        starters[1].params["ramp_time"] = 33
        with open_device(sim.client_urls()[9], profile) as device:
            assert device.read("ramp_time")["ramp_time"].raw == 33
    finally:
        sim.close()


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["--canopen", "virtual"], "expected INTERFACE:CHANNEL"),
        (["--canopen-node", "3"], "needs --canopen"),
        (["--canopen", "virtual:x", "--canopen-node", "3", "--canopen-node", "4"], "2 --canopen-node value"),
    ],
)
def test_bad_options_are_clear_errors(argv: list[str], error: str) -> None:
    profile = get_profile("example_canopen_starter")
    with pytest.raises(ConfigurationError, match=error):
        PLUGIN.start_simulators(parse(*argv), profile, [SimulatedStarter(profile)])


def test_a_model_without_canopen_is_refused() -> None:
    profile = get_profile("jjr5000")
    with pytest.raises(ConfigurationError, match="has no CANopen interface"):
        PLUGIN.start_simulators(parse("--canopen", "virtual:x"), profile, [SimulatedStarter(profile)])


def test_no_option_starts_nothing() -> None:
    profile = get_profile("example_canopen_starter")
    assert PLUGIN.start_simulators(parse(), profile, [SimulatedStarter(profile)]) == []
