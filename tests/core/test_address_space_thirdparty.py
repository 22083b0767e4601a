"""Issue 28, item 1: a third-party transport declaring the Modbus register address space, installed as its own
distribution, reads, writes, polls and cross-checks the shipped ``jjr5000`` and ``ssd1`` by their shipped names,
with no model file of its own; and an overlay adds a space to a shipped model without renaming it."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator

#: a Modbus TCP transport written against the public API only (pymodbus moves the registers)
PLUGIN_SOURCE = """
from pymodbus.client import ModbusTcpClient

from starterbus.core import (
    Capability, ControlWordState, Reading, RemoteDeviceError, TimeoutError, Transport, TransportPlugin,
    status_with_currents,
)
from starterbus.spaces.modbus import ModbusSettings

CAPS = frozenset({Capability.STATUS, Capability.READ_MEASUREMENTS, Capability.READ_PARAMETERS,
                  Capability.WRITE_PARAMETERS, Capability.COMMANDS})


class AcmeTransport(Transport):
    name = "acme-mbap"

    def __init__(self, url, profile, unit):
        super().__init__(url, profile)
        self.unit = unit
        self.settings = ModbusSettings.of(profile)  # the shipped model's own table, typed
        self.control = ControlWordState()

    @property
    def capabilities(self):
        return CAPS

    def _open(self):
        host, port = self.url.host_port(502)
        self.client = ModbusTcpClient(host, port=port, timeout=2, retries=0)
        self.client.connect()

    def _close(self):
        self.client.close()

    def _check(self, answer, what):
        if answer.isError():
            code = getattr(answer, "exception_code", 0)
            if code in (0x0A, 0x0B):
                raise TimeoutError(f"{what}: the device behind the gateway is unreachable")
            raise RemoteDeviceError("acme-mbap", code, self.settings.exception_text(code), detail=what)
        return answer

    def _read_points(self, points):
        out = []
        for point in points:
            address = point.address_for("modbus")
            answer = self._check(self.client.read_holding_registers(address, count=1, device_id=self.unit), point.key)
            out.append(Reading(point, answer.registers[0]))
        return out

    def _write_parameter(self, point, raw):
        self._check(self.client.write_register(point.address_for("modbus"), raw, device_id=self.unit), point.key)

    def _read_status(self):
        status, *currents = self._read_points([self.profile.role("status_word"), *self.profile.phase_currents()])
        return status_with_currents(self.profile, status.raw, [r.raw for r in currents], source="acme-mbap")

    def _send_command(self, command):
        state = ControlWordState(self.control.bus_control, self.control.run)
        for word in state.apply(command):
            self._write_parameter(self.profile.role("control_word"), word)
        self.control.apply(command)


class AcmePlugin(TransportPlugin):
    name = "acme-mbap"
    address_space = "modbus"  # serves every model that has Modbus registers, by its shipped name
    summary = "ACME Modbus TCP (third party)"
    capabilities = CAPS
    url_forms = ("acme-mbap://HOST:PORT?unit=N",)
    address_parameter = "unit"

    def open(self, url, profile):
        url.check_known({"unit"})
        lo, hi = ModbusSettings.of(profile).unit_ids
        return AcmeTransport(url, profile, url.get_int("unit", lo=max(lo, 1), hi=hi))


PLUGIN = AcmePlugin()
"""


@pytest.fixture
def gateway() -> Iterator[ModbusTcpSimulator]:
    starters = {
        2: SimulatedStarter(get_profile("jjr5000"), ManualClock(0.0), load=0.5),
        3: SimulatedStarter(get_profile("ssd1"), ManualClock(0.0), load=0.5),
    }
    with ModbusTcpSimulator(starters) as sim:
        yield sim


def test_a_third_party_modbus_transport_serves_the_shipped_models(
    tmp_path: Path, third_party: Any, gateway: ModbusTcpSimulator
) -> None:
    third_party.make_dist(
        tmp_path, "acme_mbap", "acme_mbap", "[starterbus.transports]\nacme-mbap = acme_mbap:PLUGIN\n",
        {"__init__.py": PLUGIN_SOURCE},
    )  # fmt: skip
    where = gateway.where
    for unit, model in ((2, "jjr5000"), (3, "ssd1")):
        url = f"acme-mbap://{where}?unit={unit}"
        starter = gateway.starters[unit]
        read = third_party.run_cli("read", url, "--model", model, "ramp_time", "--json", path=tmp_path)
        assert read.returncode == 0, read.stderr
        assert json.loads(read.stdout)["values"][0]["raw"] == starter.params["ramp_time"]
        wrote = third_party.run_cli("write", url, "--model", model, "--yes", "ramp_time=25", path=tmp_path)
        assert wrote.returncode == 0, wrote.stderr
        assert starter.params["ramp_time"] == 25
        starter.start()  # the cross-check compares currents of a running motor
        checked = third_party.run_cli("crosscheck", "--model", model, url, gateway.url(unit), "--json", path=tmp_path)
        assert checked.returncode == 0, checked.stdout + checked.stderr
        assert json.loads(checked.stdout)["ok"] is True
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(
        f'[[bus]]\nname = "acme"\nurl = "acme-mbap://{where}"\n'
        '[[bus.device]]\nname = "a"\nmodel = "jjr5000"\naddress = 2\nparameters = ["ramp_time"]\n'
        '[[bus.device]]\nname = "b"\nmodel = "ssd1"\naddress = 3\nparameters = ["ramp_time"]\n',
        encoding="utf-8",
    )
    polled = third_party.run_cli("poll", str(fleet), "--once", "--json", path=tmp_path)
    assert polled.returncode == 0, polled.stderr
    samples = {s["device"]: s for s in map(json.loads, polled.stdout.splitlines()) if "device" in s}
    assert {s["model"] for s in samples.values()} == {"jjr5000", "ssd1"}  # the shipped names
    assert all(s["online"] for s in samples.values())
    assert sorted(p.name for p in tmp_path.rglob("*.toml")) == ["fleet.toml"]  # no model file written


OVERLAY = """
schema = 1
[overlay]
model = "jjr5000"
[transports.acme-loop]
[addresses.acme-loop]
phase_a_current = 12
status_word = 1
"""

LOOP_SOURCE = """
from starterbus.core import Capability, TransportPlugin, UnsupportedOperationError


class LoopPlugin(TransportPlugin):
    name = "acme-loop"  # no address_space: a space of its own name, its table and addresses parsed here
    summary = "ACME loop"
    capabilities = frozenset({Capability.STATUS})
    url_forms = ("acme-loop://HOST",)

    def open(self, url, profile):
        raise UnsupportedOperationError("test plugin")


PLUGIN = LoopPlugin()
"""


def test_an_overlay_adds_a_space_to_a_shipped_model_without_renaming_it(tmp_path: Path, third_party: Any) -> None:
    third_party.make_dist(
        tmp_path, "acme_loop", "acme_loop",
        "[starterbus.transports]\nacme-loop = acme_loop:PLUGIN\n"
        "[starterbus.overlays]\njjr5000.acme = acme_loop:OVERLAY\n",
        {"__init__.py": LOOP_SOURCE + "\nfrom pathlib import Path\nOVERLAY = Path(__file__).with_name('o.toml')\n",
         "o.toml": OVERLAY},
    )  # fmt: skip
    shown = third_party.run_cli("params", "jjr5000", "--json", path=tmp_path)
    assert shown.returncode == 0, shown.stderr
    doc = json.loads(shown.stdout)
    assert doc["model"] == "jjr5000" and "acme-loop" in doc["served_by"]
    current = next(p for p in doc["measurements"] if p["key"] == "phase_a_current")
    assert current["addresses"]["acme-loop"] == "0x000C" and current["addresses"]["modbus"] == "0x0002"
    ssd1 = third_party.run_cli("models", "--json", path=tmp_path)
    rows = {m["name"]: m for m in json.loads(ssd1.stdout)}
    assert "acme-loop" not in rows["ssd1"]["transports"] and rows["jjr5000"]["overlays"]


def test_a_broken_overlay_leaves_the_model_as_shipped(tmp_path: Path, third_party: Any) -> None:
    third_party.make_dist(
        tmp_path, "acme_bad", "acme_bad",
        "[starterbus.overlays]\njjr5000.bad = acme_bad:OVERLAY\n",
        {"__init__.py": "OVERLAY = {'schema': 1, 'overlay': {'model': 'jjr5000'}, 'transports': {'modbus': {}}}\n"},
    )  # fmt: skip
    shown = third_party.run_cli("params", "jjr5000", "--json", path=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert "already has the modbus address space" in shown.stderr
    assert json.loads(shown.stdout)["model"] == "jjr5000"
