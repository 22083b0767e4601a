"""Audit records as history events: a write, a command, and attempts refused before anything was sent (not
confirmed, a refused DCMD), each with words a reader understands and the record (its actor) kept."""

from __future__ import annotations

from pathlib import Path

import pytest

from starterbus.core.audit import AuditLog
from starterbus.ops.history import HistoryStore
from starterbus.ops.recorder import HistoryRecorder

URL = "modbus-tcp://127.0.0.1:5020?unit=1"
BASE = {"device": URL, "model": "jjr5000", "actor": "cli:olga"}


@pytest.mark.parametrize(
    ("record", "kind", "text"),
    [
        (
            {"action": "write", "key": "ramp_time", "old": "10 s", "new": "12 s", "read_back": "12 s", "result": "ok"},
            "write",
            "ramp_time: 10 s -> 12 s: ok",
        ),
        (
            {"action": "command", "command": "stop", "before": "running", "reached": "stopping", "result": "ok"},
            "command",
            "stop: running -> stopping: ok",
        ),
        (
            {"action": "stop", "what": "Send stop to JJR5000 at ... unit 1?", "result": "not confirmed"},
            "command",
            "Send stop to JJR5000 at ... unit 1: not confirmed",
        ),
        (
            {"action": "write", "what": "Write ramp_time = 12 s?", "result": "not confirmed"},
            "write",
            "Write ramp_time = 12 s: not confirmed",
        ),
        (
            {"action": "dcmd", "asked": "Device Control/Start=True", "result": "refused: not allowed"},
            "dcmd",
            "Device Control/Start=True: refused: not allowed",
        ),
    ],
)
def test_an_audit_record_is_an_event_in_words(tmp_path: Path, record: dict[str, str], kind: str, text: str) -> None:
    audit = AuditLog(tmp_path / "audit.jsonl")
    with HistoryRecorder(tmp_path / "h.db", audit=audit, devices={URL: "conveyor"}) as recorder:
        audit.append(**BASE, **record)
        recorder.follow_audit()
    with HistoryStore(tmp_path / "h.db", create=False) as store:
        (event,) = store.events(device="conveyor")
    assert (event["kind"], event["text"]) == (kind, text)
    assert event["detail"]["actor"] == "cli:olga"
