"""serve with a paho host decoding with Eclipse Tahu's schema: NBIRTH and every DBIRTH before any DATA on the
first session and after a reconnect; DCMDs without a timestamp, dated in the future or too large refused,
each in the published outcome (``Last Command`` and its count, also when it repeats) and in the audit log."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from tahutils.tahu import sparkplug_b_pb2 as tahu

from starterbus.serve.embedded import Mosquitto
from starterbus.testing.conformance import wait_until

if TYPE_CHECKING:  # conftest is not importable at run time (pytest's importlib mode)
    from starterbus.tests.serve.conftest import Host, Line, Message, Proxy, Serve

BOOLEAN = 11
LAST, COUNT = "Device Control/Last Command", "Device Control/Command Count"
TOPIC = "spBv1.0/g1/DCMD/n1/pump"


def is_(kind: str, device: str | None = None) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind and (device is None or m.device == device)


def births_first(host: Host, after: int) -> int:
    """The next session's NBIRTH, then the DBIRTHs of pump and fan with no NDATA/DDATA in between; its index."""
    start, _ = host.wait(is_("NBIRTH"), after=after)
    last = max(host.wait(is_("DBIRTH", d), after=start)[0] for d in ("pump", "fan"))
    between = [(m.kind, m.device) for m in host.messages[start : last + 1]]
    assert not [k for k, _ in between if k in ("NDATA", "DDATA")], between
    assert [m.payload.seq for m in host.messages[start : last + 1]] == list(range(len(between)))
    return last


def raw_dcmd(host: Host, ts: int | None, *, pad: int = 0) -> None:
    """Start on the pump, timestamped (payload and metric) or not; ``pad``: an extra string metric that large."""
    payload = tahu.Payload()
    if ts is not None:
        payload.timestamp = ts
    metric = payload.metrics.add(name="Device Control/Start", datatype=BOOLEAN, boolean_value=True)
    if ts is not None:
        metric.timestamp = ts
    if pad:
        payload.metrics.add(name="padding", datatype=12, string_value="x" * pad)
    host.client.publish(TOPIC, payload.SerializeToString(), qos=0).wait_for_publish(5)


def now() -> int:
    return int(time.time() * 1000)


def outcome(host: Host, after: int, text: str) -> tuple[int, str, int]:
    i, m = host.wait(lambda m: is_("DDATA", "pump")(m) and text in str(host.values(m).get(LAST, "")), after=after)
    values = host.values(m)
    return i, str(values[LAST]), int(values[COUNT])  # type: ignore[call-overload]


def test_births_before_data_in_every_session_and_refused_dcmds_published_and_audited(
    broker: Mosquitto,
    proxy: Proxy,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    _audit_log_in_tmp: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(broker.port)
    serve(
        str(fleet_toml),
        "--mqtt", f"mqtt://127.0.0.1:{proxy.port}", "--group", "g1", "--node", "n1",
        "--state-file", str(tmp_path / "state.json"), "--allow-plaintext-commands",
        "--command-max-bytes", "4096", "--reconnect-delay", "0.2",
    )  # fmt: skip
    last = births_first(host, 0)

    raw_dcmd(host, None)
    i, text, count = outcome(host, last, "no timestamp")
    assert text.startswith("refused: Device Control/Start: no timestamp") and count == 1
    raw_dcmd(host, now() + 86_400_000)
    i, text, count = outcome(host, i + 1, "in the future")
    assert "clock skew limit 5 s" in text and count == 2
    raw_dcmd(host, now(), pad=5000)
    i, text, count = outcome(host, i + 1, "--command-max-bytes")
    assert "more than the limit of 4096" in text and count == 3
    raw_dcmd(host, now(), pad=5000)  # the same refusal again: the same text, published with the next count
    i, again, count = outcome(host, i + 1, "--command-max-bytes")
    assert (again, count) == (text, 4)
    assert line.starters[2].phase.value == "stopped"  # nothing ran

    def refusals() -> list[dict[str, object]]:
        if not _audit_log_in_tmp.exists():
            return []
        lines = _audit_log_in_tmp.read_text(encoding="utf-8").splitlines()
        return [r for r in map(json.loads, lines) if str(r.get("result", "")).startswith("refused")]

    assert wait_until(lambda: len(refusals()) >= 4, timeout=10), refusals()
    records = refusals()
    assert [r["name"] for r in records] == ["pump"] * 4
    assert {r["topic"] for r in records} == {TOPIC} and {r["action"] for r in records} == {"dcmd"}
    assert all(str(r["actor"]).startswith("mqtt:") and r["model"] == "jjr5000" for r in records)
    reasons = [str(r["result"]) for r in records]
    assert "no timestamp" in reasons[0] and "in the future" in reasons[1] and "4096" in reasons[2] == reasons[3]
    assert records[0]["asked"] == "Device Control/Start=True" and records[2]["asked"] == "?"

    # the broker away and back: a new session, again NBIRTH and every DBIRTH before any DATA
    after = len(host.messages)
    proxy.cut()
    proxy.resume()
    births_first(host, after)
