"""Where the servers listen: an OPC UA endpoint that is not ``opc.tcp://HOST:PORT`` and a busy port (OPC UA or
``--metrics``) are each one line naming it, a non-zero exit, no traceback and nothing reported as serving."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.errors import ConfigurationError
from starterbus.opcua.endpoint import parse_endpoint
from starterbus.serve.prometheus import FleetCollector, start_metrics_server

EXE = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))


@pytest.fixture
def busy_port() -> Iterator[int]:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        yield int(held.getsockname()[1])


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("opc.tcp://0.0.0.0:4840/starterbus", ("0.0.0.0", 4840)),
        ("opc.tcp://127.0.0.1:0", ("127.0.0.1", 0)),
        ("OPC.TCP://[::1]:4841", ("::1", 4841)),
    ],
)
def test_opc_tcp_host_port_is_accepted(text: str, expected: tuple[str, int]) -> None:
    assert parse_endpoint(text) == expected


@pytest.mark.parametrize(
    "text",
    ["http://127.0.0.1:4840", "opc.tcp://127.0.0.1", "opc.tcp://:4840", "opc.tcp://h:port", "opc.tcp://h:99999",
     "127.0.0.1:4840", "opc.tcp://h:4840?x=1"],
)  # fmt: skip
def test_anything_else_is_refused(text: str) -> None:
    with pytest.raises(ConfigurationError, match=r"^OPC UA endpoint .* is not opc.tcp://HOST:PORT \(e.g. "):
        parse_endpoint(text)


@pytest.mark.parametrize("option", ["--endpoint", "--opcua"])
def test_an_http_endpoint_is_refused_before_anything_starts(
    option: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if option == "--endpoint":
        argv = ["opcua", "--demo", "--anonymous", "--pki", str(tmp_path), "--endpoint", "http://127.0.0.1:0"]
    else:
        argv = ["serve", "--demo", "--opcua", "http://127.0.0.1:0", "--opcua-anonymous", "--mqtt", "mqtt://127.0.0.1:1"]
    assert main([*argv, "--duration", "1"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert "OPC UA endpoint 'http://127.0.0.1:0' is not opc.tcp://HOST:PORT" in err


def test_opcua_on_a_busy_port_is_one_line_without_asyncuas_traceback(busy_port: int, tmp_path: Path) -> None:
    argv = [EXE, "opcua", "--demo", "--anonymous", "--pki", str(tmp_path / "pki"),
            "--endpoint", f"opc.tcp://127.0.0.1:{busy_port}", "--duration", "30"]  # fmt: skip
    result = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 1 and result.stdout == ""
    assert result.stderr == (
        f"starterbus: error: OPC UA endpoint 127.0.0.1:{busy_port} is already in use (another program listens "
        "there): choose another port\n"
    )


def test_metrics_on_a_busy_port_names_it(busy_port: int) -> None:
    with pytest.raises(ConfigurationError, match=rf"^--metrics 127.0.0.1:{busy_port} is already in use "):
        start_metrics_server(f"127.0.0.1:{busy_port}", FleetCollector())


@pytest.mark.skipif(shutil.which("mosquitto") is None, reason="needs the mosquitto broker (CI installs it)")
def test_serve_with_metrics_on_a_busy_port_says_so_and_reports_nothing_as_serving(
    busy_port: int, tmp_path: Path
) -> None:
    argv = [EXE, "serve", "--demo", "--metrics", f"127.0.0.1:{busy_port}", "--state-file", str(tmp_path / "bdseq"),
            "--duration", "30"]  # fmt: skip
    result = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 1 and result.stdout == ""  # no banner: nothing is said to serve
    assert result.stderr == (
        f"starterbus: error: --metrics 127.0.0.1:{busy_port} is already in use (another program listens there): "
        "choose another port\n"
    )
