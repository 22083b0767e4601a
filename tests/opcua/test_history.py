"""HistoryRead over the recorder's SQLite history, with asyncua's client: the recorded samples of a range (raw, in
order, with their source timestamps), long ranges in pages whose continuation points lose and repeat nothing,
the recorded fault as an event with the alarm's fields, and Bad codes for nodes without history."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Awaitable, Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, Node, ua
from asyncua.common.events import Event, get_filter_from_event_type

from starterbus.aio import AsyncFleet
from starterbus.core.errors import ConfigurationError
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.opcua.history_events import event_id
from starterbus.opcua.server import OpcUaServer, OpcUaSettings
from starterbus.ops.history import HistoryStore
from starterbus.ops.recorder import HistoryRecorder
from starterbus.testing import wait_until, wait_until_async
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

NS = "urn:starterbus:fleet"
WAIT = 15.0
T0 = 1_700_000_000.0  # the synthetic history's first sample


def fleet(port: str) -> Any:
    return parse_fleet(
        f'[poll]\nperiod = 0.1\nmax_backoff = 0.3\n[[bus]]\nname = "l"\nurl = "modbus-rtu://{port}?timeout=0.2"\n'
        '[[bus.device]]\nname = "conveyor"\nmodel = "jjr5000"\naddress = 1\nmeasurements = ["phase_a_current"]\n'
        'parameters = ["start_mode"]\n',
        "h.toml",
    )


def at(seconds: float) -> datetime:
    return datetime.fromtimestamp(seconds, timezone.utc)


def synthetic(path: Path, count: int) -> list[dict[str, Any]]:
    """``count`` samples of conveyor, three to a timestamp (the continuation must not rely on unique times)."""
    rows = []
    for i in range(count):
        online = i % 50 != 49  # now and then offline: Bad values in the history too
        rows.append({
            "time": T0 + (i // 3) * 0.1, "device": "conveyor", "model": "jjr5000", "online": int(online),
            "state": "running" if online else None, "fault_code": None,
            "values": {"phase_a_current": {"value": float(i), "raw": i, "unit": "A"}} if online else {},
            "error": None if online else "no answer",
        })  # fmt: skip
    with HistoryStore(path) as store:
        store.add_batch(rows, [])
    return rows


def run_server(settings: OpcUaSettings, port: str, body: Callable[[Client, int, OpcUaServer], Awaitable[None]],
               sink: Any = None) -> None:  # fmt: skip
    async def scenario() -> None:
        async with AsyncFleet(fleet(port), sink=sink) as f, OpcUaServer(f, settings) as server:
            client = Client(server.endpoint_url, timeout=10)
            async with client:
                await body(client, await client.get_namespace_index(NS), server)

    asyncio.run(scenario())


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One server certificate for the module (generating a key takes seconds)."""
    return tmp_path_factory.mktemp("pki")


@pytest.fixture
def line() -> Any:
    starter = SimulatedStarter(get_profile("jjr5000"))
    sim = ModbusRtuSimulator({1: starter}, pty=True).start()
    port = sim.client_urls()[1].split("://", 1)[1].split("?", 1)[0]
    yield port, starter
    sim.close()


def settings(pki: Path, history: Path | None) -> OpcUaSettings:
    return OpcUaSettings("opc.tcp://127.0.0.1:0/sb", pki_dir=pki, anonymous=True, allow_insecure=True, history=history)


async def read_raw(node: Node, start: float | None, end: float | None, count: int, point: bytes | None = None) -> Any:
    details = ua.ReadRawModifiedDetails(
        IsReadModified=False,
        StartTime=at(start) if start is not None else ua.get_win_epoch(),
        EndTime=at(end) if end is not None else ua.get_win_epoch(),
        NumValuesPerNode=count,
        ReturnBounds=False,
    )
    return await node.history_read(details, point)


async def pages(node: Node, start: float | None, end: float | None, count: int) -> list[list[ua.DataValue]]:
    out, point = [], None
    while True:
        result = await read_raw(node, start, end, count, point)
        result.StatusCode.check()
        out.append(result.HistoryData.DataValues)
        point = result.ContinuationPoint
        if point is None:
            return out


async def event_pages(client: Client, node: Node, details: ua.ReadEventDetails) -> list[Any]:
    """Every event of ``details`` read one to a page (NumValuesPerNode 1), following the continuation points."""
    out, point = [], None
    while True:
        item = ua.HistoryReadValueId(NodeId=node.nodeid, ContinuationPoint=point)
        params = ua.HistoryReadParameters(
            HistoryReadDetails=details,
            TimestampsToReturn=ua.TimestampsToReturn.Both,
            ReleaseContinuationPoints=False,  # asyncua's default is True
            NodesToRead=[item],
        )
        (result,) = await client.uaclient.history_read(params)
        result.StatusCode.check()
        assert len(result.HistoryData.Events) == 1
        out.append(Event.from_event_fields(details.Filter.SelectClauses, result.HistoryData.Events[0].EventFields))
        point = result.ContinuationPoint
        if point is None:
            return out


def test_long_ranges_come_in_pages_with_nothing_lost_or_repeated(tmp_path: Path, pki: Path, line: Any) -> None:
    rows = synthetic(tmp_path / "h.db", 2345)
    currents = [r["values"]["phase_a_current"]["value"] if r["online"] else None for r in rows]

    async def body(client: Client, idx: int, server: OpcUaServer) -> None:
        node = client.get_node(ua.NodeId("conveyor.Measurements.phase_a_current", idx))
        assert (await node.read_attribute(ua.AttributeIds.Historizing)).Value.Value is True
        assert ua.AccessLevel.HistoryRead in await node.get_access_level()
        end = T0 + 1000.0
        forward = await pages(node, T0 - 1, end, 100)
        assert [len(p) for p in forward] == [100] * 23 + [45]
        got = [dv.Value.Value if dv.StatusCode.is_good() else None for p in forward for dv in p]
        assert got == currents  # in order, each once, offline polls as Bad values
        bad = forward[0][49]
        assert bad.StatusCode.value == ua.StatusCodes.BadCommunicationError and bad.SourceTimestamp == at(T0 + 1.6)
        stamps = [dv.SourceTimestamp for p in forward for dv in p]
        assert stamps == [at(r["time"]) for r in rows] and all(dv.ServerTimestamp is None for p in forward for dv in p)

        backward = await pages(node, end, T0 - 1, 700)  # EndTime before StartTime: latest first
        assert [len(p) for p in backward] == [700, 700, 700, 245]
        assert [dv.Value.Value if dv.StatusCode.is_good() else None for p in backward for dv in p] == currents[::-1]

        one_ended = await pages(node, T0 + 10.0, None, 1500)  # StartTime and a count: 1500 in all, server pages 1000
        assert [len(p) for p in one_ended] == [1000, 500]
        first = rows.index(next(r for r in rows if r["time"] >= T0 + 10.0 - 1e-9))
        assert [dv.SourceTimestamp for p in one_ended for dv in p] == [
            at(r["time"]) for r in rows[first : first + 1500]
        ]
        latest = await pages(node, None, end, 4)  # EndTime and a count: the last four, latest first
        assert [dv.Value.Value for dv in latest[0]] == [2344.0, 2343.0, 2342.0, 2341.0] and len(latest) == 1

        state = client.get_node(ua.NodeId("conveyor.Status.State", idx))
        (states,) = await pages(state, T0 - 1, T0 + 0.05, 0)
        assert [dv.Value.Value for dv in states] == [4, 4, 4]  # Running (StarterStateEnum), the three of T0

        tampered = bytearray((await read_raw(node, T0 - 1, end, 100)).ContinuationPoint)
        tampered[-1] ^= 1
        result = await read_raw(node, T0 - 1, end, 100, bytes(tampered))
        assert result.StatusCode.value == ua.StatusCodes.BadContinuationPointInvalid
        other = (await read_raw(state, T0 - 1, end, 100)).ContinuationPoint  # another node's point
        assert (
            await read_raw(node, T0 - 1, end, 100, other)
        ).StatusCode.value == ua.StatusCodes.BadContinuationPointInvalid

    run_server(settings(pki, tmp_path / "h.db"), line[0], body)


def test_event_pages_hold_the_types_asked_for_and_skip_the_others(tmp_path: Path, pki: Path, line: Any) -> None:
    """Offline/online rows are OfflineAlarm conditions: a filter on record and fault events skips them, across
    pages, and loses none of the others; a filter on every event type returns them too, in order."""
    kinds = ["state", "offline", "online", "write", "offline", "online", "state", "fault"]
    events = [{"time": T0 + i * 0.1, "device": "conveyor", "kind": kind, "text": f"e{i}",
               "code": 6 if kind == "fault" else None} for i, kind in enumerate(kinds)]  # fmt: skip
    with HistoryStore(tmp_path / "h.db") as store:
        store.add_batch([], events)

    async def body(client: Client, idx: int, server: OpcUaServer) -> None:
        device = client.get_node(ua.NodeId("conveyor", idx))
        record_type = await client.nodes.base_event_type.get_child(f"{idx}:StarterRecordEventType")
        fault_type = await client.nodes.base_event_type.get_child(
            ["0:ConditionType", "0:AcknowledgeableConditionType", "0:AlarmConditionType",
             f"{idx}:StarterFaultAlarmType"]
        )  # fmt: skip
        offline_type = client.get_node(ua.NodeId(ua.ObjectIds.AlarmConditionType))
        for types, wanted in (
            ([record_type, fault_type], [1, 4, 7, 8]),
            ([record_type, fault_type, offline_type], list(range(1, 9))),
        ):
            evfilter = await get_filter_from_event_type(types)
            details = ua.ReadEventDetails(
                StartTime=at(T0 - 1), EndTime=at(T0 + 10), NumValuesPerNode=1, Filter=evfilter
            )
            got = await event_pages(client, device, details)
            assert [e.EventId for e in got] == [event_id(i) for i in wanted], types

    run_server(settings(pki, tmp_path / "h.db"), line[0], body)


def test_nodes_without_history_answer_bad_codes(tmp_path: Path, pki: Path, line: Any) -> None:
    synthetic(tmp_path / "h.db", 10)

    async def body(client: Client, idx: int, server: OpcUaServer) -> None:
        def code(result: Any) -> int:
            return int(result.StatusCode.value)

        unsupported = ua.StatusCodes.BadHistoryOperationUnsupported
        last_operation = client.get_node(ua.NodeId("conveyor.Status.LastOperation", idx))  # not in the history
        assert code(await read_raw(last_operation, T0 - 1, T0 + 10, 0)) == unsupported
        assert ua.AccessLevel.HistoryRead not in await last_operation.get_access_level()
        assert code(await read_raw(client.get_node(ua.NodeId("nothing", idx)), T0, T0 + 1, 0)) == (
            ua.StatusCodes.BadNodeIdUnknown
        )
        current = client.get_node(ua.NodeId("conveyor.Measurements.phase_a_current", idx))
        assert code(await read_raw(current, T0, None, 0)) == ua.StatusCodes.BadInvalidTimestampArgument
        modified = ua.ReadRawModifiedDetails(IsReadModified=True, StartTime=at(T0), EndTime=at(T0 + 1))
        assert code(await current.history_read(modified)) == unsupported
        processed = ua.ReadProcessedDetails(StartTime=at(T0), EndTime=at(T0 + 1), ProcessingInterval=1000.0)
        assert code(await current.history_read(processed)) == unsupported
        events = await client.nodes.server.read_event_history(at(T0 - 1), at(T0 + 10))
        assert events == []  # a history with no events: none, Good

    run_server(settings(pki, tmp_path / "h.db"), line[0], body)

    async def without_history(client: Client, idx: int, server: OpcUaServer) -> None:
        current = client.get_node(ua.NodeId("conveyor.Measurements.phase_a_current", idx))
        result = await read_raw(current, T0 - 1, T0 + 10, 0)
        assert result.StatusCode.value == ua.StatusCodes.BadHistoryOperationUnsupported
        assert ua.AccessLevel.HistoryRead not in await current.get_access_level()

    run_server(settings(pki, None), line[0], without_history)


def test_the_recorded_samples_and_the_recorded_fault_are_read_back(tmp_path: Path, pki: Path, line: Any) -> None:
    port, starter = line
    db = tmp_path / "plant.db"
    recorder = HistoryRecorder(db)

    def recorded(kind: str) -> list[dict[str, Any]]:
        try:
            with HistoryStore(db, create=False) as store:
                return store.events(device="conveyor", kind=kind)
        except ConfigurationError:  # not there yet, or its tables not yet written
            return []

    async def body(client: Client, idx: int, server: OpcUaServer) -> None:
        starter.start()
        # starting, then running
        assert await wait_until_async(lambda: starter.current() > 1 and len(recorded("state")) >= 2, WAIT)
        served = server.samples_served
        assert await wait_until_async(lambda: server.samples_served >= served + 3, WAIT)
        starter.inject_fault(6)
        assert await wait_until_async(lambda: bool(recorded("fault")), WAIT)
        (fault,) = recorded("fault")
        with HistoryStore(db, create=False) as store:
            samples = store.samples(device="conveyor", until=fault["time"])
        start = (samples[1]["time"] + samples[2]["time"]) / 2  # between two polls: from the third one on
        expected = samples[2:]

        current = client.get_node(ua.NodeId("conveyor.Measurements.phase_a_current", idx))
        (values,) = await pages(current, start, fault["time"] + 0.001, 0)
        assert [dv.SourceTimestamp for dv in values] == [at(s["time"]) for s in expected]
        for dv, sample in zip(values, expected, strict=True):
            value = sample["values"].get("phase_a_current")
            if value is None:  # a poll that failed (a loaded machine): withheld, as the live variable's was
                assert not dv.StatusCode.is_good()
            else:
                assert dv.Value.Value == value["value"]
        fault_code = client.get_node(ua.NodeId("conveyor.Status.FaultCode", idx))
        (codes,) = await pages(fault_code, start, fault["time"] + 0.001, 0)
        assert codes[-1].Value.Value == 6
        # before the fault: 0, or withheld where a poll failed (a loaded machine), as for the currents above
        assert all(dv.Value.Value == 0 or not dv.StatusCode.is_good() for dv in codes[:-1]), codes

        before = [s for s in samples if s["time"] < fault["time"] and s["state"] != "fault"][-1]
        fault_type = await client.nodes.base_event_type.get_child(
            [
                "0:ConditionType",
                "0:AcknowledgeableConditionType",
                "0:AlarmConditionType",
                f"{idx}:StarterFaultAlarmType",
            ]
        )
        device = client.get_node(ua.NodeId("conveyor", idx))
        for source in (device, client.nodes.server):
            assert ua.EventNotifier.HistoryRead in await source.read_event_notifier()
            (event,) = await source.read_event_history(at(start), at(fault["time"] + 0.001), evtypes=fault_type)
            assert event.FaultCode == 6 and event.FaultText.Text == "motor overload" and event.Severity == 800
            assert event.CurrentKeys == "phase_a_current"
            assert event.CurrentsBeforeTrip == [before["values"]["phase_a_current"]["value"]]
            assert event.CurrentsBeforeTrip[0] > 1
            assert event.Time == at(fault["time"]) and event.SourceName == "conveyor" and event.Retain is True
            assert getattr(event, "ActiveState/Id") is True and getattr(event, "AckedState/Id") is False
            assert event.Message.Text == "conveyor: fault 6: motor overload"

        record_type = await client.nodes.base_event_type.get_child(f"{idx}:StarterRecordEventType")
        everything = await device.read_event_history(
            at(start - 60), at(fault["time"] + 0.001), evtypes=[record_type, fault_type]
        )
        kinds = [(getattr(e, "Kind", None), e.Message.Text) for e in everything]
        assert ("state", "conveyor: state: running -> fault") in kinds
        assert kinds[-1] == (None, "conveyor: fault 6: motor overload")  # written after its state change
        state_event = next(e for e in everything if getattr(e, "Kind", None) == "state")
        assert json.loads(state_event.Detail)["from"] in ("stopped", "ready", "starting")

        evfilter = await get_filter_from_event_type([fault_type])
        details = ua.ReadEventDetails(
            StartTime=at(start - 60), EndTime=at(fault["time"] + 1), NumValuesPerNode=1, Filter=evfilter
        )
        first = await device.history_read_events(details)  # one to a page: the fault is the only one
        assert len(first.HistoryData.Events) == 1 and first.ContinuationPoint is None
        got = Event.from_event_fields(evfilter.SelectClauses, first.HistoryData.Events[0].EventFields)
        assert got.FaultCode == 6

        evfilter = await get_filter_from_event_type([record_type, fault_type])
        details.Filter = evfilter
        ids = [e.EventId for e in await event_pages(client, device, details)]
        with HistoryStore(db, create=False) as store:
            rows = store.events(device="conveyor", since=start - 60, until=fault["time"] + 1)
        # offline/online rows (a poll that failed on a loaded machine) are OfflineAlarm conditions: not asked for
        asked = [r for r in rows if r["kind"] not in ("offline", "online")]
        assert ids == [event_id(r["id"]) for r in asked] and len(ids) >= 4, [(r["id"], r["kind"]) for r in rows]

    try:
        run_server(settings(pki, db), port, body, sink=recorder)
    finally:
        recorder.close()


def test_opcua_record_records_and_serves_the_history(tmp_path: Path, pki: Path) -> None:
    exe = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))
    db = tmp_path / "demo.db"
    proc = subprocess.Popen(
        [exe, "opcua", "--demo", "--endpoint", "opc.tcp://127.0.0.1:0/sb", "--anonymous", "--allow-insecure",
         "--pki", str(pki), "--record", str(db), "--keep", "1d", "--json", "--duration", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "STARTERBUS_AUDIT_LOG": str(tmp_path / "audit.jsonl")},
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        ready = json.loads(proc.stdout.readline())
        assert ready["history"] == str(db)
        device = ready["devices"][0]

        def samples() -> list[dict[str, Any]]:
            try:
                with HistoryStore(db, create=False) as store:
                    return store.samples(device=device)
            except ConfigurationError:  # not there yet, or its tables not yet written
                return []

        assert wait_until(lambda: len(samples()) >= 3, 30.0)
        rows = samples()[:3]

        async def body() -> None:
            async with Client(ready["endpoint"], timeout=10) as client:
                idx = await client.get_namespace_index(NS)
                online = client.get_node(ua.NodeId(f"{device}.Status.Online", idx))
                (values,) = await pages(online, rows[0]["time"] - 0.001, rows[-1]["time"], 0)
                assert [(dv.SourceTimestamp, dv.Value.Value) for dv in values] == [
                    (at(r["time"]), r["online"]) for r in rows
                ]

        asyncio.run(body())
    finally:
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
