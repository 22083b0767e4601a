"""A recorded event (an ``events`` row of the history) -> the OPC UA event a HistoryRead of events returns.

The alarms' episodes come back as the events of their conditions, with the fields the live ones carry
(:mod:`starterbus.opcua.alarms`): a ``fault`` row is the device's FaultAlarm going active (StarterFaultAlarmType:
FaultCode, FaultText, CurrentKeys and CurrentsBeforeTrip, the currents of the last sample before the trip, read
from the history), a ``state`` row out of ``fault`` is it going inactive (the reset); ``offline`` and ``online``
rows are the OfflineAlarm's. Acknowledgements are not recorded: an inactive event leaves AckedState,
ConfirmedState and Retain empty rather than guess them. Every other row (a change of state, a command, a write, a
recorded start, a gap in the recording) is a ``StarterRecordEventType`` (BaseEventType with ``Kind`` and
``Detail``, the row's JSON detail). EventIds are derived from the row (``starterbus-history`` and its id), so
they never match a live alarm's EventId (Acknowledge refuses them: BadEventIdUnknown).
"""

from __future__ import annotations

import copy
import json
import struct
from collections.abc import Callable, Mapping
from datetime import datetime, timezone
from typing import Any

from asyncua import Node, Server, ua
from asyncua.common.events import get_event_obj_from_type_node

from starterbus.opcua.address_space import DeviceNodes
from starterbus.opcua.alarms import SERVER, condition_fields, current_keys, fault_text, two_state

Row = Mapping[str, Any]
#: a device's last sample before a time (the currents before a trip), from the history
SampleBefore = Callable[[str, float], Mapping[str, Any] | None]
RECORD_EVENT_TYPE = "StarterRecordEventType"
SEVERITY = {"state": 100, "start": 100, "command": 200, "write": 200, "gap": 500}


def event_id(row_id: int) -> bytes:
    return b"starterbus-history" + struct.pack(">q", row_id)


class HistoricalEvents:
    """Builds events from rows; :meth:`build` (once, before the server starts) adds ``StarterRecordEventType``."""

    def __init__(self, server: Server, idx: int, devices: Mapping[str, DeviceNodes], locale: str) -> None:
        self.server = server
        self.idx = idx
        self.devices = devices
        self.locale = locale
        self._templates: dict[str, Any] = {}

    async def build(self, fault_type: ua.NodeId) -> None:
        record = await self.server.create_custom_event_type(
            self.idx, RECORD_EVENT_TYPE, ua.ObjectIds.BaseEventType,
            [("Kind", ua.VariantType.String), ("Detail", ua.VariantType.String)],
        )  # fmt: skip
        session = self.server.iserver.isession
        for name, type_id in (
            ("FaultAlarm", fault_type),
            ("OfflineAlarm", ua.NodeId(ua.ObjectIds.AlarmConditionType)),
            ("record", record.nodeid),
        ):
            event = await get_event_obj_from_type_node(Node(session, type_id))
            if name != "record":  # the ConditionId, as asyncua's EventGenerator adds it
                event.add_property("NodeId", None, ua.VariantType.NodeId)
            self._templates[name] = event

    def event(self, row: Row, sample_before: SampleBefore) -> Any:
        """The event of one row (``detail`` as stored: JSON text or already a dict)."""
        kind = str(row["kind"])
        device = self.devices.get(str(row["device"]))
        detail = row["detail"]
        if isinstance(detail, str):
            detail = json.loads(detail or "{}")
        if device is not None:
            if kind == "fault":
                return self._fault(row, device, sample_before)
            if kind in ("offline", "online"):
                return self._offline(row, device, kind == "offline")
            if kind == "state" and detail.get("from") == "fault" and detail.get("to") != "fault":
                return self._condition(row, device, "FaultAlarm", False, f"{device.config.name}: fault reset")
        return self._record(row, device, kind, detail)

    def _common(self, template: str, row: Row) -> Any:
        event = copy.deepcopy(self._templates[template])
        at = datetime.fromtimestamp(float(row["time"]), timezone.utc)
        event.EventId = event_id(int(row["id"]))
        event.Time = event.ReceiveTime = at
        return event

    def _condition(self, row: Row, device: DeviceNodes, name: str, active: bool, message: str) -> Any:
        event = self._common(name, row)
        condition = ua.NodeId(f"{device.config.name}.{name}", self.idx)
        condition_fields(event, device, name, condition)
        two_state(event, "ActiveState", active, "Active", "Inactive")
        if active:  # a new episode: unacknowledged, unconfirmed, retained (what later happened is not recorded)
            two_state(event, "AckedState", False, "Acknowledged", "Unacknowledged")
            two_state(event, "ConfirmedState", False, "Confirmed", "Unconfirmed")
            event.Retain = True
        else:
            for field in ("AckedState", "AckedState/Id", "ConfirmedState", "ConfirmedState/Id", "Retain"):
                setattr(event, field, None)
        event.Quality = ua.StatusCode()
        event.Message = ua.LocalizedText(message, "en")
        return event

    def _fault(self, row: Row, device: DeviceNodes, sample_before: SampleBefore) -> Any:
        name = device.config.name
        code = int(row["code"] or 0)
        text = fault_text(device, code, self.locale)
        event = self._condition(row, device, "FaultAlarm", True, f"{name}: fault {code}: {text.Text}")
        event.FaultCode = code
        event.FaultText = text
        before = sample_before(name, float(row["time"]))
        currents: list[float] = []
        if before is not None:
            values = before["values"]
            if isinstance(values, str):
                values = json.loads(values or "{}")
            for key in current_keys(device):
                value = values.get(key)
                if value is not None and value.get("value") is not None:
                    currents.append(float(value["value"]))
        event.CurrentsBeforeTrip = currents
        return event

    def _offline(self, row: Row, device: DeviceNodes, offline: bool) -> Any:
        name = device.config.name
        message = f"{name}: offline: {row['text']}" if offline else f"{name}: answers again"
        return self._condition(row, device, "OfflineAlarm", offline, message)

    def _record(self, row: Row, device: DeviceNodes | None, kind: str, detail: Mapping[str, Any]) -> Any:
        event = self._common("record", row)
        name = str(row["device"])
        if device is not None:
            event.SourceNode, event.SourceName = device.node, name
        elif name == "*":  # about every device: a gap in the recording
            event.SourceNode, event.SourceName = SERVER, "Server"
        else:  # a device the fleet no longer has
            event.SourceNode, event.SourceName = ua.NodeId(), name
        event.Severity = SEVERITY.get(kind, 100)
        event.Message = ua.LocalizedText(f"{name}: {kind}: {row['text']}", "en")
        event.Kind = kind
        event.Detail = json.dumps(dict(detail), ensure_ascii=False, default=str)
        return event
