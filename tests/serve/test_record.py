"""serve --record: the history written beside the Sparkplug node (the same recorder as poll --record), in the
bus threads, so a device's state change seen on the broker is also a sample and an event of the history; a
file that is not a history is refused before the broker is reached."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from starterbus.serve.embedded import Mosquitto

if TYPE_CHECKING:  # conftest is not importable at run time (pytest's importlib mode)
    from starterbus.tests.serve.conftest import Host, Line, Message, Serve


def state_is(device: str, state: str, host: Host) -> Callable[[Message], bool]:
    def pred(m: Message) -> bool:
        return m.kind in ("DBIRTH", "DDATA") and m.device == device and host.values(m).get("Status/State") == state

    return pred


def test_serve_records_samples_and_events(
    broker: Mosquitto,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(broker.port)
    db = tmp_path / "history.db"
    node = serve(
        str(fleet_toml), "--mqtt", broker.url, "--group", "g1", "--node", "n1",
        "--state-file", str(tmp_path / "state.json"), "--record", str(db),
    )  # fmt: skip
    i, _ = host.wait(state_is("pump", "ready", host))
    line.starters[2].start()
    host.wait(state_is("pump", "running", host), after=i)
    node.process.terminate()  # a clean stop writes what waits
    assert node.process.wait(15) == 0, node.output()

    with sqlite3.connect(db) as conn:
        devices = {d for (d,) in conn.execute("SELECT DISTINCT device FROM samples WHERE online = 1")}
        changes = [t for (t,) in conn.execute("SELECT text FROM events WHERE device = 'pump' AND kind = 'state'")]
    assert devices == {"pump", "fan"}
    assert any(t.endswith("-> running") for t in changes), changes


def test_serve_refuses_a_record_file_that_is_not_a_history(tmp_path: Path, fleet_toml: Path) -> None:
    not_db = tmp_path / "fleet-copy.toml"
    not_db.write_text(fleet_toml.read_text(encoding="utf-8"), encoding="utf-8")
    before = not_db.read_bytes()
    done = subprocess.run(
        [sys.executable, "-m", "starterbus.cli.main", "serve", str(fleet_toml), "--mqtt", "mqtt://127.0.0.1:9",
         "--state-file", str(tmp_path / "state.json"), "--record", str(not_db)],
        check=False, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 1, done
    assert str(not_db) in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not_db.read_bytes() == before
