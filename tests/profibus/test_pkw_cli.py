"""The CLI through profibus-pkw+gateway:// against the simulator, in-process and as ``starterbus simulate``."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.profile import Profile
from starterbus.core.simulator import Phase, SimulatedStarter
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

Factory = type[ProfibusGatewaySimulator]


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> object:
    code, out, err = run(capsys, *argv, "--json")
    assert code == 0, err
    return json.loads(out)


@pytest.fixture
def audit(tmp_path: Path) -> list[str]:
    return ["--yes", "--audit-log", str(tmp_path / "audit.jsonl")]


@pytest.mark.parametrize("model", ["jjr5000", "jjr8000"])
def test_status_read_write_commands_in_process(
    model: str, gateway_factory: Factory, profiles: dict[str, Profile], capsys: pytest.CaptureFixture[str],
    audit: list[str],
) -> None:  # fmt: skip
    starter = SimulatedStarter(profiles[model])
    sim = gateway_factory(starter, port=0, ppo=1, cycle=0.002).start()
    url = sim.url(0)
    status = run_json(capsys, "status", url, "--model", model)
    assert status["status"]["state"] == "ready"  # type: ignore[index]
    values = run_json(capsys, "read", url, "ramp_time", "phase_b_current", "--model", model)
    assert [v["key"] for v in values["values"]] == ["ramp_time", "phase_b_current"]  # type: ignore[index]
    written = run_json(capsys, "write", url, "ramp_time=25", "--model", model, *audit)
    assert written["written"][0]["read_back"] == "25 s"  # type: ignore[index]
    assert starter.params["ramp_time"] == 25
    code, out, err = run(capsys, "start", url, "--model", model, *audit)
    assert code == 0, err
    assert phase(starter) is Phase.STARTING
    code, out, err = run(capsys, "status", url, "--model", model)
    assert code == 0 and "starting" in out and "current A" in out
    assert run(capsys, "stop", url, "--model", model, *audit)[0] == 0
    assert phase(starter) in (Phase.STOPPING, Phase.STOPPED)
    starter.inject_fault(6)
    assert run(capsys, "reset", url, "--model", model, *audit)[0] == 0
    assert phase(starter) is Phase.STOPPED


def test_errors_and_unsupported_through_the_cli(
    gateway_factory: Factory, jjr8000: Profile, capsys: pytest.CaptureFixture[str], audit: list[str]
) -> None:
    starter = SimulatedStarter(jjr8000)
    starter.write_control_word(0x0009)
    sim = gateway_factory(starter, port=0, ppo=1, cycle=0.002).start()
    code, _, err = run(capsys, "write", sim.url(0), "p7=4.0", "--model", "jjr8000", *audit)
    # refused by the profile's state rule before a byte is sent (the device's own error 3 is tested in
    # test_pkw_transport.py)
    assert code == 1 and "does not accept changes while the motor is starting" in err and "nothing sent" in err
    assert starter.params["current_limit"] == 350
    sim3 = gateway_factory(SimulatedStarter(jjr8000), port=0, ppo=3, cycle=0.002).start()
    code, _, err = run(capsys, "read", sim3.url(0), "p7", "--model", "jjr8000")
    assert code == 1 and "cannot read parameters" in err
    assert run(capsys, "start", sim3.url(0), "--model", "jjr8000", *audit)[0] == 0


def test_dry_run_prints_the_telegrams(jjr8000: Profile, capsys: pytest.CaptureFixture[str]) -> None:
    url = "profibus-pkw+gateway://192.0.2.1:502?ppo=1"  # never contacted
    out = run_json(capsys, "write", url, "p7=3.5", "--model", "jjr8000", "--dry-run")
    frames = out["would_send"][0]["frames"]  # type: ignore[index]
    # a new session: its start chain (reads of p8, p9, p10), then the write; the control word in force left alone
    assert frames[-2:] == ["00 00 00 00 -- -- -- --", "02 07 01 5E -- -- -- --"]
    assert frames[:6] == [f"{t} -- -- -- --" for i in (8, 9, 10) for t in ("00 00 00 00", f"01 {i:02X} 00 00")]
    out = run_json(capsys, "reset", url, "--model", "jjr8000", "--dry-run")
    assert out["would_send"][0]["frames"] == ["00 00 00 00 00 0C 00 00", "00 00 00 00 00 08 00 00"]  # type: ignore[index]


# -- decode -------------------------------------------------------------------------------------------------

DECODE_CASES = [
    # the manual's four-byte examples, each with what the annotation must say
    (["jjr5000", "in", "pzd", "09 00 03 C0"], ["soft starting", "reserved bit 11 set", "96.0 A"]),
    (["jjr5000", "in", "pzd", "81 05 05 64"], ["fault 5: mains phase loss", "138.0 A"]),
    (["jjr8000", "in", "pzd", "81 01 05 64"], ["fault 1: mains phase loss", "138.0 A"]),
    (["jjr5000", "out", "pzd", "00 0B 00 00"], ["start", "bus control", "reserved bits 0x0002"]),
    (["jjr8000", "out", "pzd", "00 09 00 00"], ["start", "bus control"]),
    (["jjr5000", "out", "pkw", "01 02 00 00"], ["read parameter", "soft_stop_time"]),
    (["jjr5000", "in", "pkw", "01 02 00 0C"], ["value in PWE", "12 s"]),
    (["jjr5000", "out", "pkw", "02 03 01 5E"], ["write parameter", "current_limit", "350 %"]),
    (["jjr5000", "in", "pkw", "03 03 00 03"], ["error 3: illegal data value", "JJR5000 table"]),
    (["jjr5000", "out", "pkw", "03 03 00 00"], ["read measurement", "phase_b_current"]),
    (["jjr5000", "in", "pkw", "01 03 02 64"], ["61.2 A"]),
    (["jjr8000", "out", "pkw", "01 03 00 00"], ["read parameter", "p3 ramp_time"]),
    (["jjr8000", "in", "pkw", "01 03 00 0C"], ["12 s"]),
    (["jjr8000", "out", "pkw", "02 07 01 5E"], ["p7 current_limit", "3.50 x In"]),
    (["jjr8000", "in", "pkw", "03 07 00 03"], ["error 3: cannot modify while running", "正在运行不能修改"]),
    (["jjr8000", "in", "pkw", "01 03 02 64"], ["measurement: 61.2 A"]),
    (["jjr8000", "out", "all", "02 07 01 5E 00 09 00 00"], ["write parameter", "3.50 x In", "start"]),
]


@pytest.mark.parametrize(("args", "expected"), DECODE_CASES, ids=[" ".join(a) for a, _ in DECODE_CASES])
def test_decode_the_manuals_examples(args: list[str], expected: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    model, direction, part, data = args
    code, out, err = run(
        capsys, "decode", "profibus-pkw", "--model", model, "--direction", direction, "--part", part, *data.split()
    )
    assert code == 0, err
    for text in expected:
        assert text in out, (text, out)


def test_decode_json_and_errors(capsys: pytest.CaptureFixture[str]) -> None:
    out = run_json(
        capsys, "decode", "profibus-pkw", "--direction", "in", "--kind", "measurement", "01030264", "09000000"
    )
    assert [f["field"] for f in out[0]["fields"]] == ["INDH", "INDL", "PWE", "ZSW", "ACT"]  # type: ignore[index]
    assert "measurement" in out[0]["fields"][1]["meaning"] and "parameter" not in out[0]["fields"][1]["meaning"]  # type: ignore[index]
    code, out_text, _ = run(capsys, "decode", "profibus-pkw", "--direction", "out", "01 02 00 00 00 0B")
    assert code == 1 and "8 bytes, got 6" in out_text and "01 02 00 00 00 0B" in out_text
    code, out_text, _ = run(capsys, "decode", "profibus-pkw", "--direction", "out", "zz")
    assert code == 1 and "not hex" in out_text
    code, _, err = run(capsys, "decode", "profibus-pkw", "--ppo", "3", "--part", "pkw", "--direction", "in", "00")
    assert code == 1 and "PPO3 has no PKW" in err
    code, out_text, _ = run(capsys, "decode", "profibus-pkw", "--ppo", "3", "--direction", "in", "C1 2A 00 00")
    assert code == 0 and "unknown fault 42" in out_text
    # two telegrams back to back
    out = run_json(capsys, "decode", "profibus-pkw", "--direction", "out", "--part", "pkw", "01020000 07070000")
    assert len(out) == 2 and "unknown task code 7" in out[1]["fields"][0]["meaning"]  # type: ignore[arg-type,index]


# -- starterbus simulate as a separate process ------------------------------------------------------------


@pytest.fixture
def simulate_process() -> Iterator[tuple[subprocess.Popen[str], str]]:
    cmd = [
        sys.executable, "-m", "starterbus.cli.main", "simulate", "--model", "jjr5000",
        "--profibus-gateway", "127.0.0.1:0", "--ppo", "1", "--profibus-cycle", "0.003",
        "--unit", "2", "--unit", "3", "--duration", "60",
    ]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    deadline = time.monotonic() + 20
    url = ""
    try:
        assert proc.stdout is not None
        while time.monotonic() < deadline and not url:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            match = re.search(r"station 3 \(JJR5000\): (\S+)", line)
            if match:
                url = match.group(1)
        assert url, f"no station URL printed: {lines!r} {proc.stderr.read() if proc.poll() is not None else ''}"  # type: ignore[union-attr]
        yield proc, url
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def test_cli_against_starterbus_simulate(
    simulate_process: tuple[subprocess.Popen[str], str], capsys: pytest.CaptureFixture[str], audit: list[str]
) -> None:
    proc, url = simulate_process
    assert "?ppo=1&out=4&in=4&unit=1&stale_time=" in url  # the second station, PPO1: four words further
    assert run_json(capsys, "status", url, "--model", "jjr5000")["status"]["state"] == "ready"  # type: ignore[index]
    assert run(capsys, "write", url, "0x0102=30", "--model", "jjr5000", *audit)[0] == 0
    values = run_json(capsys, "read", url, "soft_stop_time", "0x0147", "--model", "jjr5000")
    assert [v["raw"] for v in values["values"]] == [30, 1]  # type: ignore[index]
    assert run(capsys, "start", url, "--model", "jjr5000", *audit)[0] == 0
    state = ""
    for _ in range(50):  # the gateway's image follows within its DP cycle
        state = run_json(capsys, "status", url, "--model", "jjr5000")["status"]["state"]  # type: ignore[index]
        if state == "starting":
            break
    assert state == "starting"
    assert run(capsys, "stop", url, "--model", "jjr5000", *audit)[0] == 0
    assert run(capsys, "reset", url, "--model", "jjr5000", *audit)[0] == 0
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(10) == 0


def test_simulate_refuses_a_model_without_profibus(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "simulate", "--model", "ssd1", "--profibus-gateway", "127.0.0.1:0", "--duration", "0")
    assert code == 1 and "no Profibus interface" in err
    code, _, err = run(capsys, "simulate", "--model", "jjr8000", "--profibus-gateway", "nowhere", "--duration", "0")
    assert code == 1 and "HOST:PORT" in err
    code, _, err = run(
        capsys, "simulate", "--model", "jjr8000", "--profibus-gateway", "127.0.0.1:0", "--unit", "0", "--duration", "0"
    )
    assert code == 1 and "1..127" in err
