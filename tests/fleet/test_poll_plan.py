"""Poll plans: every register once, merged by wire time; a counting slave sees exactly the planned requests."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.cli.main import main
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.master.poll_plan import PollPlans, cover, fc03_wire_time
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

CHAR = 11 / 19200
SILENCE = 3.5 * CHAR


def test_cover_merges_adjacent_up_to_the_limit() -> None:
    readable = set(range(0, 10))
    assert cover([1, 2, 3, 4], readable, 4, CHAR, SILENCE) == [(1, 4)]
    assert cover([1, 2, 3, 4, 5], readable, 4, CHAR, SILENCE) in ([(1, 4), (5, 1)], [(1, 1), (2, 4)])
    assert cover([4, 1, 4, 2], readable, 1, CHAR, SILENCE) == [(1, 1), (2, 1), (4, 1)]


def test_cover_reads_a_defined_gap_along_but_never_an_undefined_one() -> None:
    assert cover([1, 3], {1, 2, 3}, 4, CHAR, SILENCE) == [(1, 3)]
    assert cover([1, 3], {1, 3}, 4, CHAR, SILENCE) == [(1, 1), (3, 1)]  # 2 would answer exception 02
    far = cover([0, 60], set(range(61)), 125, CHAR, SILENCE)
    assert far == [(0, 1), (60, 1)], "59 registers along cost more wire than a second request"


@given(
    needed=st.lists(st.integers(0, 40), min_size=1, max_size=12),
    holes=st.sets(st.integers(0, 40), max_size=10),
    limit=st.integers(1, 8),
)
def test_cover_reads_every_register_within_the_rules_and_never_costs_more_than_adjacent_merging(
    needed: list[int], holes: set[int], limit: int
) -> None:
    readable = set(range(41)) - holes | set(needed)
    plan = cover(needed, readable, limit, CHAR, SILENCE)
    covered = [a for start, count in plan for a in range(start, start + count)]
    assert set(needed) <= set(covered)
    assert len(covered) == len(set(covered)), "a register is read once"
    assert all(1 <= count <= limit for _, count in plan)
    assert set(covered) <= readable
    adjacent: list[tuple[int, int]] = []  # the plan without gaps read along
    for a in sorted(set(needed)):
        if adjacent and a == sum(adjacent[-1]) and adjacent[-1][1] < limit:
            adjacent[-1] = (adjacent[-1][0], adjacent[-1][1] + 1)
        else:
            adjacent.append((a, 1))
    cost = sum(fc03_wire_time(n, CHAR, SILENCE) for _, n in plan)
    assert cost <= sum(fc03_wire_time(n, CHAR, SILENCE) for _, n in adjacent) + 1e-12


@pytest.mark.parametrize(("model", "requests"), [("jjr5000", 1), ("ssd1", 1), ("jjr8000", 4)])
def test_status_and_phase_currents_are_read_once(model: str, requests: int) -> None:
    profile = get_profile(model)
    plans = PollPlans(profile, int(profile.transport_settings("modbus-rtu")["max_read_registers"]), 19200, SILENCE)
    plan = plans.get(profile.phase_currents(), status=True)
    assert len(plan.requests) == requests
    assert sum(count for _, count in plan.requests) == 4


@pytest.fixture
def counting_line() -> Iterator[ModbusRtuSimulator]:
    starters = {
        unit: SimulatedStarter(get_profile(model)) for unit, model in ((1, "jjr5000"), (2, "ssd1"), (3, "jjr8000"))
    }
    with ModbusRtuSimulator(starters, pty=True, baudrate=19200) as sim:
        yield sim


def _fleet(sim: ModbusRtuSimulator, tmp_path: Path, extra: str = "") -> Path:
    base = sim.url(1).split("?")[0]
    text = f'[[bus]]\nname = "rtu"\nurl = "{base}?baudrate=19200&timeout=0.5"\n'
    for unit, model in ((1, "jjr5000"), (2, "ssd1"), (3, "jjr8000")):
        text += f'[[bus.device]]\nname = "{model}"\nmodel = "{model}"\naddress = {unit}\n'
        if unit == 1:
            text += extra
    path = tmp_path / "fleet.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("extra", "jjr5000_requests"),
    [("", 1), ('parameters = ["current_limit", "ramp_time"]\n', 2)],
)
def test_poll_once_sends_exactly_the_planned_requests(
    counting_line: ModbusRtuSimulator,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: str,
    jjr5000_requests: int,
) -> None:
    fleet = _fleet(counting_line, tmp_path, extra)
    assert main(["poll", str(fleet), "--plan", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    planned = {d["device"]: len(d["requests"]) for d in plan["buses"][0]["devices"]}
    assert planned == {"jjr5000": jjr5000_requests, "ssd1": 1, "jjr8000": 4}
    assert counting_line.counters.requests == 0, "--plan sends nothing"

    assert main(["poll", str(fleet), "--once", "--json"]) == 0
    samples = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert {s["device"]: s["wire"]["requests"] for s in samples} == planned
    assert all(s["online"] and s["error"] is None for s in samples)
    assert counting_line.counters.requests == sum(planned.values())
    assert counting_line.counters.errors == 0


def test_poll_gives_the_status_and_the_values_of_separate_reads(counting_line: ModbusRtuSimulator) -> None:
    from starterbus.core.device import open_device

    with open_device(counting_line.url(1), "jjr5000") as device:
        profile: Profile = device.profile
        points = device.resolve(["phase_b_current", "current_limit", "ramp_time"])
        polled = device.transport.poll(points, status=True)
        separate_status = device.status()
        separate_values = device.read(*points)
    assert polled.status is not None
    assert polled.status.state == separate_status.state
    assert polled.status.currents == separate_status.currents
    assert {r.point.key: r.value("modbus-rtu") for r in polled.readings} == separate_values
    assert [r.point for r in polled.readings] == points
    assert profile.name == "jjr5000"


def test_plan_and_line_counts_as_text(
    counting_line: ModbusRtuSimulator, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet = _fleet(counting_line, tmp_path)
    assert main(["poll", str(fleet), "--plan"]) == 0
    text = capsys.readouterr().out
    assert "unit 1 FC03 0x0001 x4: status_word, phase_a_current, phase_b_current, phase_c_current" in text
    assert text.count("unit 3 FC03") == 4
    # 2 FC03 of 4 registers + 4 of 1 register at 19200 baud: (2 x 21 + 4 x 15) characters + 12 silences
    assert "line budget: 82.5 ms of wire per round vs 1000 ms: 8.2 % of the line; at most 12.1 rounds/s" in text
    assert main(["poll", str(fleet), "--once"]) == 0
    assert "line rtu: 6 requests (0 retries, 0 timeouts), 48 B out, 54 B in, wire " in capsys.readouterr().out


def test_probe_settings_out_of_range_are_one_line_errors(
    counting_line: ModbusRtuSimulator, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet = _fleet(counting_line, tmp_path)
    assert main(["poll", str(fleet), "--once", "--probe-share", "0"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("starterbus: error: probe share 0.0 must be in (0, 1]") and err.count("\n") == 1
    assert counting_line.counters.requests == 0


def test_a_pkw_devices_plan_sends_a_task_for_each_point_and_nothing_for_the_status(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The status of a cyclic protocol comes in every cycle's inputs: not a request of its own (``frames`` 0)."""
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(
        '[[bus]]\nname = "dp"\nurl = "profibus-pkw+gateway://192.0.2.1:502?ppo=1"\n'  # never contacted
        '[[bus.device]]\nname = "mill"\nmodel = "jjr8000"\nmeasurements = ["phase_a_current", "phase_b_current"]\n'
    )
    assert main(["poll", str(fleet), "--plan", "--json"]) == 0
    (bus,) = json.loads(capsys.readouterr().out)["buses"]
    (device,) = bus["devices"]
    assert [r["frames"] for r in device["requests"]] == [0, 2, 2]
    assert main(["poll", str(fleet), "--plan"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("mill"))
    assert row.split()[:4] == ["mill", "jjr8000", "2", "3"], row
