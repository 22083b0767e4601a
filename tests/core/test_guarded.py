"""The guarded path: every write and command, from any caller, is validated, confirmed, audited and read back.

Against the Modbus RTU simulator on a real pseudo-terminal; the simulator's trace shows what the line saw.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.core.audit import AuditLog
from starterbus.core.device import open_device
from starterbus.core.errors import RemoteDeviceError, StateRuleError, ValidationError
from starterbus.core.guarded import (
    CommandNotReached,
    ConfirmationRefused,
    Proposal,
    ReadBackMismatch,
    UncertainValueError,
)
from starterbus.core.model import PointDef
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import Command
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator


class Line:
    """A simulated Modbus RTU line on a pty, recording the function code of every request it receives."""

    def __init__(self, starters: dict[int, SimulatedStarter]) -> None:
        self.starters = starters
        self.functions: list[int] = []
        self.sim = ModbusRtuSimulator(starters, pty=True, trace=self._trace).start()

    def _trace(self, kind: str, data: bytes) -> None:
        if kind == "rx" and len(data) >= 2:
            self.functions.append(data[1])

    def url(self, unit: int) -> str:
        return self.sim.client_urls()[unit]


class DeafToStart(SimulatedStarter):
    """Acknowledges every control word but never starts (a wiring fault, a local/remote switch)."""

    def start(self, why: str = "start command") -> bool:
        return False


class TripsOnStart(SimulatedStarter):
    """Trips (overheat) the moment it is started."""

    def start(self, why: str = "start command") -> bool:
        self.inject_fault(2)
        return False


class Sticky(SimulatedStarter):
    def write(self, point: PointDef, raw: int) -> None:
        if point.key != "ramp_time":
            super().write(point, raw)


@pytest.fixture
def line() -> Iterator[Line]:
    j5, j8 = get_profile("jjr5000"), get_profile("jjr8000")
    starters = {
        2: SimulatedStarter(j5),
        3: SimulatedStarter(j8),
        4: DeafToStart(j5),
        5: Sticky(j5),
        6: TripsOnStart(j5),
    }
    line = Line(starters)
    try:
        yield line
    finally:
        line.sim.close()


def entries(path: Path) -> list[dict[str, object]]:
    return [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines()]


def test_api_write_is_audited_and_read_back(line: Line, tmp_path: Path) -> None:
    log = tmp_path / "api.jsonl"
    with open_device(line.url(2), "jjr5000", audit=AuditLog(log), actor="test:api") as dev:
        outcome = dev.write("current_limit", 380)
    assert outcome.ok and outcome.read_back is not None and outcome.read_back.raw == 380
    assert outcome.old is not None and outcome.old.raw == 350
    assert line.functions == [3, 6, 3]  # old value, the write, the read-back
    (entry,) = entries(log)
    assert entry["actor"] == "test:api" and entry["key"] == "current_limit" and entry["result"] == "ok"
    assert (entry["old"], entry["new"], entry["raw"], entry["read_back"]) == ("350 %", "380 %", 380, "380 %")


def test_default_audit_log_is_used_by_a_library_caller(line: Line, _audit_log_in_tmp: Path) -> None:
    with open_device(line.url(2), "jjr5000") as dev:
        dev.write("ramp_time", 20)
    assert entries(_audit_log_in_tmp)[-1]["key"] == "ramp_time"


def test_locked_while_running_is_refused_before_any_write(line: Line, tmp_path: Path) -> None:
    starter = line.starters[3]
    starter.start()
    with open_device(line.url(3), "jjr8000", audit=AuditLog(tmp_path / "a.jsonl")) as dev:
        line.functions.clear()
        with pytest.raises(StateRuleError, match=r"ramp_time: JJR8000 does not accept changes while the motor is"):
            dev.write("ramp_time", 10)
        assert 6 not in line.functions  # the status was read, nothing was written
        dev.write("motor_overload_protection", 0)  # not locked: goes through while running
    assert not (tmp_path / "a.jsonl").exists() or all(e["key"] != "ramp_time" for e in entries(tmp_path / "a.jsonl"))


def test_a_fresh_status_from_a_poll_spares_the_read(line: Line) -> None:
    with open_device(line.url(3), "jjr8000") as dev:
        dev.status()
        line.functions.clear()
        dev.write("ramp_time", 10)
    assert line.functions == [3, 6, 3]


def test_read_back_mismatch_raises_with_every_outcome(line: Line, tmp_path: Path) -> None:
    log = tmp_path / "a.jsonl"
    with (
        open_device(line.url(5), "jjr5000", audit=AuditLog(log)) as dev,
        pytest.raises(ReadBackMismatch, match="wrote 30 s but read back") as info,
    ):
        dev.write_many({"ramp_time": 30, "current_limit": 400})
    results = [(o.key, o.result) for o in info.value.outcomes]
    assert results == [("ramp_time", "mismatch"), ("current_limit", "not sent (an earlier write failed)")]
    assert [e["result"] for e in entries(log)] == ["mismatch"]
    assert line.starters[5].params["current_limit"] == 350


def test_the_devices_refusal_is_its_typed_cause_and_audited(line: Line, tmp_path: Path) -> None:
    log = tmp_path / "a.jsonl"
    with open_device(line.url(2), "jjr5000", audit=AuditLog(log)) as dev:
        dev.write("parameter_modify", 0)
        with pytest.raises(RemoteDeviceError) as info:
            dev.write("current_limit", 400)
    assert info.value.code == 4
    assert str(entries(log)[-1]["result"]).startswith("failed: ")


def test_confirmation_hook_sees_raw_codes_and_frames_and_can_refuse(line: Line, tmp_path: Path) -> None:
    seen: list[Proposal] = []

    def refuse(proposal: Proposal) -> bool:
        seen.append(proposal)
        return False

    log = tmp_path / "a.jsonl"
    with open_device(line.url(2), "jjr5000", audit=AuditLog(log), confirm=refuse) as dev:
        line.functions.clear()
        with pytest.raises(ConfirmationRefused, match="nothing sent"):
            dev.write("current_limit", 380)
        with pytest.raises(ConfirmationRefused):
            dev.start()
    assert seen[0].writes[0].raw == 380 and any("01 03 01 7C" in f.upper() for f in seen[0].frames)
    assert seen[1].command is Command.START
    assert 6 not in line.functions and line.starters[2].phase is Phase.STOPPED
    assert [e["result"] for e in entries(log)] == ["not confirmed", "not confirmed"]


def test_an_uncertain_code_needs_an_acknowledgement(line: Line, tmp_path: Path) -> None:
    """JJR8000 p15: the manual prints the overload classes without codes; code 1 (class 20) is inferred."""
    log = tmp_path / "a.jsonl"
    with open_device(line.url(3), "jjr8000", audit=AuditLog(log)) as dev:
        line.functions.clear()
        with pytest.raises(UncertainValueError, match=r"code 1 \(class 20\) is inferred.*accept_uncertain"):
            dev.write("motor_overload_class", "class 20")
        assert 6 not in line.functions and not log.exists()
        outcome = dev.write("motor_overload_class", "class 20", accept_uncertain=True)
    assert outcome.ok and line.starters[3].params["motor_overload_class"] == 1
    assert "inferred" in str(entries(log)[-1]["acknowledged"])


def test_commands_report_the_state_reached(line: Line, tmp_path: Path) -> None:
    log = tmp_path / "a.jsonl"
    with open_device(line.url(2), "jjr5000", audit=AuditLog(log)) as dev:
        started = dev.start()
        assert started.ok and started.reached is not None and started.reached.state.value == "starting"
        stopped = dev.stop()
        assert stopped.ok and stopped.reached is not None and stopped.reached.state.value in ("stopping", "ready")
        line.starters[2].inject_fault(6)
        reset = dev.reset()
        assert reset.ok and reset.before is not None and reset.before.fault and not reset.reached.fault  # type: ignore[union-attr]
    assert [(e["command"], e["before"], e["result"]) for e in entries(log)] == [
        ("start", "ready", "ok"), ("stop", "starting", "ok"), ("reset", "fault", "ok"),
    ]  # fmt: skip


def test_a_command_not_reached_fails_and_says_so(line: Line, tmp_path: Path) -> None:
    log = tmp_path / "a.jsonl"
    clock = ManualClock(0.0)
    with open_device(line.url(4), "jjr5000", audit=AuditLog(log)) as dev:
        dev.guard.clock, dev.guard.sleep = clock, clock.advance
        with pytest.raises(CommandNotReached, match=r"still ready 2 s after the command") as info:
            dev.start(timeout=2)
    (outcome,) = info.value.outcomes
    assert outcome.result == "not reached" and outcome.reached is not None
    assert str(entries(log)[-1]["result"]).startswith("not reached: ")


def test_a_start_that_trips_is_not_a_success(line: Line) -> None:
    with open_device(line.url(6), "jjr5000") as dev, pytest.raises(CommandNotReached, match="tripped: fault 2"):
        dev.start(timeout=1)


def test_a_start_on_a_faulted_starter_is_refused_before_any_frame(line: Line, tmp_path: Path) -> None:
    line.starters[2].inject_fault(2)
    log = tmp_path / "a.jsonl"
    with open_device(line.url(2), "jjr5000", audit=AuditLog(log)) as dev:
        line.functions.clear()
        with pytest.raises(StateRuleError, match=r"faulted \(fault 2: overheat\); reset the fault first.*nothing sent"):
            dev.start(force=True)  # no override for this one
    assert 6 not in line.functions and line.starters[2].control_word == 0
    assert str(entries(log)[-1]["result"]).startswith("refused: ")


def test_validation_errors_send_nothing(line: Line) -> None:
    with open_device(line.url(2), "jjr5000") as dev:
        line.functions.clear()
        with pytest.raises(ValidationError):
            dev.write_many({"ramp_time": 20, "current_limit": 1000})
    assert line.functions == []


def test_cli_needs_accept_uncertain_and_shows_the_raw_code(line: Line, capsys: pytest.CaptureFixture[str]) -> None:
    from starterbus.cli.main import main

    url = line.url(3)
    assert main(["write", url, "--model", "jjr8000", "p15=class 20", "--yes"]) == 1
    err = capsys.readouterr().err
    assert "inferred" in err and "--accept-uncertain" in err and len(err.strip().splitlines()) == 1
    assert main(["write", url, "--model", "jjr8000", "p15=class 20", "--dry-run", "--json"]) == 1
    capsys.readouterr()
    assert main(["write", url, "--model", "jjr8000", "p15=class 20", "--accept-uncertain", "--dry-run", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["would_send"][0]["raw"] == 1
    assert main(["write", url, "--model", "jjr8000", "p15=class 20", "--accept-uncertain", "--yes"]) == 0
    assert line.starters[3].params["motor_overload_class"] == 1
