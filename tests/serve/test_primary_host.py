"""--primary-host: births only while the host's STATE (retained, JSON) says online; offline -> NDEATH, a new
connection (new bdSeq), and births again once the host is back."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from starterbus.serve.embedded import Mosquitto

if TYPE_CHECKING:
    from starterbus.tests.serve.conftest import Host, Message, Serve


def is_(kind: str) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind


def bdseq(m: Message) -> int:
    return int(next(x.long_value for x in m.payload.metrics if x.name == "bdSeq"))


def test_births_follow_the_primary_host_state(
    broker: Mosquitto, fleet_toml: Path, tmp_path: Path, host_factory: Callable[..., Host], serve: Callable[..., Serve]
) -> None:
    host = host_factory(broker.port)

    def state(online: bool) -> None:
        payload = json.dumps({"online": online, "timestamp": int(time.time() * 1000)})
        host.client.publish("spBv1.0/STATE/scada", payload, qos=1, retain=True).wait_for_publish(5)

    state(True)  # retained: serve reads it as soon as it subscribes
    serve(
        str(fleet_toml), "--mqtt", broker.url, "--group", "g1", "--node", "n1", "--primary-host", "scada",
        "--state-file", str(tmp_path / "s.json"), "--reconnect-delay", "0.2",
    )  # fmt: skip
    i, first = host.wait(is_("NBIRTH"))

    state(False)
    j, death = host.wait(is_("NDEATH"), after=i)
    assert bdseq(death) == bdseq(first)  # published by serve itself, then a clean DISCONNECT

    state(True)
    k, _ = host.wait(lambda m: "/STATE/" in m.topic and m.raw != b"" and json.loads(m.raw)["online"], after=j)
    n, second = host.wait(is_("NBIRTH"), after=j)
    assert n > k  # no birth while the host was offline: only after it came back
    assert bdseq(second) > bdseq(first) and second.payload.seq == 0
    host.client.publish("spBv1.0/STATE/scada", b"", qos=1, retain=True).wait_for_publish(5)  # clear the retained
