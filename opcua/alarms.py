"""OPC UA Alarms & Conditions: a device fault and a device offline are alarms an operator acknowledges and confirms.

Per device two conditions, ``ns=2;s=DEVICE.FaultAlarm`` (of ``StarterFaultAlarmType``, an AlarmConditionType with
``FaultCode``, ``FaultText`` and ``CurrentsBeforeTrip``: the currents of the last poll before the trip, in the
order of ``CurrentKeys``) and ``ns=2;s=DEVICE.OfflineAlarm`` (an AlarmConditionType). Their events come from the
Server object (where alarm clients subscribe) with the device as SourceNode. A condition goes active when the
device reports a fault (or stops answering), unacknowledged and unconfirmed; it goes inactive when the fault is
reset (or the device answers again) and is retained until it is inactive, acknowledged and confirmed. Operators
call the standard ``Acknowledge`` and ``Confirm`` methods (AcknowledgeableConditionType, i=9111 and i=9113) on
the ConditionId with the EventId of the latest event; read-only users are refused (BadUserAccessDenied) by the
role rules, like every Call. ``ConditionRefresh`` replays the retained conditions (asyncua's
``bind_condition_methods``). asyncua has no condition instances: the condition nodes are plain objects and the
state lives in the events.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

from asyncua import Server, ua
from asyncua.server.event_generator import EventGenerator

from starterbus.fleet.poller import Sample
from starterbus.opcua.address_space import DeviceNodes, texts

log = logging.getLogger("starterbus.opcua")

FAULT_SEVERITY = 800  # OPC UA 1-1000: high
OFFLINE_SEVERITY = 600
ACKNOWLEDGE = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)
SERVER = ua.NodeId(ua.ObjectIds.Server)


@dataclass(slots=True)
class Condition:
    device: DeviceNodes
    name: str  # FaultAlarm, OfflineAlarm
    node: ua.NodeId
    generator: EventGenerator
    active: bool = False
    acked: bool = True
    confirmed: bool = True
    event_id: bytes | None = None
    currents: list[float] = field(default_factory=list)

    @property
    def retained(self) -> bool:
        return self.active or not (self.acked and self.confirmed)


def two_state(event: object, name: str, value: bool, true: str, false: str) -> None:
    setattr(event, f"{name}/Id", value)
    setattr(event, name, ua.LocalizedText(true if value else false, "en"))
    setattr(event, f"{name}/TrueState", ua.LocalizedText(true, "en"))
    setattr(event, f"{name}/FalseState", ua.LocalizedText(false, "en"))


def current_keys(device: DeviceNodes) -> list[str]:
    """The device's measurements in amperes: the order of a fault's CurrentsBeforeTrip."""
    return [k for k, p in device.points.items() if p.point.unit == "A"]


def fault_text(device: DeviceNodes, code: int, locale: str) -> ua.LocalizedText:
    """A fault alarm's FaultText: the profile's text of ``code`` in the server's language."""
    label = device.profile.faults.label(code)
    return texts(label.en, label.zh, locale)[0] if label is not None else ua.LocalizedText(f"fault {code}")


def condition_fields(event: Any, device: DeviceNodes, name: str, node: ua.NodeId) -> None:
    """The fields every event of the condition ``name`` (FaultAlarm, OfflineAlarm) of ``device`` carries (also
    its historical events, :mod:`starterbus.opcua.history_events`)."""
    event.NodeId = node
    event.SourceNode = device.node
    event.SourceName = device.config.name
    event.ConditionName = name
    event.BranchId = ua.NodeId()
    two_state(event, "EnabledState", True, "Enabled", "Disabled")
    event.Severity = event.LastSeverity = FAULT_SEVERITY if name == "FaultAlarm" else OFFLINE_SEVERITY
    if name == "FaultAlarm":
        event.CurrentKeys = ",".join(current_keys(device))


class Alarms:
    """The fleet's conditions; ``operator()`` names the caller of the method being served (None: not an operator)."""

    def __init__(self, server: Server, idx: int, operator: Callable[[], str | None], locale: str = "en") -> None:
        self.server = server
        self.idx = idx
        self.operator = operator
        self.locale = locale
        self.conditions: dict[ua.NodeId, Condition] = {}
        self.fault: dict[str, Condition] = {}
        self.offline: dict[str, Condition] = {}
        self._last_currents: dict[str, list[float]] = {}
        self.fault_type = ua.NodeId()  # StarterFaultAlarmType, once built

    async def build(self, devices: dict[str, DeviceNodes]) -> None:
        fault_type = await self.server.create_custom_event_type(
            self.idx,
            "StarterFaultAlarmType",
            ua.ObjectIds.AlarmConditionType,
            [
                ("FaultCode", ua.VariantType.UInt16),
                ("FaultText", ua.VariantType.LocalizedText),
                ("CurrentKeys", ua.VariantType.String),
                ("CurrentsBeforeTrip", ua.VariantType.Double),
            ],
        )
        self.fault_type = fault_type.nodeid
        first = True
        for name, device in devices.items():
            for kind, etype, table in (
                ("FaultAlarm", fault_type.nodeid, self.fault),
                ("OfflineAlarm", ua.NodeId(ua.ObjectIds.AlarmConditionType), self.offline),
            ):
                node = await self.server.get_node(device.node).add_object(
                    ua.NodeId(f"{name}.{kind}", self.idx), ua.QualifiedName(kind, self.idx)
                )
                generator = EventGenerator(self.server.iserver.isession)
                await generator.init(etype, emitting_node=SERVER, add_generates_event=first)
                first = False
                condition = Condition(device, kind, node.nodeid, generator)
                self._initial(condition)
                table[name] = self.conditions[node.nodeid] = condition
        session = self.server.iserver.isession
        session.add_method_callback(ACKNOWLEDGE, self.acknowledge)
        session.add_method_callback(CONFIRM, self.confirm)

    def _initial(self, c: Condition) -> None:
        condition_fields(c.generator.event, c.device, c.name, c.node)

    # -- from the polls ---------------------------------------------------------------------------------------

    async def on_sample(self, device: DeviceNodes, sample: Sample) -> None:
        name = device.config.name
        offline = self.offline.get(name)
        if offline is not None and offline.active == sample.online:
            message = f"{name}: offline: {sample.error}" if not sample.online else f"{name}: answers again"
            await self._transition(offline, not sample.online, message, sample.time)
        fault = self.fault.get(name)
        status = sample.status
        if fault is None or status is None:
            return
        if not status.fault:
            keys = current_keys(device)
            self._last_currents[name] = [float(sample.values[k].value) for k in keys if k in sample.values]
            if fault.active:
                await self._transition(fault, False, f"{name}: fault reset", sample.time)
            return
        if fault.active:
            return
        code = status.fault_code or 0
        text = fault_text(device, code, self.locale)
        event = fault.generator.event
        event.FaultCode = code
        event.FaultText = text
        event.CurrentsBeforeTrip = self._last_currents.get(name, [])
        await self._transition(fault, True, f"{name}: fault {code}: {text.Text}", sample.time)

    async def _transition(self, c: Condition, active: bool, message: str, at: float) -> None:
        c.active = active
        if active:
            c.acked = c.confirmed = False
        await self._fire(c, message, datetime.fromtimestamp(at, timezone.utc))

    async def _fire(self, c: Condition, message: str, at: datetime | None = None) -> None:
        event = c.generator.event
        two_state(event, "ActiveState", c.active, "Active", "Inactive")
        two_state(event, "AckedState", c.acked, "Acknowledged", "Unacknowledged")
        two_state(event, "ConfirmedState", c.confirmed, "Confirmed", "Unconfirmed")
        event.Retain = c.retained
        event.Quality = ua.StatusCode()
        await c.generator.trigger(time_attr=at, message=message)
        c.event_id = bytes(event.EventId.Value)
        log.info("alarm %s.%s: %s (active %s, acked %s, confirmed %s)", c.device.config.name, c.name, message,
                 c.active, c.acked, c.confirmed)  # fmt: skip

    # -- the standard methods -----------------------------------------------------------------------------------

    async def acknowledge(self, parent: ua.NodeId, event_id: ua.Variant, comment: ua.Variant) -> ua.StatusCode:
        return await self._respond(parent, event_id, comment, confirm=False)

    async def confirm(self, parent: ua.NodeId, event_id: ua.Variant, comment: ua.Variant) -> ua.StatusCode:
        return await self._respond(parent, event_id, comment, confirm=True)

    async def _respond(
        self, parent: ua.NodeId, event_id: ua.Variant, comment: ua.Variant, *, confirm: bool
    ) -> ua.StatusCode:
        actor = self.operator()
        if actor is None:
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        c = self.conditions.get(parent)
        if c is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        if c.event_id is None or bytes(event_id.Value or b"") != c.event_id:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        if confirm:
            if c.confirmed:
                return ua.StatusCode(ua.StatusCodes.BadConditionBranchAlreadyConfirmed)
            c.confirmed = True
        else:
            if c.acked:
                return ua.StatusCode(ua.StatusCodes.BadConditionBranchAlreadyAcked)
            c.acked = True
        text = comment.Value.Text if isinstance(comment.Value, ua.LocalizedText) else ""
        event = c.generator.event
        event.Comment = ua.LocalizedText(text or "", "en")
        event.ClientUserId = actor
        verb = "confirmed" if confirm else "acknowledged"
        await self._fire(c, f"{c.device.config.name}: {c.name} {verb} by {actor}" + (f": {text}" if text else ""))
        return ua.StatusCode()
