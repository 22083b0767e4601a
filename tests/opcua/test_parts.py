"""The OPC UA server's pure parts: UNECE unit ids, password hashes and the users file, refusal codes, DataValues."""

from __future__ import annotations

import io
import os
from pathlib import Path

import pytest
from asyncua import ua

from starterbus.aio import RemoteNotAllowed
from starterbus.core.errors import ConfigurationError, StateRuleError, TimeoutError, ValidationError
from starterbus.core.guarded import CommandNotReached
from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.fleet.config import DeviceConfig
from starterbus.fleet.poller import Sample
from starterbus.opcua.address_space import STATES, DeviceNodes, PointNode
from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.refusals import status_code
from starterbus.opcua.units import eu_information, unit_id
from starterbus.opcua.users import Role, dump_users, hash_password, load_users, parse_users, verify_password
from starterbus.opcua.values import sample_updates

# OPC 10000-8 / UNECE Rec. 20 codes: docs/opcua.md#engineering-units
UNECE_VECTORS = [
    ("AMP", 4279632),
    ("SEC", 5457219),
    ("P1", 20529),
    ("VLT", 5655636),
    ("HTZ", 4740186),
    ("CEL", 4408652),
]


@pytest.mark.parametrize(("code", "expected"), UNECE_VECTORS)
def test_unece_unit_ids(code: str, expected: int) -> None:
    assert unit_id(code) == expected


def test_every_profile_unit_has_eu_information() -> None:
    for model in ("jjr5000", "ssd1", "jjr8000"):
        for point in get_profile(model).points.values():
            info = eu_information(point.unit)
            assert (info is None) == (point.unit == ""), point.key
            if info is not None:
                assert info.DisplayName.Text == point.unit
    assert eu_information("A").UnitId == 4279632  # type: ignore[union-attr]
    assert eu_information("x In").UnitId == -1  # type: ignore[union-attr]


def test_password_hashes_verify_and_reject() -> None:
    encoded = hash_password("s3cret-pass", iterations=1000)
    assert encoded.startswith("pbkdf2-sha256$1000$") and "s3cret" not in encoded
    assert verify_password("s3cret-pass", encoded)
    assert not verify_password("s3cret-pasS", encoded)
    assert not verify_password("s3cret-pass", "md5$1$x$y")
    assert not verify_password("s3cret-pass", "garbage")


def test_users_file_round_trip_and_errors(tmp_path: Path) -> None:
    users = parse_users({"users": {"op": {"role": "operator", "password": hash_password("x" * 8, iterations=10)}}}, "u")
    path = tmp_path / "users.toml"
    path.write_text(dump_users(users), encoding="utf-8")
    assert load_users(path) == users
    with pytest.raises(ConfigurationError, match=r"users\.op\.password: not a pbkdf2-sha256 hash"):
        parse_users({"users": {"op": {"role": "operator", "password": "plain"}}}, "u.toml")
    with pytest.raises(ConfigurationError, match=r"users\.op\.role: 'admin' is not one of read-only, operator"):
        parse_users({"users": {"op": {"role": "admin", "password": users["op"].password_hash}}}, "u.toml")


def test_refusals_map_to_status_codes() -> None:
    assert status_code(RemoteNotAllowed("x"), write=True) == ua.StatusCodes.BadNotWritable
    assert status_code(RemoteNotAllowed("x"), write=False) == ua.StatusCodes.BadNotExecutable
    assert status_code(ValidationError("x"), write=True) == ua.StatusCodes.BadOutOfRange
    assert status_code(StateRuleError("x"), write=True) == ua.StatusCodes.BadInvalidState
    assert status_code(CommandNotReached("x", []), write=False) == ua.StatusCodes.BadInvalidState
    assert status_code(TimeoutError("x"), write=False) == ua.StatusCodes.BadTimeout


def _device() -> DeviceNodes:
    profile = get_profile("jjr5000")
    config = DeviceConfig("c", "l1", "jjr5000", "modbus-rtu:///dev/null?unit=1", 1, 1.0, ("phase_a_current",), ())
    status = {k: ua.NodeId(f"c.{k}", 2) for k in (
        "State", "Fault", "FaultCode", "FaultText", "Ready", "BusControl", "Online", "LastError", "DeviceHealth",
    )}  # fmt: skip
    point = PointNode(profile.point("phase_a_current"), ua.NodeId("c.phase_a_current", 2))
    mode = PointNode(profile.point("start_mode"), ua.NodeId("c.start_mode", 2), ua.NodeId("c.start_mode.text", 2))
    return DeviceNodes(config, profile, ua.NodeId("c", 2), status, {"phase_a_current": point, "start_mode": mode})


def _sample(online: bool, **kwargs: object) -> Sample:
    base: dict[str, object] = dict(
        device="c", bus="l1", model="jjr5000", time=1_700_000_000.5, online=online, status=None, values={},
        error=None, errors=0,
    )  # fmt: skip
    base.update(kwargs)
    return Sample(**base)  # type: ignore[arg-type]


def test_offline_sample_sets_bad_codes_not_stale_values() -> None:
    device = _device()
    updates = dict(sample_updates(device, _sample(False, error="no answer")))
    assert updates[device.status["Online"]].Value.Value is False
    assert updates[device.status["LastError"]].Value.Value == "no answer"
    for key in ("State", "FaultCode", "Ready"):
        assert updates[device.status[key]].StatusCode.value == ua.StatusCodes.BadCommunicationError
    current = updates[device.points["phase_a_current"].node]
    assert current.StatusCode.value == ua.StatusCodes.BadCommunicationError and current.Value.Value is None
    assert current.SourceTimestamp.timestamp() == 1_700_000_000.5
    label = updates[device.points["start_mode"].value_as_text]
    assert label.StatusCode.value == ua.StatusCodes.BadCommunicationError


def test_online_sample_sets_values_fault_text_and_source_time() -> None:
    device = _device()
    profile = device.profile
    status = decode_status_word(0x8000 | 6, profile.faults)  # fault 6: motor overload
    value = Value.from_raw(profile.point("phase_a_current"), 963)
    updates = dict(sample_updates(device, _sample(True, status=status, values={"phase_a_current": value})))
    assert STATES[updates[device.status["State"]].Value.Value].value == "fault"
    assert updates[device.status["FaultCode"]].Value.Value == 6
    assert updates[device.status["FaultText"]].Value.Value.Text == "motor overload"
    assert updates[device.status["DeviceHealth"]].Value.Value == 1  # FAILURE
    assert updates[device.points["phase_a_current"].node].Value.Value == 96.3
    zh = dict(sample_updates(device, _sample(True, status=status), locale="zh"))
    assert zh[device.status["FaultText"]].Value.Value.Text == "电机过载"


def test_certificate_generated_once_with_a_private_key_file(tmp_path: Path) -> None:
    cert, key = ensure_certificate(tmp_path / "pki", "urn:test:server")
    assert os.stat(key).st_mode & 0o777 == 0o600
    assert ensure_certificate(tmp_path / "pki", "urn:test:server") == (cert, key)
    der = cert.read_bytes()
    assert ensure_certificate(tmp_path / "pki", "urn:test:server")[0].read_bytes() == der
    with pytest.raises(ConfigurationError, match="is not the server's application URI 'urn:other'"):
        ensure_certificate(tmp_path / "pki", "urn:other")


def test_opcua_user_command_stores_only_a_hash(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from starterbus.cli.main import main

    path = tmp_path / "users.toml"
    monkeypatch.setattr("sys.stdin", io.StringIO("correct horse\n"))
    assert main(["opcua-user", str(path), "alice", "--role", "operator"]) == 0
    text = path.read_text(encoding="utf-8")
    assert "correct horse" not in text
    entry = load_users(path)["alice"]
    assert entry.role is Role.OPERATOR and verify_password("correct horse", entry.password_hash)
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert main(["opcua-user", str(path), "bob"]) == 1
    assert "at least 8 characters" in capsys.readouterr().err
    assert main(["opcua", "--demo", "--pki", str(tmp_path / "pki")]) == 1
    assert "nobody could connect" in capsys.readouterr().err
