"""The node's persistent state: the last bdSeq, so that it advances across restarts (SPARKPLUG.md pitfalls)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from starterbus.core.errors import ConfigurationError


def default_state_file(group: str, node: str) -> Path:
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "starterbus" / f"serve-{group}-{node}.json"


def load_bdseq(path: Path) -> int:
    """The last bdSeq used, or -1 when there is no state yet (the first CONNECT then uses 0)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return -1
    except (OSError, ValueError) as exc:
        raise ConfigurationError(f"state file {path}: {exc}") from None
    value = data.get("bdSeq") if isinstance(data, dict) else None
    if not isinstance(value, int) or not 0 <= value <= 255:
        raise ConfigurationError(f"state file {path}: bdSeq must be an integer 0..255, not {value!r}")
    return value


def save_bdseq(path: Path, bdseq: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"bdSeq": bdseq}) + "\n", encoding="utf-8")
    os.replace(tmp, path)
