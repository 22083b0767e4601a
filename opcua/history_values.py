"""A recorded sample (a ``samples`` row of the history) -> the DataValue one variable had then (pure).

The same values and status codes the live server wrote at that poll (:mod:`starterbus.opcua.values`): the poll's
time as SourceTimestamp, BadCommunicationError while the device was offline, the fault text from the profile.
``Ready``, ``BusControl`` and ``LastOperation`` are not in the history, so they are not historized.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from asyncua import ua

from starterbus.core.status import MotorState
from starterbus.opcua.address_space import STATES, DeviceHealth, DeviceNodes, texts
from starterbus.opcua.values import point_updates

Row = Mapping[str, Any]
#: a row and its time -> the variable's DataValue
Extract = Callable[[Row, datetime], ua.DataValue]
#: the status variables the history can tell
HISTORIZED_STATUS = ("State", "Fault", "FaultCode", "FaultText", "Online", "LastError", "DeviceHealth")


@dataclass(frozen=True, slots=True)
class HistoricalVariable:
    device: str
    extract: Extract


def _bad(code: int, at: datetime) -> ua.DataValue:
    return ua.DataValue(StatusCode=ua.StatusCode(code), SourceTimestamp=at)


def _good(variant: ua.Variant, at: datetime) -> ua.DataValue:
    return ua.DataValue(variant, SourceTimestamp=at)


def _missing(row: Row) -> int:
    """The code of a value a poll did not give (as values.sample_updates chooses it)."""
    if not row["online"]:
        return int(ua.StatusCodes.BadCommunicationError)
    return int(ua.StatusCodes.BadDeviceFailure if row["error"] else ua.StatusCodes.BadNotSupported)


def row_time(row: Row) -> datetime:
    return datetime.fromtimestamp(float(row["time"]), timezone.utc)


def historical_variables(device: DeviceNodes, locale: str) -> dict[ua.NodeId, HistoricalVariable]:
    """Every variable of ``device`` the history can fill, and how."""
    name = device.config.name
    profile = device.profile

    def status(make: Callable[[Row, bool, int], ua.Variant]) -> Extract:
        def extract(row: Row, at: datetime) -> ua.DataValue:
            if not row["online"] or row["state"] is None:
                return _bad(_missing(row), at)
            fault = row["state"] == MotorState.FAULT.value
            return _good(make(row, fault, int(row["fault_code"] or 0) if fault else 0), at)

        return extract

    def fault_text(row: Row, fault: bool, code: int) -> ua.Variant:
        label = profile.faults.label(code) if fault else None
        text = texts(label.en, label.zh, locale)[0] if label is not None else ua.LocalizedText("")
        return ua.Variant(text, ua.VariantType.LocalizedText)

    extracts: dict[str, Extract] = {
        "Online": lambda row, at: _good(ua.Variant(bool(row["online"]), ua.VariantType.Boolean), at),
        "LastError": lambda row, at: _good(ua.Variant(row["error"] or "", ua.VariantType.String), at),
        "State": status(lambda row, f, c: ua.Variant(STATES.index(MotorState(row["state"])), ua.VariantType.Int32)),
        "Fault": status(lambda row, f, c: ua.Variant(f, ua.VariantType.Boolean)),
        "FaultCode": status(lambda row, f, c: ua.Variant(c, ua.VariantType.UInt16)),
        "FaultText": status(fault_text),
        "DeviceHealth": status(
            lambda row, f, c: ua.Variant(int(DeviceHealth.FAILURE if f else DeviceHealth.NORMAL), ua.VariantType.Int32)
        ),
    }
    out = {device.status[key]: HistoricalVariable(name, extracts[key]) for key in HISTORIZED_STATUS}
    for key, point_node in device.points.items():
        nodes = [point_node.node] + ([point_node.value_as_text] if point_node.value_as_text is not None else [])
        for index, node in enumerate(nodes):
            out[node] = HistoricalVariable(name, _point_extract(key, point_node, index, locale))
    return out


def _point_extract(key: str, point_node: Any, index: int, locale: str) -> Extract:
    def extract(row: Row, at: datetime) -> ua.DataValue:
        values = row["values"]
        if isinstance(values, str):
            values = json.loads(values or "{}")
        value = values.get(key)
        if value is None or value.get("raw") is None:
            if not row["online"] or row["error"]:
                return _bad(_missing(row), at)
            return _bad(ua.StatusCodes.BadNoData, at)
        updates = point_updates(point_node, int(value["raw"]), float(value["value"]), at, locale)
        dv = updates[index][1]
        dv.ServerTimestamp = None  # the history keeps the poll's time only
        return dv

    return extract
