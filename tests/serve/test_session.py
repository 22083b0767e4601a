"""The sans-IO edge node, driven by hand: samples, connection events, commands and times in, messages out.

Every payload is read back with Eclipse Tahu's schema (tahutils ships its generated module), not starterbus's."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import pytest
from tahutils.tahu import sparkplug_b_pb2 as tahu

from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import Command, decode_status_word
from starterbus.fleet.config import DeviceConfig, RemotePolicy
from starterbus.fleet.poller import Sample
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.session import (
    CommandAudit,
    CommandRequest,
    EdgeSession,
    HistoryReady,
    Publish,
    Reconnect,
    SessionOptions,
)

PROFILE = get_profile("jjr5000")
T0 = 1_800_000_000.0


def session(**options: Any) -> EdgeSession:
    aliases = Aliases()
    node = node_metrics(aliases)
    remote = RemotePolicy(frozenset({Command.START}), frozenset({"ramp_time"}))
    config = DeviceConfig("pump", "l1", "jjr5000", "x", 2, 1.0, ("phase_a_current",), ("ramp_time",), remote)
    devices = {"pump": device_metrics(config, PROFILE, aliases, options.pop("deadband", 1.0))}
    return EdgeSession(SessionOptions("g", "n", **options), node, devices, bdseq=options.pop("bdseq", -1))


def sample(t: float, amps_raw: int = 100, online: bool = True, word: int = 0x2000) -> Sample:
    point = PROFILE.point("phase_a_current")
    status = decode_status_word(word, PROFILE.faults) if online else None
    values = {"phase_a_current": Value.from_raw(point, amps_raw)} if online else {}
    return Sample("pump", "l1", "jjr5000", t, online, status, values, None, 0)


def decode(p: Publish) -> Any:
    payload = tahu.Payload()
    payload.ParseFromString(p.payload)
    return payload


def publishes(actions: list[Any]) -> list[Publish]:
    return [a for a in actions if isinstance(a, Publish)]


def kinds(actions: list[Any]) -> list[str]:
    return [p.topic.split("/")[2] for p in publishes(actions)]


def connect(s: EdgeSession, now: float) -> list[Any]:
    s.next_will()
    return s.on_connected(now)


def test_will_carries_the_next_bdseq_and_wraps() -> None:
    s = session()
    will = s.next_will()
    assert (will.topic, will.qos) == ("spBv1.0/g/NDEATH/n", 1)
    (metric,) = decode(will).metrics
    assert (metric.name, metric.datatype, metric.long_value) == ("bdSeq", 4, 0) and not decode(will).HasField("seq")
    assert decode(s.next_will()).metrics[0].long_value == 0  # that CONNECT was never sent: the same bdSeq
    s.connect_sent()
    assert decode(s.next_will()).metrics[0].long_value == 1
    s.connect_sent()
    s.bdseq = 255
    assert decode(s.next_will()).metrics[0].long_value == 0


def test_births_seq_and_report_by_exception_with_deadband() -> None:
    s = session()
    s.on_sample(sample(T0), T0)  # polled before the broker is there
    out = connect(s, T0 + 1)
    assert kinds(out)[:2] == ["NBIRTH", "DBIRTH"]
    nbirth, dbirth = (decode(p) for p in publishes(out)[:2])
    assert (nbirth.seq, dbirth.seq) == (0, 1)
    current = next(m for m in dbirth.metrics if m.name == "Measurements/phase_a_current")
    assert current.double_value == pytest.approx(10.0) and current.timestamp == int(T0 * 1000)
    assert isinstance(out[-1], HistoryReady)
    (history,), _ids = s.history(T0 + 1)
    assert decode(history).metrics[0].is_historical and decode(history).seq == 2  # sampled while disconnected
    assert s.on_sample(sample(T0 + 2), T0 + 2) == []  # nothing changed
    (ddata,) = publishes(s.on_sample(sample(T0 + 3, amps_raw=101), T0 + 3))
    data = decode(ddata)
    assert [(m.alias, round(m.double_value, 1)) for m in data.metrics] == [(current.alias, 10.1)]
    assert not data.metrics[0].name and not data.metrics[0].HasField("datatype")  # DATA: alias only


def test_deadband_in_resolution_steps() -> None:
    s = session(deadband=5.0)
    s.on_sample(sample(T0), T0)
    connect(s, T0)
    assert s.on_sample(sample(T0 + 1, amps_raw=104), T0 + 1) == []  # 0.4 A < 5 x 0.1 A
    assert kinds(s.on_sample(sample(T0 + 2, amps_raw=105), T0 + 2)) == ["DDATA"]


def test_seq_wraps_after_255() -> None:
    s = session(deadband=0.0)
    s.on_sample(sample(T0), T0)
    connect(s, T0)
    seqs = [decode(p).seq for i in range(300) for p in publishes(s.on_sample(sample(T0 + i, 200 + i), T0 + i))]
    assert seqs[:3] == [2, 3, 4] and 255 in seqs and seqs[seqs.index(255) + 1] == 0


def test_ddeath_then_dbirth_and_no_data_in_between() -> None:
    s = session()
    s.on_sample(sample(T0), T0)
    connect(s, T0)
    assert kinds(s.on_sample(sample(T0 + 1, online=False), T0 + 1)) == ["DDEATH", "NDATA"]
    assert s.on_sample(sample(T0 + 2, online=False), T0 + 2) == []
    assert kinds(s.on_sample(sample(T0 + 3), T0 + 3)) == ["DBIRTH", "NDATA"]


def test_buffer_bounded_then_flushed_as_historical_in_order() -> None:
    s = session(buffer_messages=3)
    s.on_sample(sample(T0), T0)
    connect(s, T0)
    s.history_sent(s.history(T0)[1])
    s.on_disconnected()
    for i in range(1, 6):
        assert s.on_sample(sample(T0 + i, amps_raw=100 + i), T0 + i) == []
    assert (len(s.store), s.dropped) == (3, 2)
    out = connect(s, T0 + 10)
    assert kinds(out) == ["NBIRTH", "DBIRTH"] and isinstance(out[-1], HistoryReady)
    nbirth = decode(publishes(out)[0])
    assert {m.name: m.long_value for m in nbirth.metrics if m.name == "Node Info/Buffered Messages Dropped"} == {
        "Node Info/Buffered Messages Dropped": 2
    }
    sent, ids = s.history(T0 + 10, limit=2)
    assert len(s.store) == 3  # nothing is forgotten before it was written
    s.history_sent(ids)
    rest, rest_ids = s.history(T0 + 10, limit=2)
    s.history_sent(rest_ids)
    history = [decode(p) for p in sent + rest]
    assert [p.topic for p in sent + rest] == ["spBv1.0/g/DDATA/n/pump"] * 3
    assert [p.seq for p in history] == [2, 3, 4]
    assert [m.timestamp for p in history for m in p.metrics] == [int((T0 + i) * 1000) for i in (3, 4, 5)]
    assert all(m.is_historical for p in history for m in p.metrics)
    assert s.history(T0 + 10) == ([], []) and (len(s.store), s.store.delivered) == (0, 4)


def test_history_waits_for_the_birth_of_its_device() -> None:
    s = session()
    s.on_sample(sample(T0), T0)  # buffered: never born
    s.on_sample(sample(T0 + 1, online=False), T0 + 1)
    out = connect(s, T0 + 2)
    assert kinds(out) == ["NBIRTH"] and not any(isinstance(a, HistoryReady) for a in out)
    assert s.history(T0 + 2) == ([], []) and len(s.store) == 1  # kept, not dropped: no DATA before its DBIRTH
    out = s.on_sample(sample(T0 + 3, amps_raw=120), T0 + 3)
    assert kinds(out)[0] == "DBIRTH" and any(isinstance(a, HistoryReady) for a in out)
    (ddata,), ids = s.history(T0 + 3)
    assert decode(ddata).metrics[0].is_historical and len(ids) == 1


def test_buffer_drops_by_age() -> None:
    s = session(buffer_age=10.0)
    s.on_sample(sample(T0), T0)
    s.on_sample(sample(T0 + 1, amps_raw=150), T0 + 1)
    s.on_tick(T0 + 30)
    assert (len(s.store), s.dropped) == (0, 2)


def dcmd(metrics: Sequence[tuple[str, int, str, object]], ts: int | None) -> bytes:
    payload = tahu.Payload()
    for name, datatype, fld, value in metrics:
        m = payload.metrics.add(name=name, datatype=datatype)
        if ts is not None:
            m.timestamp = ts
        setattr(m, fld, value)
    return bytes(payload.SerializeToString())


def last_command(actions: list[Any], s: EdgeSession) -> str:
    alias = s.devices["pump"].metrics.by_name["Device Control/Last Command"].alias
    (p,) = [p for p in publishes(actions) if "DDATA" in p.topic]
    return str(next(m.string_value for m in decode(p).metrics if m.alias == alias))


def test_commands_checked_before_the_guarded_path() -> None:
    s = session(command_max_age=5.0)
    s.on_sample(sample(T0), T0)
    connect(s, T0)
    topic, now = "spBv1.0/g/DCMD/n/pump", T0 + 1
    ms = int(now * 1000)
    start = [("Device Control/Start", 11, "boolean_value", True)]
    assert s.on_message(topic, dcmd(start, ms), now) == [
        CommandRequest("pump", Command.START, {}, topic, "Device Control/Start=True")
    ]
    assert "old" in last_command(s.on_message(topic, dcmd(start, ms - 6000), now), s)
    assert "expected boolean" in last_command(
        s.on_message(topic, dcmd([("Device Control/Start", 11, "int_value", 1)], ms), now), s
    )
    assert "not writable" in last_command(
        s.on_message(topic, dcmd([("Measurements/phase_a_current", 10, "double_value", 1.0)], ms), now), s
    )
    assert s.on_message(topic, dcmd([("Parameters/ramp_time", 3, "int_value", 20)], ms), now) == [
        CommandRequest("pump", None, {"ramp_time": 20}, topic, "Parameters/ramp_time=20")
    ]
    assert "ignored: no metric" in last_command(
        s.on_message(topic, dcmd([("No Such Metric", 11, "boolean_value", True)], ms), now), s
    )
    (audit,) = s.on_message("spBv1.0/g/DCMD/n/ghost", dcmd(start, ms), now)  # no DATA for an unknown device
    assert audit == CommandAudit(None, "spBv1.0/g/DCMD/n/ghost", "?", "ignored: no such device")
    s.commands_allowed = False
    assert "plaintext" in last_command(s.on_message(topic, dcmd(start, ms), now), s)
    assert s.refused == 4


def test_rebirth_keeps_bdseq_and_restarts_seq() -> None:
    s = session()
    s.on_sample(sample(T0), T0)
    connect(s, T0)
    s.on_sample(sample(T0 + 1, amps_raw=120), T0 + 1)
    out = s.on_message("spBv1.0/g/NCMD/n", dcmd([("Node Control/Rebirth", 11, "boolean_value", True)], None), T0 + 2)
    assert kinds(out) == ["NBIRTH", "DBIRTH"]
    nbirth = decode(publishes(out)[0])
    assert nbirth.seq == 0 and {m.name: m.long_value for m in nbirth.metrics}["bdSeq"] == s.bdseq == 0


def state(online: bool, ts: int) -> bytes:
    return json.dumps({"online": online, "timestamp": ts}).encode()


def test_primary_host_state_gates_the_births() -> None:
    s = session(primary_host="scada")
    assert ("spBv1.0/STATE/scada", 1) in s.subscriptions()
    s.on_sample(sample(T0), T0)
    assert connect(s, T0) == []
    assert s.on_message("spBv1.0/STATE/other", state(True, 5), T0) == []
    assert s.on_message("spBv1.0/STATE/scada", state(False, 5), T0) == []
    assert kinds(s.on_message("spBv1.0/STATE/scada", state(True, 6), T0))[:2] == ["NBIRTH", "DBIRTH"]
    assert s.on_message("spBv1.0/STATE/scada", state(False, 4), T0) == []  # older: ignored
    out = s.on_message("spBv1.0/STATE/scada", state(False, 7), T0)
    assert kinds(out) == ["NDEATH"] and isinstance(out[-1], Reconnect) and not s.born


def test_deadband_per_key_and_unknown_keys() -> None:
    from starterbus.core.errors import ConfigurationError
    from starterbus.fleet.config import parse_fleet

    config = parse_fleet(
        '[[bus]]\nname = "l"\nurl = "modbus-rtu:///dev/null"\n[[bus.device]]\nname = "pump"\nmodel = "jjr5000"\n'
        'address = 2\nmeasurements = ["phase_a_current", "phase_b_current"]\n',
        "f.toml",
    )
    s = EdgeSession.for_fleet(
        config, SessionOptions("g", "n"), deadband_steps=3, deadband_per_key={"phase_b_current": 0}
    )
    by_name = s.devices["pump"].metrics.by_name
    assert by_name["Measurements/phase_a_current"].deadband == pytest.approx(0.3)
    assert by_name["Measurements/phase_b_current"].deadband == 0
    with pytest.raises(ConfigurationError, match="no device of f.toml publishes ramp_time"):
        EdgeSession.for_fleet(config, SessionOptions("g", "n"), deadband_per_key={"ramp_time": 2})


def test_primary_host_offline_before_the_births_walks_only_with_several_servers() -> None:
    one, several = session(primary_host="scada"), session(primary_host="scada", servers=2)
    for s in (one, several):
        s.on_sample(sample(T0), T0)
        assert connect(s, T0) == []
    assert one.on_message("spBv1.0/STATE/scada", state(False, 5), T0) == []  # one server: wait for it there
    out = several.on_message("spBv1.0/STATE/scada", state(False, 5), T0)
    assert out == [Reconnect()] and not several.connected  # several: the next server (no NDEATH: never born)
