"""serve on a plaintext broker: births, commands refused without TLS, the Will on SIGKILL, bdSeq across restarts.

The host application is paho-mqtt; payloads are decoded with Eclipse Tahu's schema, not starterbus's."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from starterbus.serve.embedded import Mosquitto

if TYPE_CHECKING:  # conftest is not importable at run time (pytest's importlib mode)
    from starterbus.tests.serve.conftest import Host, Line, Message, Serve

BOOLEAN = 11


def is_(kind: str, device: str | None = None) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind and (device is None or m.device == device)


def bdseq(m: Message) -> int:
    (value,) = [x.long_value for x in m.payload.metrics if x.name == "bdSeq"]
    return int(value)


def test_births_refused_plaintext_command_will_and_bdseq_across_restarts(
    broker: Mosquitto,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(broker.port)
    state = tmp_path / "state.json"
    args = (str(fleet_toml), "--mqtt", broker.url, "--group", "g1", "--node", "n1")
    node = serve(*args, "--state-file", str(state))

    i, nbirth = host.wait(is_("NBIRTH"))
    assert nbirth.topic == "spBv1.0/g1/NBIRTH/n1" and nbirth.payload.seq == 0 and nbirth.payload.timestamp > 0
    assert bdseq(nbirth) == 0 and json.loads(state.read_text())["bdSeq"] == 0
    rebirth = next(x for x in nbirth.payload.metrics if x.name == "Node Control/Rebirth")
    assert rebirth.datatype == BOOLEAN and rebirth.boolean_value is False and not rebirth.HasField("alias")

    births, last = {}, i
    for device in ("pump", "fan"):
        j, births[device] = host.wait(is_("DBIRTH", device), after=i)
        last = max(last, j)
    seqs = [m.payload.seq for m in host.messages[i : last + 1] if m.topic.split("/")[3] == "n1"]
    assert seqs == list(range(len(seqs)))  # NBIRTH 0, then +1 on every message (DBIRTH, NDATA)
    pump = births["pump"]
    by_name = {x.name: x for x in pump.payload.metrics}
    current = by_name["Measurements/phase_a_current"]
    props = dict(zip(current.properties.keys, current.properties.values, strict=True))
    assert props["engUnit"].string_value == "A" and props["resolution"].double_value == 0.1
    assert props["nameZh"].string_value and props["nameEn"].string_value
    assert by_name["Status/State"].string_value == "ready"
    aliases = [x.alias for b in births.values() for x in b.payload.metrics]
    assert len(aliases) == len(set(aliases)) and 0 not in aliases

    # a start on a plaintext connection: refused by default, reported, and the motor stays stopped
    host.send("DCMD", "pump", [("Device Control/Start", BOOLEAN, "boolean_value", True)])
    _, refusal = host.wait(lambda m: is_("DDATA", "pump")(m) and "Device Control/Last Command" in host.values(m))
    assert "plaintext" in str(host.values(refusal)["Device Control/Last Command"])
    assert line.starters[2].phase.value == "stopped"

    # killed: the broker publishes the Will, NDEATH with this session's bdSeq
    node.kill()
    _, ndeath = host.wait(is_("NDEATH"))
    assert bdseq(ndeath) == 0 and not ndeath.payload.HasField("seq")

    # restarted: bdSeq advanced from the state file
    after = len(host.messages)
    serve(*args, "--state-file", str(state))
    _, nbirth2 = host.wait(is_("NBIRTH"), after=after)
    assert bdseq(nbirth2) == 1 and nbirth2.payload.seq == 0
