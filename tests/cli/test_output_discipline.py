"""Output discipline: every command takes ``--json`` and then writes JSON only on stdout; a closed pipe ends quietly
with exit 0 (buffered as in a user's shell, not only unbuffered); Ctrl-C exits 130 after a clean shutdown.

Run through the installed console script (``starterbus``): the process boundary is the point.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from starterbus.cli.parser import build_parser, parse_arguments
from starterbus.opcua.users import Role, load_users
from starterbus.serve.embedded import mosquitto_binary
from starterbus.tests.cli.test_habits import EXE, run, spawn
from starterbus.tests.cli.test_help_examples import COMMANDS, subparsers
from starterbus.tests.ops.test_record import check_png, write_start_history

DEMO_DEVICES = ["conveyor", "fan", "crusher", "mill", "mixer", "pump-a", "pump-b"]
FRAME = ["02", "03", "01", "00", "00", "01", "85", "C5"]


def takes_json(parser: argparse.ArgumentParser) -> bool:
    return any("--json" in action.option_strings for action in parser._actions)


def nested(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """A command's own sub-commands (``decode PROTOCOL``), if it has any."""
    found = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(found[0].choices) if found else {}


def test_the_walk_sees_every_command() -> None:
    assert {"plot", "serve", "opcua", "opcua-user", "completion", "decode", "read", "poll"} <= set(COMMANDS)
    assert {"modbus-rtu", "profibus-pkw", "devicenet"} <= set(nested(subparsers(build_parser(["decode"]))["decode"]))


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_takes_json(name: str) -> None:
    command = subparsers(build_parser([name]))[name]  # its options are built only when it is asked for
    assert takes_json(command), f"`starterbus {name}` takes no --json"
    for sub, parser in nested(command).items():
        assert takes_json(parser), f"`starterbus {name} {sub}` takes no --json"


def test_decode_takes_json_before_or_after_the_protocol() -> None:
    assert parse_arguments(["decode", "--json", "modbus-rtu", *FRAME]).json is True
    assert parse_arguments(["decode", "modbus-rtu", "--json", *FRAME]).json is True
    assert parse_arguments(["decode", "modbus-rtu", *FRAME]).json is False
    result = run("decode", "--json", "modbus-rtu", *FRAME)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)[0]["title"] == "request: read 1 register(s) from 0x0100 at unit 2"


def closed_pipe(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    """Run with stdout a pipe whose reader is gone before the first write (``| head`` that has its line), and
    stdout buffered as in a user's shell: without PYTHONUNBUFFERED, the failed write comes at the final flush."""
    read, write = os.pipe()
    os.close(read)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    try:
        return subprocess.run(
            [EXE, *args], stdout=write, stderr=subprocess.PIPE, input=stdin, text=True, env=env, timeout=60, check=False
        )
    finally:
        os.close(write)


@pytest.mark.parametrize(
    "words", [["--version"], ["models", "--json"], ["params", "ssd1"], ["completion", "zsh", "--json"]]
)
def test_a_closed_pipe_ends_quietly_however_little_was_written(words: list[str]) -> None:
    result = closed_pipe(*words)
    assert (result.returncode, result.stderr) == (0, "")


def test_a_stream_ends_when_its_reader_goes_away() -> None:
    """`demo --json | head -1`: the polling stops cleanly at the first failed write, long before the duration."""
    result = closed_pipe("demo", "--json", "--duration", "600")  # (the subprocess's timeout is 60 s)
    assert (result.returncode, result.stderr) == (0, "")  # no summary either: nobody reads any more


def test_plot_json(tmp_path: Path) -> None:
    db = tmp_path / "h.db"
    event = write_start_history(db)
    png = tmp_path / "start.png"
    result = run("plot", str(db), "--device", "m1", "--event", str(event), "-o", str(png), "--json")
    assert result.returncode == 0, result.stderr
    # the samples from before the start (99.5 s) up to the next change of state (105 s): 56 of the 60
    assert json.loads(result.stdout) == {"file": str(png), "device": "m1", "event": event, "samples": 56}
    check_png(png)
    png.unlink()
    result = closed_pipe("plot", str(db), "--device", "m1", "--event", str(event), "-o", str(png), "--json")
    assert (result.returncode, result.stderr) == (0, "") and png.exists()  # the work is done; only the report is lost


def test_opcua_user_json(tmp_path: Path) -> None:
    users = tmp_path / "users.toml"
    result = run("opcua-user", str(users), "alice", "--role", "operator", "--json", stdin="correct horse\n")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == {"file": str(users), "user": "alice", "action": "set", "role": "operator"}
    assert load_users(users)["alice"].role is Role.OPERATOR
    result = closed_pipe("opcua-user", str(users), "bob", "--json", stdin="battery staple\n")
    assert (result.returncode, result.stderr) == (0, "") and set(load_users(users)) == {"alice", "bob"}
    result = run("opcua-user", str(users), "alice", "--delete", "--json")
    assert json.loads(result.stdout) == {"file": str(users), "user": "alice", "action": "removed", "role": None}
    assert set(load_users(users)) == {"bob"}
    result = run("opcua-user", str(users), "carol", "--json", stdin="short\n")
    assert result.returncode == 1 and result.stdout == "" and "at least 8 characters" in result.stderr


def test_completion_json() -> None:
    result = run("completion", "bash", "--json")
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert set(doc) == {"shell", "script"} and doc["shell"] == "bash"
    assert doc["script"] + "\n" == run("completion", "bash").stdout  # the same script, as a JSON string
    assert "complete -F _starterbus starterbus" in doc["script"]


@pytest.fixture
def audit_env(tmp_path: Path) -> dict[str, str]:
    return {"STARTERBUS_AUDIT_LOG": str(tmp_path / "audit.jsonl")}


def ready(proc: subprocess.Popen[str]) -> dict[str, Any]:
    """The JSON line a server prints once it runs (with its stderr when it died before)."""
    assert proc.stdout is not None and proc.stderr is not None
    line = proc.stdout.readline()
    if not line:
        pytest.fail(f"exit {proc.wait(30)} before the ready line: {proc.stderr.read()}")
    doc = json.loads(line)
    assert isinstance(doc, dict)
    return doc


def interrupt(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    return proc.returncode, out, err


@pytest.fixture
def stopper() -> Iterator[list[subprocess.Popen[str]]]:
    running: list[subprocess.Popen[str]] = []
    yield running
    for proc in running:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_opcua_json_says_when_it_is_up_and_ctrl_c_exits_130(
    tmp_path: Path, audit_env: dict[str, str], stopper: list[subprocess.Popen[str]]
) -> None:
    proc = spawn(
        "opcua", "--demo", "--json", "--anonymous", "--endpoint", "opc.tcp://127.0.0.1:0/starterbus",
        "--pki", str(tmp_path / "pki"), env=audit_env,
    )  # fmt: skip
    stopper.append(proc)
    doc = ready(proc)
    endpoint = urlsplit(str(doc["endpoint"]))
    assert doc["event"] == "ready" and endpoint.hostname == "127.0.0.1" and endpoint.port != 0
    assert doc["devices"] == DEMO_DEVICES and doc["anonymous"] is True and doc["users"] == 0
    assert doc["security"] == [
        f"{policy} {mode}"
        for policy in ("Basic256Sha256", "Aes256_Sha256_RsaPss", "Aes128_Sha256_RsaOaep")
        for mode in ("SignAndEncrypt", "Sign")
    ]
    socket.create_connection(("127.0.0.1", endpoint.port or 0), timeout=10).close()  # it listens there
    code, out, err = interrupt(proc)
    assert (code, out) == (130, "") and "Traceback" not in err


@pytest.mark.skipif(mosquitto_binary() is None, reason="mosquitto is not installed (apt-get install mosquitto)")
def test_serve_json_says_when_it_is_up_and_ctrl_c_exits_130(
    tmp_path: Path, audit_env: dict[str, str], stopper: list[subprocess.Popen[str]]
) -> None:
    proc = spawn(
        "serve", "--demo", "--json", "--node", "t1", "--state-file", str(tmp_path / "bdseq.json"),
        "--metrics", "127.0.0.1:0", env=audit_env,
    )  # fmt: skip
    stopper.append(proc)
    doc = ready(proc)
    assert doc["event"] == "ready" and doc["embedded_broker"] is True and doc["opcua"] is None
    assert str(doc["broker"]).startswith("mqtt://127.0.0.1:") and doc["topic"] == "spBv1.0/starterbus/+/t1"
    assert (doc["group"], doc["node"], doc["commands"]) == ("starterbus", "t1", False)
    assert sorted(doc["devices"]) == sorted(DEMO_DEVICES)
    with urllib.request.urlopen(str(doc["metrics"]), timeout=10) as answer:
        assert answer.status == 200
    code, out, err = interrupt(proc)
    assert (code, out) == (130, "") and "Traceback" not in err
