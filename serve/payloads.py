"""Encoding the edge node's payloads and reading the host's commands (Sparkplug B section 4, 6, 8)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from starterbus.serve.metrics import BDSEQ, QUALITY, MetricDef, Property, Scalar
from starterbus.serve.schema import WRITERS, DataType, Payload, from_wire, to_wire, value_field

#: one metric value to publish: its definition, the value (None: null) and its acquisition time in ms
Entry = tuple[MetricDef, "Scalar | None", int]


def _set_value(target: Any, datatype: DataType, value: Scalar | None) -> None:
    if value is None:
        target.is_null = True
    else:
        setattr(target, value_field(datatype), to_wire(datatype, value))


def _add_properties(target: Any, properties: Iterable[Property]) -> None:
    """Fill a PropertySet; a PROPERTYSET value nests another set (payloads-propertyset-*: keys and values pair)."""
    for key, ptype, pvalue in properties:
        target.keys.append(key)
        value = target.values.add(type=int(ptype))
        if isinstance(pvalue, tuple):
            _add_properties(value.propertyset_value, pvalue)
        else:
            _set_value(value, ptype, pvalue)


def encode(
    entries: Iterable[Entry],
    *,
    timestamp: int,
    seq: int | None,
    birth: bool,
    historical: bool = False,
    quality: Mapping[str, int] | None = None,
) -> bytes:
    """A payload: in a BIRTH every metric has name, alias, datatype and properties; in DATA only the alias.

    ``quality``: metric name -> the Sparkplug ``Quality`` property to attach (Int32: 192 good, 0 bad)."""
    if not (birth or historical or quality):  # the DDATA of every sample: the metrics made in one call
        metrics: list[dict[str, object]] = []
        for defn, value, ts in entries:
            alias = defn.alias
            fields: dict[str, object] = (
                {"timestamp": ts, "name": defn.name} if alias is None else {"timestamp": ts, "alias": alias}
            )
            if value is None:
                fields["is_null"] = True
            else:
                field, wire = WRITERS[defn.datatype]
                fields[field] = wire(value)
            metrics.append(fields)
        return encode_fields(metrics, timestamp=timestamp, seq=seq)
    payload = Payload(timestamp=timestamp)
    if seq is not None:
        payload.seq = seq
    add = payload.metrics.add
    quality = quality or {}
    for defn, value, ts in entries:
        metric = add(timestamp=ts)
        if birth or defn.alias is None:
            metric.name = defn.name
        if defn.alias is not None:
            metric.alias = defn.alias
        properties: list[Property] = list(defn.properties) if birth else []
        if defn.name in quality:
            properties.append((QUALITY, DataType.INT32, quality[defn.name]))
        if birth:
            metric.datatype = int(defn.datatype)
        if properties:
            _add_properties(metric.properties, properties)
        if historical:
            metric.is_historical = True
        _set_value(metric, defn.datatype, value)
    return bytes(payload.SerializeToString())


def encode_fields(metrics: list[dict[str, object]], *, timestamp: int, seq: int | None) -> bytes:
    """A DATA payload of metrics given as protobuf's field dicts (``{"timestamp": ..., "alias": ..., FIELD:
    value}``), made in one constructor call."""
    if seq is None:
        return bytes(Payload(timestamp=timestamp, metrics=metrics).SerializeToString())
    return bytes(Payload(timestamp=timestamp, metrics=metrics, seq=seq).SerializeToString())


def encode_ndeath(bdseq: int) -> bytes:
    """The Will: exactly one metric, bdSeq as Int64, no seq (topics-ndeath-payload)."""
    payload = Payload()
    payload.metrics.add(name=BDSEQ, datatype=int(DataType.INT64), long_value=bdseq)
    return bytes(payload.SerializeToString())


@dataclass(frozen=True, slots=True)
class CommandMetric:
    """One metric of an NCMD/DCMD: how it was named, its timestamp (ms, or None) and its value."""

    name: str | None
    alias: int | None
    timestamp: int | None
    field: str | None  # which value field the sender set (None: is_null or nothing)
    raw: object


@dataclass(frozen=True, slots=True)
class CommandPayload:
    timestamp: int | None
    metrics: tuple[CommandMetric, ...]


class BadCommandPayload(ValueError):
    """A command payload that is not a Sparkplug B payload."""


def decode_command(data: bytes) -> CommandPayload:
    payload = Payload()
    try:
        payload.ParseFromString(data)
    except Exception as exc:  # protobuf's DecodeError has no stable public home across versions
        raise BadCommandPayload(f"not a Sparkplug B payload ({len(data)} bytes): {exc}") from None
    metrics = []
    for m in payload.metrics:
        which = m.WhichOneof("value")
        metrics.append(
            CommandMetric(
                name=m.name if m.HasField("name") else None,
                alias=m.alias if m.HasField("alias") else None,
                timestamp=m.timestamp if m.HasField("timestamp") else None,
                field=None if m.is_null else which,
                raw=getattr(m, which) if which else None,
            )
        )
    return CommandPayload(payload.timestamp if payload.HasField("timestamp") else None, tuple(metrics))


def command_value(defn: MetricDef, metric: CommandMetric) -> Scalar:
    """The value a command metric carries, checked against the metric's type in the BIRTH (commands-*-value)."""
    expected = value_field(defn.datatype)
    if metric.field != expected:
        got = metric.field or "no value"
        raise ValueError(f"{defn.name}: expected {defn.datatype.name.lower()} in {expected}, got {got}")
    value = from_wire(defn.datatype, metric.raw)
    assert isinstance(value, (bool, int, float, str))
    return value
