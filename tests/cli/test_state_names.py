"""One name per motor state everywhere: one status rendered through every output (status table, watch line, poll
table, CSV, JSON, history, Sparkplug payload, OPC UA value) reads the same, ``MotorState``'s value."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import pytest
from asyncua import ua

from starterbus.cli.device_cmds import status_rows
from starterbus.cli.watch import show
from starterbus.core.registry import get_profile
from starterbus.core.status import MotorState, Status, decode_status_word
from starterbus.fleet.config import DeviceConfig
from starterbus.fleet.device_poll import DeviceRuntime
from starterbus.fleet.output import TABLE_HEADERS, CsvLog, table_rows
from starterbus.fleet.sample import Sample
from starterbus.opcua.address_space import STATE_ENUM_STRINGS, STATES, DeviceNodes
from starterbus.opcua.values import sample_updates
from starterbus.ops.history import HistoryStore
from starterbus.ops.recorder import sample_row
from starterbus.serve.metrics import Aliases, device_metrics, sample_values
from starterbus.serve.payloads import encode
from starterbus.serve.schema import Payload

PROFILE = get_profile("jjr5000")
CONFIG = DeviceConfig("conveyor", "l1", "jjr5000", "modbus-rtu:///dev/null?unit=2", 2, 1.0, (), ())


def _idle_devicenet() -> Status:
    """An idle motor over DeviceNet: its assemblies do not tell whether it is ready."""
    return Status(fault=False, fault_code=None, fault_text=None, starting=False, running=False, stopping=False)


STATUSES = {
    "ready": decode_status_word(1 << 13, PROFILE.faults),  # idle, bit 13 "ready to start"
    "stopped": decode_status_word(0, PROFILE.faults),  # idle, not ready (no mains, a start inhibit)
    "stopped, ready unknown": _idle_devicenet(),
    "starting": decode_status_word(1 << 8 | 1 << 13, PROFILE.faults),
    "running": decode_status_word(1 << 9 | 1 << 13, PROFILE.faults),
    "stopping": decode_status_word(1 << 10, PROFILE.faults),
    "fault": decode_status_word(0x8000 | 6, PROFILE.faults),
}


def _sample(status: Status) -> Sample:
    return Sample("conveyor", "l1", "jjr5000", 1_700_000_000.25, True, status, {}, None, 0)


class _Described:
    def describe(self) -> str:
        return "conveyor"


def rendered(status: Status, tmp_path: Path) -> dict[str, str]:
    """The state as each output shows it."""
    sample = _sample(status)
    out: dict[str, str] = {"status": str(status_rows(status)[0][1])}

    watch = io.StringIO()
    show(_Described(), status, [], None, watch, False, None)  # type: ignore[arg-type]
    out["watch"] = watch.getvalue().splitlines()[0].split()[2]

    runtime = DeviceRuntime(CONFIG, online=True, last_ok=0.0, last_sample=sample)
    out["poll table"] = table_rows([runtime], 0.0)[0][TABLE_HEADERS.index("state")]

    for long in (False, True):
        path = tmp_path / f"log-{long}.csv"
        log = CsvLog(path, long=long)
        log(sample)
        log.close()
        with path.open(encoding="utf-8", newline="") as f:
            out[f"csv long={long}"] = next(csv.DictReader(f))["state"]

    json_status = sample.as_json()["status"]
    assert isinstance(json_status, dict)
    out["json"] = json_status["state"]

    with HistoryStore(tmp_path / "history.db") as store:
        store.add_sample(sample_row(sample, PROFILE))
        out["history"] = store.samples(device="conveyor")[-1]["state"]

    metrics = device_metrics(CONFIG, PROFILE, Aliases())
    values = sample_values(sample, metrics)
    entries = [(metrics.by_name[name], value, 0) for name, value in values.items()]
    payload = Payload()
    payload.ParseFromString(encode(entries, timestamp=0, seq=0, birth=True))
    out["sparkplug"] = next(m.string_value for m in payload.metrics if m.name == "Status/State")

    status_ids = {k: ua.NodeId(f"c.{k}", 2) for k in (
        "State", "Fault", "FaultCode", "FaultText", "Ready", "BusControl", "Online", "LastError", "DeviceHealth",
    )}  # fmt: skip
    nodes = DeviceNodes(CONFIG, PROFILE, ua.NodeId("c", 2), status_ids)
    index = dict(sample_updates(nodes, sample))[status_ids["State"]].Value.Value
    out["opcua value"] = STATES[index].value
    out["opcua enum string"] = STATE_ENUM_STRINGS[index].lower()
    return out


@pytest.mark.parametrize("case", STATUSES)
def test_every_output_gives_a_state_the_same_name(case: str, tmp_path: Path) -> None:
    status = STATUSES[case]
    expected = case.partition(",")[0]
    assert status.state.value == expected
    names = rendered(status, tmp_path)
    assert names == dict.fromkeys(names, expected), case


def test_ready_and_stopped_are_told_apart() -> None:
    """An idle motor ready to start (bit 13) is not the same state as one that is not (known to be) ready."""
    assert STATUSES["ready"].state is MotorState.READY
    assert STATUSES["stopped"].state is STATUSES["stopped, ready unknown"].state is MotorState.STOPPED
    assert set(STATE_ENUM_STRINGS) == {s.value.capitalize() for s in MotorState}
