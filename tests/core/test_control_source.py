"""Multi-master awareness: a start, stop or reset is refused, before its first frame, while the starter is
controlled from elsewhere (its control-source parameter, or a motor its status shows driven by the terminals,
the keypad or another master); ``force`` overrides and the audit says so; the hand-over commands never refuse.

Against the Modbus RTU simulator on a pty (the trace counts the requests by function code: 6 is a write), and
a status-only test transport for the paths that cannot read parameters.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.audit import AuditLog
from starterbus.core.device import Device, open_device
from starterbus.core.errors import ControlSourceError, ProfileError, StateRuleError
from starterbus.core.profile import load_profile_text
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import CW_START, Command, ControlWordState, Status, status_with_currents
from starterbus.core.transport import Capability
from starterbus.core.url import DeviceUrl
from starterbus.tests.stub_transport import StubTransport
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

WRITE = 6  # Modbus FC06: every command and parameter write of this line


class Line:
    """Unit 2: JJR5000 commissioned for the bus (the simulator's default); unit 3: JJR5000 on keypad control;
    unit 4: JJR8000 on terminals control; unit 5: SSD1 on bus + terminals."""

    def __init__(self) -> None:
        j5 = get_profile("jjr5000")
        self.starters = {
            2: SimulatedStarter(j5),
            3: SimulatedStarter(j5, values={"control_source": 1}),
            4: SimulatedStarter(get_profile("jjr8000"), values={"control_source": 1}),
            5: SimulatedStarter(get_profile("ssd1"), values={"control_source": 4}),
        }
        self.functions: list[int] = []
        self.sim = ModbusRtuSimulator(self.starters, pty=True, trace=self._trace).start()

    def _trace(self, kind: str, data: bytes) -> None:
        if kind == "rx" and len(data) >= 2:
            self.functions.append(data[1])

    def url(self, unit: int) -> str:
        # 2 s, not the default 0.5 s: a write is not retried, and an in-process simulator thread held for half a
        # second on a loaded machine (-n 3 on two cores) once failed a forced stop with "no answer within 0.5 s"
        return self.sim.url(unit, timeout=2)


@pytest.fixture
def line() -> Iterator[Line]:
    line = Line()
    try:
        yield line
    finally:
        line.sim.close()


def entries(path: Path) -> list[dict[str, object]]:
    return [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines()]


def test_the_simulator_is_commissioned_for_the_bus_unless_told() -> None:
    for model, code in (("jjr5000", 4), ("ssd1", 3), ("jjr8000", 2)):
        profile = get_profile(model)
        assert profile.control.source_bus_codes[0] == code
        assert SimulatedStarter(profile).params["control_source"] == code
    assert SimulatedStarter(get_profile("jjr5000"), values={"control_source": 0}).params["control_source"] == 0


@pytest.mark.parametrize(("unit", "model", "said"), [(3, "jjr5000", "keypad (1)"),
                                                     (4, "jjr8000", "external terminals (1)")])  # fmt: skip
def test_a_control_source_without_the_bus_refuses_every_command(
    line: Line, tmp_path: Path, unit: int, model: str, said: str
) -> None:
    log = tmp_path / "a.jsonl"
    starter = line.starters[unit]
    with open_device(line.url(unit), model, audit=AuditLog(log)) as dev:
        line.functions.clear()
        for command in (Command.START, Command.SOFT_STOP, Command.FAULT_RESET):
            with pytest.raises(
                ControlSourceError,
                match=rf"controlled from elsewhere: its control_source .* {re.escape(said)}: it takes",
            ):
                dev.command(command)
        assert WRITE not in line.functions and starter.control_word == 0 and starter.phase.value == "stopped"
        refusals = entries(log)
        assert len(refusals) == 3 and all(str(e["result"]).startswith("refused: ") for e in refusals)
        assert all("--force" in str(e["result"]) for e in refusals)
        # the override: sent, and the audit record says what it went against
        outcome = dev.start(force=True)
    assert outcome.overridden is not None and said in outcome.overridden
    assert WRITE in line.functions and starter.phase in (Phase.STARTING, Phase.RUNNING)
    assert said in str(entries(log)[-1]["overridden"]) and entries(log)[-1]["result"] == "ok"


def test_the_hand_over_is_never_refused(line: Line) -> None:
    with open_device(line.url(4), "jjr8000") as dev:  # terminals: taking bus control is how one asks for it
        dev.command(Command.TAKE_BUS_CONTROL)
        dev.command(Command.RELEASE_BUS_CONTROL)


def test_a_shared_control_source_lets_the_bus_command(line: Line) -> None:
    with open_device(line.url(5), "ssd1") as dev:  # bus + terminals
        assert dev.start().ok


def test_a_fresh_starter_without_bus_control_is_not_controlled_elsewhere(line: Line) -> None:
    """No master commanded it yet: bit 14 is off, and the command takes bus control itself (bit 3)."""
    with open_device(line.url(2), "jjr5000") as dev:
        before = dev.status()
        assert before.bus_control is False and before.state.value == "ready"
        outcome = dev.start()
    assert outcome.ok and outcome.overridden is None and outcome.reached is not None
    assert outcome.reached.bus_control is True


def test_a_motor_started_from_elsewhere_is_not_stopped(line: Line, tmp_path: Path) -> None:
    starter = line.starters[2]
    starter.write_control_word(CW_START)  # another master that started it without taking bus control
    with open_device(line.url(2), "jjr5000", audit=AuditLog(tmp_path / "a.jsonl")) as dev:
        line.functions.clear()
        for command in (Command.SOFT_STOP, Command.START, Command.FAULT_RESET):
            with pytest.raises(ControlSourceError, match=r"the motor is (starting|running) and the status says"):
                dev.command(command)
        assert WRITE not in line.functions and starter.phase in (Phase.STARTING, Phase.RUNNING)
        assert dev.stop(force=True).ok
    assert starter.phase in (Phase.STOPPING, Phase.STOPPED)


def test_a_motor_this_master_started_is_stopped(line: Line) -> None:
    with open_device(line.url(2), "jjr5000") as dev:
        assert dev.start().ok
        outcome = dev.stop()
    assert outcome.ok and outcome.overridden is None


class StatusOnly(StubTransport):
    """A path that reads the status and sends commands but cannot read parameters (as DeviceNet, PPO3)."""

    name = "status-only"

    def __init__(self, url: DeviceUrl, starter: SimulatedStarter) -> None:
        super().__init__(url, starter.profile)
        self.starter = starter
        self.control = ControlWordState()
        self.sent: list[Command] = []

    @property
    def capabilities(self) -> frozenset[Capability]:
        return frozenset({Capability.STATUS, Capability.COMMANDS})

    def _read_status(self) -> Status:
        return status_with_currents(self.profile, self.starter.status_word(), [])

    def _send_command(self, command: Command) -> None:
        self.sent.append(command)
        for word in self.control.apply(command):
            self.starter.write_control_word(word)


def status_only(values: dict[str, int] | None = None) -> tuple[Device, StatusOnly]:
    starter = SimulatedStarter(get_profile("jjr8000"), ManualClock(0.0), values=values)
    transport = StatusOnly(DeviceUrl.parse("status-only://x"), starter)
    device = Device(transport, starter.profile, audit=AuditLog(Path("/dev/null")))
    device.guard.sleep = lambda _s: None
    return device.open(), transport


def test_without_parameters_the_status_alone_decides() -> None:
    device, transport = status_only({"control_source": 1})  # terminals, but this path cannot read it
    assert device.start(timeout=0).result in ("ok", "not reached")  # the status says nothing against it
    assert transport.sent == [Command.START]
    device, transport = status_only()
    transport.starter.start("terminals")
    with pytest.raises(ControlSourceError, match="bus-control bit off"):
        device.stop()
    assert transport.sent == []


def test_a_start_on_a_faulted_starter_is_refused_even_forced() -> None:
    device, transport = status_only()
    transport.starter.inject_fault(6)
    with pytest.raises(StateRuleError, match=r"faulted \(fault 6: motor overload\); reset the fault first"):
        device.start(force=True)
    assert transport.sent == []
    assert device.reset().ok and transport.sent == [Command.FAULT_RESET]


def test_the_profile_names_the_source_and_its_bus_codes() -> None:
    base = (Path(__file__).parent / "toy_profile.toml").read_text(encoding="utf-8")
    assert load_profile_text(base, "toy.toml").control.source_key == ""
    with pytest.raises(ProfileError, match=r"toy.toml: control.source_bus_codes: given without control.source_key"):
        load_profile_text(base + "\n[control]\nsource_bus_codes = [1]\n", "toy.toml")


def test_cli_refuses_in_one_line_and_force_warns(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line.starters[2].write_control_word(CW_START)  # another master, without the bus-control bit
    log = str(tmp_path / "a.jsonl")
    args = ["stop", line.url(2), "--model", "jjr5000", "--yes", "--audit-log", log]
    line.functions.clear()
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "controlled from elsewhere" in err[0] and "--force" in err[0] and "nothing sent" in err[0]
    assert WRITE not in line.functions
    assert main([*args, "--force", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["overridden"].startswith("the motor is")
    assert "warning: --force: sent although the motor is" in captured.err
