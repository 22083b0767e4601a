"""The sans-IO edge node to the letter of Sparkplug B (issue 27): births before any DATA in every session,
bdSeq once per CONNECT sent, DCMDs refused without a timestamp, from the future or too large (before parsing),
every outcome published with a count and every refusal handed to the audit log, enum labels, Quality and
``writable`` from the fleet file. Payloads are read with Eclipse Tahu's schema (tahutils), not starterbus's."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tahutils.tahu import sparkplug_b_pb2 as tahu

from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import Command, decode_status_word
from starterbus.fleet.config import DeviceConfig, RemotePolicy
from starterbus.fleet.poller import Sample
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.session import CommandAudit, CommandRequest, EdgeSession, HistoryReady, Publish, SessionOptions

PROFILE = get_profile("jjr5000")
T0 = 1_800_000_000.0
BOOLEAN, INT32 = 11, 3
DCMD = "spBv1.0/g/DCMD/n/pump"


def session(**options: Any) -> EdgeSession:
    aliases = Aliases()
    node = node_metrics(aliases)
    remote = RemotePolicy(frozenset({Command.START}), frozenset({"ramp_time"}))
    params = ("ramp_time", "start_mode")
    devices = {
        name: device_metrics(
            DeviceConfig(name, "l1", "jjr5000", "x", unit, 1.0, ("phase_a_current",), params, remote), PROFILE, aliases
        )
        for name, unit in (("pump", 2), ("fan", 3))
    }
    return EdgeSession(SessionOptions("g", "n", **options), node, devices)


def sample(device: str, t: float, online: bool = True, amps_raw: int = 100, ramp: int | None = 10) -> Sample:
    status = decode_status_word(0x2000, PROFILE.faults) if online else None
    values = {"phase_a_current": Value.from_raw(PROFILE.point("phase_a_current"), amps_raw)}
    if ramp is not None:
        values["ramp_time"] = Value.from_raw(PROFILE.point("ramp_time"), ramp)
    return Sample(device, "l1", "jjr5000", t, online, status, values if online else {}, None, 0)


def decode(p: Any) -> Any:
    assert isinstance(p, Publish)
    payload = tahu.Payload()
    payload.ParseFromString(p.payload)
    return payload


def kinds(actions: list[Any]) -> list[str]:
    return [a.topic.split("/")[2] for a in actions if isinstance(a, Publish)]


def born(s: EdgeSession, now: float = T0) -> None:
    s.next_will()
    s.on_connected(now)
    for device in s.devices:
        s.on_sample(sample(device, now), now)
    assert s.born and all(d.born for d in s.devices.values())


def dcmd(metrics: Sequence[tuple[str, int, str, object]], ts: int | None, payload_ts: int | None = None) -> bytes:
    payload = tahu.Payload()
    if payload_ts is not None:
        payload.timestamp = payload_ts
    for name, datatype, fld, value in metrics:
        m = payload.metrics.add(name=name, datatype=datatype)
        if ts is not None:
            m.timestamp = ts
        setattr(m, fld, value)
    return bytes(payload.SerializeToString())


def outcome(s: EdgeSession, actions: list[Any], device: str = "pump") -> tuple[str, int]:
    """``Last Command`` and ``Command Count`` of the DDATA among ``actions``."""
    by_alias = {d.alias: d.name for d in s.devices[device].metrics.defs}
    (ddata,) = [a for a in actions if isinstance(a, Publish) and a.topic.endswith(f"DDATA/n/{device}")]
    values = {by_alias[m.alias]: m for m in decode(ddata).metrics}
    last, count = values["Device Control/Last Command"], values["Device Control/Command Count"]
    return last.string_value, count.long_value


def audits(actions: list[Any]) -> list[CommandAudit]:
    return [a for a in actions if isinstance(a, CommandAudit)]


def test_births_wait_for_the_first_poll_of_every_device_then_data() -> None:
    s = session()
    s.next_will()
    assert s.on_connected(T0) == []  # connected before any poll: no births yet
    assert s.on_sample(sample("pump", T0 + 0.1), T0 + 0.1) == []  # kept for the births (and as history)
    out = s.on_sample(sample("fan", T0 + 0.2, online=False), T0 + 0.2)
    assert kinds(out) == ["NBIRTH", "DBIRTH"] and isinstance(out[-1], HistoryReady)  # the fan did not answer
    nbirth = decode(out[0])
    assert {m.name: m.int_value for m in nbirth.metrics}["Node Info/Devices Online"] == 1
    assert kinds(s.on_sample(sample("fan", T0 + 1), T0 + 1)) == ["DBIRTH", "NDATA"]  # mid-session, as allowed

    # reconnected: every device known, the births at once, in order, seq 0.. then DATA
    s.on_disconnected()
    s.next_will()
    out = s.on_connected(T0 + 2)
    assert kinds(out) == ["NBIRTH", "DBIRTH", "DBIRTH"]
    assert [decode(p).seq for p in out if isinstance(p, Publish)] == [0, 1, 2]


def test_births_go_with_what_is_known_once_the_first_round_waited_long() -> None:
    s = session(first_round_wait=30.0)
    s.next_will()
    s.on_connected(T0)
    s.on_sample(sample("pump", T0 + 1), T0 + 1)
    assert s.on_tick(T0 + 29) == []
    out = s.on_tick(T0 + 30)  # the fan's line hangs: births without it
    assert kinds(out) == ["NBIRTH", "DBIRTH"] and isinstance(out[1], Publish) and out[1].topic.endswith("/pump")


def test_bdseq_advances_once_per_connect_sent() -> None:
    s = session()
    assert [decode(s.next_will()).metrics[0].long_value for _ in range(3)] == [0, 0, 0]  # no broker reached
    s.on_connected(T0)  # a CONNACK: that CONNECT was sent
    s.on_disconnected()
    assert decode(s.next_will()).metrics[0].long_value == 1
    s.connect_sent()
    s.on_disconnected()
    assert decode(s.next_will()).metrics[0].long_value == 2


def test_dcmd_without_timestamp_from_the_future_or_too_large_is_refused_audited_and_published() -> None:
    s = session(command_max_skew=5.0, command_max_bytes=200)
    born(s)
    now = T0 + 10
    ms = int(now * 1000)
    start = [("Device Control/Start", BOOLEAN, "boolean_value", True)]

    out = s.on_message(DCMD, dcmd(start, None), now)
    assert outcome(s, out) == (
        "refused: Device Control/Start: no timestamp (a DCMD must carry one, in the metric or the payload)",
        1,
    )
    assert audits(out) == [CommandAudit("pump", DCMD, "Device Control/Start=True", outcome(s, out)[0])]

    out = s.on_message(DCMD, dcmd(start, ms + 86_400_000), now)  # a day ahead
    assert "86400.0 s in the future (clock skew limit 5 s" in outcome(s, out)[0] and outcome(s, out)[1] == 2
    assert audits(out)[0].result.startswith("refused: ") and len(audits(out)) == 1
    assert isinstance(s.on_message(DCMD, dcmd(start, ms + 4_000), now)[0], CommandRequest)  # within the skew
    assert isinstance(s.on_message(DCMD, dcmd(start, None, payload_ts=ms), now)[0], CommandRequest)  # payload's

    huge = b"\xff" * 201  # not even a payload: refused on its size, never parsed
    out = s.on_message(DCMD, huge, now)
    assert outcome(s, out) == ("refused: 201 bytes, more than the limit of 200 (--command-max-bytes); not parsed", 3)
    assert audits(out) == [CommandAudit("pump", DCMD, "?", outcome(s, out)[0])]
    assert "not a Sparkplug B payload" in outcome(s, s.on_message(DCMD, b"\xff" * 10, now))[0]
    assert s.devices["pump"].refused == s.refused == 4


def test_a_repeated_identical_outcome_is_published_again_with_the_next_count() -> None:
    s = session()
    born(s)
    now = T0 + 1
    old = dcmd([("Device Control/Start", BOOLEAN, "boolean_value", True)], int(now * 1000) - 60_000)
    first = outcome(s, s.on_message(DCMD, old, now))
    second = outcome(s, s.on_message(DCMD, old, now))
    assert first[0] == second[0] and (first[1], second[1]) == (1, 2)
    third = outcome(s, s.command_done("pump", "start: ok (reached starting)", now))
    assert third == ("start: ok (reached starting)", 3)
    assert outcome(s, s.command_done("pump", "start: ok (reached starting)", now))[1] == 4


def test_ncmd_too_large_or_unknown_is_refused_in_node_data_and_audited() -> None:
    s = session(command_max_bytes=100)
    born(s)
    out = s.on_message("spBv1.0/g/NCMD/n", b"\0" * 101, T0 + 1)
    (ndata,) = [a for a in out if isinstance(a, Publish)]
    names = {d.alias: d.name for d in s.node.defs}
    values = {names[m.alias]: m for m in decode(ndata).metrics}
    assert values["Node Info/Last Command"].string_value.startswith("refused: 101 bytes")
    assert values["Node Info/Command Count"].long_value == 1 and values["Node Info/Commands Refused"].long_value == 1
    assert audits(out) == [CommandAudit(None, "spBv1.0/g/NCMD/n", "?", values["Node Info/Last Command"].string_value)]
    rebirth = dcmd([("Node Control/Rebirth", BOOLEAN, "boolean_value", True)], None)
    nbirth = decode(s.on_message("spBv1.0/g/NCMD/n", rebirth, T0 + 2)[0])
    values = {m.name: m for m in nbirth.metrics}
    assert values["Node Info/Last Command"].string_value == "rebirth: ok"
    assert values["Node Info/Command Count"].long_value == 2


def test_dcmd_for_an_offline_device_is_ignored_and_audited_without_data() -> None:
    s = session()
    born(s)
    s.on_sample(sample("fan", T0 + 1, online=False), T0 + 1)
    fan = "spBv1.0/g/DCMD/n/fan"
    out = s.on_message(fan, dcmd([("Device Control/Start", BOOLEAN, "boolean_value", True)], int(T0 * 1000)), T0 + 1)
    assert out == [CommandAudit("fan", fan, "?", "ignored: the device is offline or not born")]


def properties(metric: Any) -> dict[str, Any]:
    return dict(zip(metric.properties.keys, metric.properties.values, strict=True))


def test_enum_labels_quality_and_writable_from_the_fleet_file() -> None:
    s = session()
    s.next_will()
    s.on_connected(T0)
    s.on_sample(sample("fan", T0, online=False), T0)
    out = s.on_sample(sample("pump", T0, ramp=None), T0)  # ramp_time not read in this poll
    (dbirth,) = [decode(p) for p in out if isinstance(p, Publish) and "DBIRTH" in p.topic]
    metrics = {m.name: m for m in dbirth.metrics}

    mode = properties(metrics["Parameters/start_mode"])
    labels = {
        code: dict(zip(v.propertyset_value.keys, (x.string_value for x in v.propertyset_value.values), strict=True))
        for code, v in zip(mode["enum"].propertyset_value.keys, mode["enum"].propertyset_value.values, strict=True)
    }
    assert mode["enum"].type == 20 and labels["1"] == {"en": "voltage ramp", "zh": "电压"}
    assert properties(metrics["Status/Fault Code"])["enum"].propertyset_value.keys  # the fault table

    # writable: the profile AND the fleet file's remote table (start_mode is writable by the profile, not remotely)
    assert properties(metrics["Parameters/ramp_time"])["writable"].boolean_value is True
    assert properties(metrics["Parameters/start_mode"])["writable"].boolean_value is False
    assert properties(metrics["Device Control/Start"])["writable"].boolean_value is True
    assert properties(metrics["Device Control/Reset"])["writable"].boolean_value is False
    refused = s.on_message(DCMD, dcmd([("Parameters/start_mode", INT32, "int_value", 1)], int(T0 * 1000)), T0)
    assert "does not allow remote writes of start_mode" in outcome(s, refused)[0]

    # Quality: 192 for values of the last good poll, 0 for those it did not read; back to 192 once read again
    quality = {name: properties(m)["Quality"] for name, m in metrics.items() if "Quality" in properties(m)}
    assert quality["Measurements/phase_a_current"].int_value == 192 and quality["Status/State"].type == INT32
    assert quality["Parameters/ramp_time"].int_value == 0 and metrics["Parameters/ramp_time"].is_null
    (ddata,) = [decode(p) for p in s.on_sample(sample("pump", T0 + 1), T0 + 1) if isinstance(p, Publish)]
    alias = s.devices["pump"].metrics.by_name["Parameters/ramp_time"].alias
    (ramp,) = [m for m in ddata.metrics if m.alias == alias]
    assert properties(ramp)["Quality"].int_value == 192 and ramp.int_value == 10
    assert not any(properties(m) for m in ddata.metrics if m.alias != alias)  # good stays implicit


def test_with_a_primary_host_the_births_wait_for_its_state_and_the_first_round() -> None:
    s = session(primary_host="scada")
    s.next_will()
    s.on_connected(T0)
    s.on_sample(sample("pump", T0), T0)
    online = b'{"online": true, "timestamp": 5}'
    assert s.on_message("spBv1.0/STATE/scada", online, T0) == []  # the fan not polled yet
    assert kinds(s.on_sample(sample("fan", T0 + 1), T0 + 1))[:3] == ["NBIRTH", "DBIRTH", "DBIRTH"]
