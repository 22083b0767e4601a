"""`starterbus models | params | transports` with --json, as the foundation issue checks them."""

from __future__ import annotations

import json

import pytest

from starterbus.cli.main import main


def run_json(capsys: pytest.CaptureFixture[str], *args: str) -> object:
    assert main([*args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_models(capsys: pytest.CaptureFixture[str]) -> None:
    models = run_json(capsys, "models")
    assert isinstance(models, list)
    names = {m["name"]: m for m in models}
    assert {"jjr5000", "ssd1", "jjr8000"} <= set(names)
    assert all(names[n]["error"] is None for n in ("jjr5000", "ssd1", "jjr8000"))
    # the installed transports that serve each model: every one that speaks one of its address spaces
    assert set(names["jjr8000"]["transports"]) == {"modbus-rtu", "modbus-tcp", "profibus-pkw", "devicenet"}
    assert names["ssd1"]["transports"] == ["modbus-rtu", "modbus-tcp"]
    assert names["ssd1"]["address_spaces"] == ["modbus"]


def test_transports(capsys: pytest.CaptureFixture[str]) -> None:
    listed = run_json(capsys, "transports")
    assert isinstance(listed, list)
    names = {t["name"]: t for t in listed}
    assert {"modbus-rtu", "profibus-pkw", "devicenet"} <= set(names)
    for name in ("modbus-rtu", "profibus-pkw", "devicenet"):
        assert names[name]["error"] is None
        assert names[name]["source"].startswith("starterbus ")
        assert "status" in names[name]["capabilities"]


def _point(doc: object, address: str) -> dict[str, object]:
    assert isinstance(doc, dict)
    for point in doc["parameters"] + doc["measurements"]:
        if point["address"].lower() == address.lower():
            return dict(point)
    raise AssertionError(f"{address} missing")


def test_params_jjr5000_current_limit(capsys: pytest.CaptureFixture[str]) -> None:
    limit = _point(run_json(capsys, "params", "jjr5000"), "0x0103")
    assert (limit["key"], limit["min"], limit["max"], limit["unit"]) == ("current_limit", 150, 500, "%")
    assert limit["name_zh"]
    assert limit["addresses"] == {"modbus": "0x0103", "profibus-pkw": "0x0003"}


def test_params_jjr8000_p7_scaling(capsys: pytest.CaptureFixture[str]) -> None:
    p7 = _point(run_json(capsys, "params", "jjr8000"), "p7")
    assert p7["scale"] == pytest.approx(0.01)
    assert (p7["raw_min"], p7["raw_max"]) == (150, 500)
    assert p7["min"] == pytest.approx(1.5)
    assert p7["max"] == pytest.approx(5.0)
    addresses = p7["addresses"]
    assert isinstance(addresses, dict)
    assert addresses["modbus"] == "0x0107"
    assert addresses["profibus-pkw"] == "0x0007"


def test_params_ssd1_parameter_modify(capsys: pytest.CaptureFixture[str]) -> None:
    pm = _point(run_json(capsys, "params", "ssd1"), "0x0125")
    assert pm["key"] == "parameter_modify"
    assert pm["enum"] is not None


def test_params_human_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params", "jjr8000"]) == 0
    out = capsys.readouterr().out
    assert "p7" in out and "1.5..5.0" in out


def test_unknown_model_is_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params", "jjr9999"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "jjr9999" in err


def test_params_table_stays_readable(capsys: pytest.CaptureFixture[str]) -> None:
    """Long lists of choices are cut at a choice with the count of the rest (the whole list is in --json)."""
    assert main(["params", "jjr8000"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line[:1] in "pm" and "  " in line]
    assert rows and max(len(line) for line in rows) < 260
    assert any("see --json)" in line for line in rows)
