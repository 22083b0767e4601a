"""The Sparkplug B payload schema (Eclipse Sparkplug 3.0, package org.eclipse.tahu.protobuf), built in code.

Written from the specification's field table (docs: SPARKPLUG.md section 8), not copied from Tahu's .proto:
only the messages and fields an edge node of starter data uses. DataSet, Template and MetaData keep their
field numbers free, so a full decoder reads these payloads unchanged (the tests check with Tahu's own schema).
The descriptor lives in a private pool, so another copy of the schema in the process never clashes with it.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

PACKAGE = "org.eclipse.tahu.protobuf"

_F = descriptor_pb2.FieldDescriptorProto
_OPT, _REP = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED
_U64, _U32, _BOOL, _STR, _BYTES = _F.TYPE_UINT64, _F.TYPE_UINT32, _F.TYPE_BOOL, _F.TYPE_STRING, _F.TYPE_BYTES
_FLOAT, _DOUBLE, _MSG = _F.TYPE_FLOAT, _F.TYPE_DOUBLE, _F.TYPE_MESSAGE


class DataType(enum.IntEnum):
    """Sparkplug B metric data types (section 8); the ones starterbus publishes and accepts."""

    INT8 = 1
    INT16 = 2
    INT32 = 3
    INT64 = 4
    UINT8 = 5
    UINT16 = 6
    UINT32 = 7
    UINT64 = 8
    FLOAT = 9
    DOUBLE = 10
    BOOLEAN = 11
    STRING = 12
    DATETIME = 13
    TEXT = 14
    PROPERTYSET = 20  # properties only: a nested set (an enum's labels)


INT_TYPES = {DataType.INT8, DataType.INT16, DataType.INT32, DataType.UINT8, DataType.UINT16, DataType.UINT32}
LONG_TYPES = {DataType.INT64, DataType.UINT64, DataType.DATETIME}
WIDTH = {DataType.INT8: 8, DataType.INT16: 16, DataType.INT32: 32, DataType.INT64: 64}


def _field(name: str, number: int, ftype: int, label: int = _OPT, type_name: str = "", oneof: int | None = None) -> Any:
    field = _F(name=name, number=number, type=ftype, label=label)
    if type_name:
        field.type_name = f".{PACKAGE}.Payload.{type_name}"
    if oneof is not None:
        field.oneof_index = oneof
    return field


def _values(first: int, oneof: int) -> list[Any]:
    """The typed value fields shared by Metric and PropertyValue, numbered from ``first``."""
    kinds = [("int_value", _U32), ("long_value", _U64), ("float_value", _FLOAT), ("double_value", _DOUBLE)]
    kinds += [("boolean_value", _BOOL), ("string_value", _STR)]
    return [_field(name, first + i, ftype, oneof=oneof) for i, (name, ftype) in enumerate(kinds)]


def _build() -> tuple[Any, Any]:
    file = descriptor_pb2.FileDescriptorProto(name="starterbus/sparkplug_b.proto", package=PACKAGE, syntax="proto2")
    payload = file.message_type.add(name="Payload")
    payload.field.extend(
        [
            _field("timestamp", 1, _U64),
            _field("metrics", 2, _MSG, _REP, "Metric"),
            _field("seq", 3, _U64),
            _field("uuid", 4, _STR),
            _field("body", 5, _BYTES),
        ]
    )
    prop_value = payload.nested_type.add(name="PropertyValue")
    prop_value.field.extend(
        [
            _field("type", 1, _U32),
            _field("is_null", 2, _BOOL),
            *_values(3, 0),
            _field("propertyset_value", 9, _MSG, type_name="PropertySet", oneof=0),
        ]
    )
    prop_value.oneof_decl.add(name="value")
    prop_set = payload.nested_type.add(name="PropertySet")
    prop_set.field.extend([_field("keys", 1, _STR, _REP), _field("values", 2, _MSG, _REP, "PropertyValue")])
    metric = payload.nested_type.add(name="Metric")
    metric.field.extend(
        [
            _field("name", 1, _STR),
            _field("alias", 2, _U64),
            _field("timestamp", 3, _U64),
            _field("datatype", 4, _U32),
            _field("is_historical", 5, _BOOL),
            _field("is_transient", 6, _BOOL),
            _field("is_null", 7, _BOOL),
            _field("properties", 9, _MSG, type_name="PropertySet"),
            *_values(10, 0),
            _field("bytes_value", 16, _BYTES, oneof=0),
        ]
    )
    metric.oneof_decl.add(name="value")
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file)
    desc = pool.FindMessageTypeByName(f"{PACKAGE}.Payload")
    return message_factory.GetMessageClass(desc), desc


Payload, DESCRIPTOR = _build()


_FIELDS: dict[int, str] = {
    **{t.value: "int_value" for t in INT_TYPES},
    **{t.value: "long_value" for t in LONG_TYPES},
    DataType.FLOAT.value: "float_value",
    DataType.DOUBLE.value: "double_value",
    DataType.BOOLEAN.value: "boolean_value",
    DataType.STRING.value: "string_value",
    DataType.TEXT.value: "string_value",
    DataType.PROPERTYSET.value: "propertyset_value",
}
_MASKS = {t.value: (1 << WIDTH.get(t, 32 if t in INT_TYPES else 64)) - 1 for t in INT_TYPES | LONG_TYPES}


def value_field(datatype: int) -> str:
    """The Metric/PropertyValue field that carries a value of this data type."""
    return _FIELDS[datatype]


def to_wire(datatype: int, value: object) -> object:
    """A Python value as its field holds it: signed integers wrap modulo 2^width (two's complement)."""
    mask = _MASKS.get(datatype)
    if mask is not None:
        return int(value) & mask  # type: ignore[call-overload]
    if datatype == DataType.BOOLEAN:
        return bool(value)
    if datatype in (DataType.FLOAT, DataType.DOUBLE):
        return float(value)  # type: ignore[arg-type]
    return str(value)


def _writer(datatype: int) -> Callable[[Any], object]:
    """:func:`to_wire` for one data type."""
    mask = _MASKS.get(datatype)
    if mask is not None:
        return lambda value: int(value) & mask
    if datatype == DataType.BOOLEAN:
        return bool
    if datatype in (DataType.FLOAT, DataType.DOUBLE):
        return float
    return str


#: data type -> (:func:`value_field`, :func:`to_wire`) for it: one look-up per value when encoding many
WRITERS: dict[int, tuple[str, Callable[[Any], object]]] = {t: (f, _writer(t)) for t, f in _FIELDS.items()}


def from_wire(datatype: int, raw: object) -> object:
    """The inverse of :func:`to_wire`: mask to the width, then apply the sign (SPARKPLUG.md pitfalls)."""
    if datatype in WIDTH:
        bits = WIDTH[DataType(datatype)]
        number = int(raw) & ((1 << bits) - 1)  # type: ignore[call-overload]
        return number - (1 << bits) if number >> (bits - 1) else number
    return raw
