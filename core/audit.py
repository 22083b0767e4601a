"""The audit trail: every write and command, appended as one JSON line (time, device, what, result)."""

from __future__ import annotations

import getpass
import json
import os
import threading
from pathlib import Path

from starterbus.core.timestamps import iso_time

ENV_VAR = "STARTERBUS_AUDIT_LOG"


def default_audit_path() -> Path:
    """``$STARTERBUS_AUDIT_LOG``, else ``$XDG_STATE_HOME/starterbus/audit.jsonl`` (``~/.local/state/...``)."""
    explicit = os.environ.get(ENV_VAR)
    if explicit:
        return Path(explicit)
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "starterbus" / "audit.jsonl"


class AuditLog:
    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else default_audit_path()
        self._lock = threading.Lock()

    def append(self, **record: object) -> dict[str, object]:
        entry: dict[str, object] = {
            "time": iso_time(),
            "user": _user(),
            **record,
        }
        line = json.dumps(entry, ensure_ascii=False, default=str)
        with self._lock:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open("a", encoding="utf-8") as f:
                f.write(line + "\n")
        return entry

    def read(self) -> list[dict[str, object]]:
        if not self.path.exists():
            return []
        return [json.loads(line) for line in self.path.read_text(encoding="utf-8").splitlines() if line.strip()]


def _user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return "?"
