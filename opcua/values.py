"""One poll -> the DataValues of a device's variables (pure): source time from the poll, Bad codes, never stale."""

from __future__ import annotations

from datetime import datetime, timezone

from asyncua import ua

from starterbus.fleet.poller import Sample
from starterbus.opcua.address_space import STATES, STATUS_VARIABLES, DeviceHealth, DeviceNodes, PointNode, texts


def _timestamp(seconds: float) -> datetime:
    return datetime.fromtimestamp(seconds, timezone.utc)


def _bad(code: int, at: datetime) -> ua.DataValue:
    return ua.DataValue(StatusCode=ua.StatusCode(code), SourceTimestamp=at, ServerTimestamp=datetime.now(timezone.utc))


def _good(variant: ua.Variant, at: datetime) -> ua.DataValue:
    return ua.DataValue(variant, SourceTimestamp=at, ServerTimestamp=datetime.now(timezone.utc))


Update = tuple[ua.NodeId, ua.DataValue]


def initial_updates(device: DeviceNodes, at: float) -> list[Update]:
    """Before the first poll: every live value BadWaitingForInitialData."""
    when = _timestamp(at)
    code = ua.StatusCodes.BadWaitingForInitialData
    nodes = [device.status[k] for k in (*STATUS_VARIABLES, "Online", "DeviceHealth")]
    nodes += [n for p in device.points.values() for n in _nodes(p)]
    return [(n, _bad(code, when)) for n in nodes]


def sample_updates(device: DeviceNodes, sample: Sample, locale: str = "en") -> list[Update]:
    """The DataValues one poll sets: values with the poll's time, or Bad codes, never a stale Good value."""
    at = _timestamp(sample.time)
    status_ids = device.status
    updates: list[Update] = [
        (status_ids["Online"], _good(ua.Variant(sample.online, ua.VariantType.Boolean), at)),
        (status_ids["LastError"], _good(ua.Variant(sample.error or "", ua.VariantType.String), at)),
    ]
    status = sample.status
    if not sample.online:
        missing = ua.StatusCodes.BadCommunicationError
    elif status is None and sample.error is not None:
        missing = ua.StatusCodes.BadDeviceFailure
    else:
        missing = ua.StatusCodes.BadNotSupported  # the transport does not report it
    if status is None:
        updates += [(status_ids[k], _bad(missing, at)) for k in (*STATUS_VARIABLES, "DeviceHealth")]
    else:
        code = status.fault_code if status.fault_code is not None else 0
        label = device.profile.faults.label(code) if status.fault else None
        fault_text = ua.LocalizedText("")
        if label is not None:
            fault_text = texts(label.en, label.zh, locale)[0]
        health = DeviceHealth.FAILURE if status.fault else DeviceHealth.NORMAL
        updates += [
            (status_ids["State"], _good(ua.Variant(STATES.index(status.state), ua.VariantType.Int32), at)),
            (status_ids["Fault"], _good(ua.Variant(status.fault, ua.VariantType.Boolean), at)),
            (status_ids["FaultCode"], _good(ua.Variant(code, ua.VariantType.UInt16), at)),
            (status_ids["FaultText"], _good(ua.Variant(fault_text, ua.VariantType.LocalizedText), at)),
            (status_ids["DeviceHealth"], _good(ua.Variant(int(health), ua.VariantType.Int32), at)),
        ]
        for key, flag in (("Ready", status.ready), ("BusControl", status.bus_control)):
            shown = _bad(ua.StatusCodes.BadNotSupported, at) if flag is None else _good(ua.Variant(flag), at)
            updates.append((status_ids[key], shown))
    for key, point_node in device.points.items():
        value = sample.values.get(key)
        if value is not None:
            updates += point_updates(point_node, value.raw, value.value, at, locale)
            continue
        if key in sample.unreadable:
            bad = _bad(ua.StatusCodes.BadNotSupported, at)
        else:
            bad = _bad(missing if sample.error else ua.StatusCodes.BadNoData, at)
        updates += [(node, bad) for node in _nodes(point_node)]
    return updates


def _nodes(point_node: PointNode) -> list[ua.NodeId]:
    """The variable and, for an enum, its ValueAsText: both go Bad together."""
    return [point_node.node] + ([point_node.value_as_text] if point_node.value_as_text is not None else [])


def point_updates(point_node: PointNode, raw: int, value: float, at: datetime, locale: str = "en") -> list[Update]:
    point = point_node.point
    if point.enum is not None or point.bits:
        updates = [(point_node.node, _good(ua.Variant(raw, ua.VariantType.UInt16), at))]
        if point_node.value_as_text is not None and point.enum is not None:
            label = point.enum.label(raw)
            text = texts(label.en, label.zh, locale)[0] if label else ua.LocalizedText(f"unknown value {raw}")
            updates.append((point_node.value_as_text, _good(ua.Variant(text, ua.VariantType.LocalizedText), at)))
        return updates
    return [(point_node.node, _good(ua.Variant(float(value), ua.VariantType.Double), at))]


def timestamp_now() -> datetime:
    return datetime.now(timezone.utc)
