"""Plugins' simulator and decoder options declared as data: namespaced per plugin, clashes reported and skipped.

Third-party plugins are real distributions (dist-info with entry points on PYTHONPATH) and the real CLI runs in
a subprocess, as in tests/core/test_registry_thirdparty.py: no patching of the registry.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from starterbus.cli.plugin_args import OptionMapper
from starterbus.core.errors import ConfigurationError
from starterbus.core.plugin_options import PluginOption, resolve_options
from starterbus.core.registry import get_profile, get_transport
from starterbus.core.simulator import SimulatedStarter

PLUGINS = '''
from starterbus.core.plugin_options import PluginOption, resolve_options
from starterbus.core.transport import Annotation, Capability, RunningSimulator, TransportPlugin


class Served(RunningSimulator):
    def __init__(self, text):
        self.text = text

    def describe(self):
        return [self.text]

    def close(self):
        pass


class Base(TransportPlugin):
    capabilities = frozenset({Capability.STATUS})

    def open(self, url, profile):
        raise NotImplementedError


class Clashing(Base):
    """Declares the flags of the built-in DeviceNet and Profibus front ends again."""
    name = "acme-clash"
    simulator_options = (PluginOption("node", flag="--mac", type=int), PluginOption("ppo", flag="--ppo"))

    def start_simulator(self, options, starters):
        raise AssertionError("a plugin left out is never started")


class Broken(Base):
    name = "acme-broken"

    @property
    def simulator_options(self):
        raise RuntimeError("declaration exploded")


class Typed(Base):
    name = "acme-typed"
    simulator_options = (PluginOption("port"), PluginOption("speed", type=int, default=7))
    decoder_options = (PluginOption("upper", type=bool),)

    def start_simulator(self, options, starters):
        values = resolve_options(self.simulator_options, options, "acme-typed simulator")
        if values.text("port") is None:
            return []
        return [Served(f"acme-typed: {values.text('port')} speed {values.integer('speed')} units {sorted(starters)}")]

    def decode(self, frames, options, profile):
        values = resolve_options(self.decoder_options, options)
        text = " ".join(frames)
        return [Annotation(text.upper() if values.switch("upper") else text)]


class Legacy(Base):
    """Written against the deprecated argparse hooks (one shared parser, a Namespace)."""
    name = "acme-legacy"

    def add_simulator_arguments(self, parser):
        parser.add_argument("--acme-legacy", default=None)

    def start_simulators(self, args, profile, starters):
        if args.acme_legacy is None:
            return []
        return [Served(f"acme-legacy: {args.acme_legacy} units {args.unit} {profile.name} x{len(starters)}")]

    def add_decode_arguments(self, parser):
        parser.add_argument("--reverse", action="store_true")

    def decode(self, args, profile):
        return [Annotation(" ".join(reversed(args.data)) if args.reverse else " ".join(args.data))]


class LegacyClash(Base):
    name = "acme-legacy-clash"

    def add_simulator_arguments(self, parser):
        parser.add_argument("--acme-ok", default=None)
        parser.add_argument("--modbus-rtu", default=None)


CLASHING, BROKEN, TYPED, LEGACY, LEGACY_CLASH = Clashing(), Broken(), Typed(), Legacy(), LegacyClash()
'''


@pytest.fixture(scope="module")
def plugins(tmp_path_factory: pytest.TempPathFactory, third_party: Any) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("dists")
    third_party.make_dist(
        root,
        "acme_plugins",
        "acme_plugins",
        """
        [starterbus.transports]
        acme-clash = acme_plugins:CLASHING
        acme-broken = acme_plugins:BROKEN
        acme-typed = acme_plugins:TYPED
        acme-legacy = acme_plugins:LEGACY
        acme-legacy-clash = acme_plugins:LEGACY_CLASH
        acme-missing = acme_plugins:NOT_THERE
        """,
        {"__init__.py": PLUGINS},
    )
    yield root


def _warnings(stderr: str) -> dict[str, str]:
    lines = [line for line in stderr.splitlines() if line.startswith("starterbus: warning: transport plugin")]
    return {line.split("'")[1]: line for line in lines}


def test_clashing_plugins_are_reported_and_the_others_simulate(plugins: Path, third_party: Any) -> None:
    done = third_party.run_cli(
        "simulate", "--model", "jjr8000", "--unit", "2", "--modbus-rtu", "PTY", "--devicenet", "virtual:clash",
        "--mac", "5", "--devicenet-dup-mac-wait", "0.05", "--ppo", "3", "--profibus-gateway", "127.0.0.1:0",
        "--acme-typed-port", "here", "--acme-legacy", "there", "--duration", "0.2", path=plugins,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "modbus-rtu" in out and "MAC 5" in out and "PPO3" in out
    assert "acme-typed: here speed 7 units [2]" in out
    assert "acme-legacy: there units [2] jjr8000 x1" in out
    warned = _warnings(done.stderr)
    assert set(warned) == {"acme-clash", "acme-broken", "acme-legacy-clash", "acme-missing"}
    assert "--mac is already devicenet's" in warned["acme-clash"]
    assert "declaration exploded" in warned["acme-broken"]
    assert "--modbus-rtu is already modbus-rtu's" in warned["acme-legacy-clash"]
    assert "NOT_THERE" in warned["acme-missing"]


def test_help_lists_each_plugin_in_its_own_group(plugins: Path, third_party: Any) -> None:
    done = third_party.run_cli("simulate", "--help", path=plugins)
    assert done.returncode == 0, done.stderr
    assert "acme-typed front end:" in done.stdout and "--acme-typed-speed SPEED" in done.stdout
    assert "acme-legacy front end:" in done.stdout
    assert "acme-clash front end" not in done.stdout and "--acme-ok" not in done.stdout  # nothing half-added


def test_decoders_typed_and_deprecated(plugins: Path, third_party: Any) -> None:
    typed = third_party.run_cli("decode", "acme-typed", "--acme-typed-upper", "ab", "cd", "--json", path=plugins)
    assert typed.returncode == 0, typed.stderr
    assert json.loads(typed.stdout)[0]["title"] == "AB CD"
    legacy = third_party.run_cli("decode", "acme-legacy", "--reverse", "ab", "cd", "--json", path=plugins)
    assert legacy.returncode == 0, legacy.stderr
    assert json.loads(legacy.stdout)[0]["title"] == "cd ab"
    builtin = third_party.run_cli(
        "decode", "profibus-pkw", "--direction", "in", "--part", "pzd", "0B37 0064", path=plugins
    )
    assert builtin.returncode == 0, builtin.stderr


def test_resolve_options_converts_checks_and_fills() -> None:
    declared = (
        PluginOption("mac", type=int, multiple=True),
        PluginOption("ppo", type=int, choices=(1, 3), default=1),
        PluginOption("fast", type=bool),
    )
    values = resolve_options(declared, {"mac": ["5", 6]})
    assert dict(values) == {"mac": [5, 6], "ppo": 1, "fast": False}
    assert values.given == {"mac"}
    with pytest.raises(ConfigurationError, match="unknown option.*speed.*known: fast, mac, ppo"):
        resolve_options(declared, {"speed": 1}, "acme")
    with pytest.raises(ConfigurationError, match="'ppo': 2 is not one of 1, 3"):
        resolve_options(declared, {"ppo": "2"})
    with pytest.raises(ConfigurationError, match="'mac': 'x' is not valid"):
        resolve_options(declared, {"mac": "x"})


def test_an_alias_is_dropped_when_taken_the_flag_is_not() -> None:
    parser = argparse.ArgumentParser()
    mapper = OptionMapper({"--baudrate": "the command"})
    plugin = get_transport("modbus-rtu")
    assert mapper.add_typed(plugin, plugin.simulator_options, lambda: parser)
    args = parser.parse_args(["--modbus-rtu", "PTY", "--modbus-rtu-baudrate", "19200", "--parity", "e"])
    assert mapper.given(args, "modbus-rtu") == {"port": "PTY", "baudrate": 19200, "parity": "E"}


def test_python_starts_a_front_end_through_the_typed_call() -> None:
    plugin = get_transport("modbus-rtu")
    starter = SimulatedStarter(get_profile("jjr5000"))
    assert plugin.start_simulator({}, {1: starter}) == []
    running = plugin.start_simulator({"port": "PTY", "parity": "e"}, {1: starter})
    try:
        assert len(running) == 1 and "parity=E" in running[0].client_urls()[1]
    finally:
        for sim in running:
            sim.close()
    with pytest.raises(ConfigurationError, match="need --modbus-rtu"):
        plugin.start_simulator({"parity": "E"}, {1: starter})
