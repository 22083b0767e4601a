"""One time form in every JSON the CLI prints and every file it writes: ISO 8601, UTC, milliseconds, the zone
(``2026-11-26T14:33:11.123+00:00``), from one helper (:func:`starterbus.core.timestamps.iso_time`)."""

from __future__ import annotations

import csv
import json
import re
import sys
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.audit import AuditLog
from starterbus.core.status import Status
from starterbus.core.timestamps import iso_time, parse_iso_time
from starterbus.fleet.output import CsvLog
from starterbus.fleet.sample import Sample
from starterbus.ops.record import write_csv
from starterbus.ops.recorder import _audit_time
from starterbus.ops.recording import Point, Recording

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ISO = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}\+00:00")
SIM = "profibus-pkw+sim://?ppo=1"  # an in-process simulated starter with a parameter channel
EPOCH = 1795703591.123  # 2026-11-26T14:33:11.123+00:00


def test_the_form() -> None:
    assert iso_time(EPOCH) == "2026-11-26T14:33:11.123+00:00"
    assert ISO.fullmatch(iso_time())
    assert parse_iso_time(iso_time(EPOCH)) == pytest.approx(EPOCH)


@pytest.mark.parametrize(
    "text", ["2026-11-26T14:33:11.123Z", "2026-11-26T15:33:11.123+0100", "2026-11-26T22:33:11.123+08:00"]
)
def test_the_forms_earlier_versions_wrote_still_read(text: str) -> None:
    assert parse_iso_time(text) == pytest.approx(EPOCH)
    assert _audit_time({"time": text}) == pytest.approx(EPOCH)  # audit logs written before keep their times


def test_poll_json_and_status_json() -> None:
    sample = Sample(device="d", bus="b", model="jjr5000", time=EPOCH, online=False, status=None, values={},
                    error="timeout", errors=1)  # fmt: skip
    assert sample.as_json()["time"] == "2026-11-26T14:33:11.123+00:00"
    status = Status(fault=False, fault_code=None, fault_text=None, starting=False, running=True, stopping=False,
                    timestamp=EPOCH)  # fmt: skip
    assert status.as_json()["timestamp"] == "2026-11-26T14:33:11.123+00:00"


@pytest.mark.parametrize(
    ("argv", "find"),
    [
        (["status", SIM, "--model", "jjr5000", "--json"], lambda doc: doc["status"]["timestamp"]),
        (["watch", SIM, "--model", "jjr5000", "--json", "--once"], lambda doc: doc["time"]),
        (["watch", SIM, "--model", "jjr5000", "--json", "--once"], lambda doc: doc["status"]["timestamp"]),
    ],
    ids=["status", "watch", "watch-status"],
)
def test_commands_print_it(argv: list[str], find: object, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 0
    doc, _ = json.JSONDecoder().raw_decode(capsys.readouterr().out)  # a document, or the first JSON line
    assert callable(find) and ISO.fullmatch(find(doc))


def test_files_carry_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    backup = tmp_path / "b.toml"
    assert main(["backup", SIM, "--model", "jjr5000", "-o", str(backup)]) == 0
    assert ISO.fullmatch(tomllib.loads(backup.read_text(encoding="utf-8"))["taken"])

    entry = AuditLog(tmp_path / "audit.jsonl").append(action="test")
    assert ISO.fullmatch(str(entry["time"]))

    rec = Recording("d", "jjr5000", EPOCH, [Point(0.0, EPOCH, "starting", None, {"a": 1.0})])
    write_csv(rec, tmp_path / "start.csv")
    with (tmp_path / "start.csv").open(encoding="utf-8", newline="") as f:
        assert next(csv.DictReader(f))["time"] == "2026-11-26T14:33:11.123+00:00"

    log = CsvLog(tmp_path / "poll.csv")
    log(Sample(device="d", bus="b", model="jjr5000", time=EPOCH, online=False, status=None, values={},
               error="timeout", errors=1))  # fmt: skip
    log.close()
    with (tmp_path / "poll.csv").open(encoding="utf-8", newline="") as f:
        assert next(csv.DictReader(f))["time"] == "2026-11-26T14:33:11.123+00:00"
