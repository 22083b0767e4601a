"""Broker URLs, credentials (environment or file, never the URL) and the bdSeq state file."""

from __future__ import annotations

from pathlib import Path

import pytest

from starterbus.core.errors import ConfigurationError
from starterbus.serve.broker import BrokerOptions, load_credentials, parse_broker_url
from starterbus.serve.state import load_bdseq, save_bdseq


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("mqtt://broker", ("broker", 1883, False)),
        ("mqtts://broker", ("broker", 8883, True)),
        ("mqtt://10.0.0.5:1884", ("10.0.0.5", 1884, False)),
    ],
)
def test_broker_urls(url: str, expected: tuple[str, int, bool]) -> None:
    assert parse_broker_url(url) == expected


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("tcp://broker", "expected mqtt://"),
        ("mqtt://", "expected mqtt://"),
        ("mqtt://user:secret@broker", "no credentials in the URL"),
        ("mqtt://broker:99999", "bad port"),
    ],
)
def test_bad_broker_urls(url: str, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message) as info:
        parse_broker_url(url)
    assert "secret" not in str(info.value)


def test_credentials_from_file_then_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "creds"
    path.write_text("edge\npa ss\n", encoding="utf-8")
    assert load_credentials(str(path)) == ("edge", "pa ss")
    monkeypatch.setenv("STARTERBUS_MQTT_USERNAME", "envuser")
    monkeypatch.setenv("STARTERBUS_MQTT_PASSWORD", "envpass")
    assert load_credentials(None) == ("envuser", "envpass")
    path.write_text("\n", encoding="utf-8")
    with pytest.raises(ConfigurationError, match="first line must be the user name"):
        load_credentials(str(path))
    with pytest.raises(ConfigurationError, match="credentials file"):
        load_credentials(str(tmp_path / "missing"))


def test_password_is_not_shown() -> None:
    options = BrokerOptions("b", 8883, True, username="edge", password="hunter2")
    assert "hunter2" not in repr(options) and "hunter2" not in options.describe()


def test_state_file(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "state.json"
    assert load_bdseq(path) == -1
    save_bdseq(path, 7)
    assert load_bdseq(path) == 7
    path.write_text('{"bdSeq": 300}', encoding="utf-8")
    with pytest.raises(ConfigurationError, match=r"state.json: bdSeq must be an integer 0\.\.255"):
        load_bdseq(path)
    path.write_text("not json", encoding="utf-8")
    with pytest.raises(ConfigurationError, match="state file"):
        load_bdseq(path)


def test_unreadable_tls_files_end_serve_with_one_line(
    fleet_toml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from starterbus.cli.main import main

    missing = str(tmp_path / "no-ca.pem")
    args = ["serve", str(fleet_toml), "--mqtt", "mqtts://127.0.0.1:1", "--ca-file", missing]
    assert main([*args, "--state-file", str(tmp_path / "s.json"), "--duration", "30"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"starterbus: error: TLS setup ({missing}): [Errno 2] No such file or directory"


def test_deadband_options() -> None:
    from starterbus.cli.serve_edge import parse_deadbands

    assert parse_deadbands([]) == (1.0, {})
    assert parse_deadbands(["2", "phase_a_current=5", "ramp_time=0"]) == (
        2.0,
        {"phase_a_current": 5.0, "ramp_time": 0.0},
    )
    for bad in ("x", "-1", "k=", "k=nan"):
        with pytest.raises(ConfigurationError, match="expected STEPS or KEY=STEPS"):
            parse_deadbands([bad])
