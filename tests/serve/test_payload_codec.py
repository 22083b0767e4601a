"""starterbus's schema (written from the specification) against Eclipse Tahu's (tahutils): wire-compatible for
every data type serve uses, signed integers wrapped and restored, and any bytes as a command payload either
decode or raise the one typed error."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st
from tahutils.tahu import sparkplug_b_pb2 as tahu

from starterbus.serve.metrics import MetricDef, Scalar
from starterbus.serve.payloads import BadCommandPayload, command_value, decode_command, encode
from starterbus.serve.schema import DataType, from_wire

RANGES = {
    DataType.INT8: (-(2**7), 2**7 - 1),
    DataType.INT16: (-(2**15), 2**15 - 1),
    DataType.INT32: (-(2**31), 2**31 - 1),
    DataType.INT64: (-(2**63), 2**63 - 1),
    DataType.UINT8: (0, 2**8 - 1),
    DataType.UINT16: (0, 2**16 - 1),
    DataType.UINT32: (0, 2**32 - 1),
    DataType.UINT64: (0, 2**64 - 1),
}


TYPED = st.one_of(
    *[st.tuples(st.just(datatype), st.integers(lo, hi)) for datatype, (lo, hi) in RANGES.items()],
    st.tuples(st.just(DataType.DOUBLE), st.floats(allow_nan=False)),
    st.tuples(st.just(DataType.BOOLEAN), st.booleans()),
    st.tuples(st.just(DataType.STRING), st.text(max_size=20)),
)


def typed_values() -> st.SearchStrategy[tuple[DataType, Scalar]]:
    return TYPED


@given(st.lists(typed_values(), min_size=1, max_size=5), st.booleans(), st.integers(0, 255))
def test_tahu_reads_what_starterbus_writes(values: list[tuple[DataType, Scalar]], birth: bool, seq: int) -> None:
    defs = [
        MetricDef(f"m{i}", datatype, i + 1, (("engUnit", DataType.STRING, "A"),))
        for i, (datatype, _) in enumerate(values)
    ]
    data = encode(
        [(d, v, 1000 + i) for i, (d, (_, v)) in enumerate(zip(defs, values, strict=True))],
        timestamp=5,
        seq=seq,
        birth=birth,
    )
    payload = tahu.Payload()
    payload.ParseFromString(data)
    assert (payload.timestamp, payload.seq) == (5, seq)
    for i, (metric, (datatype, value)) in enumerate(zip(payload.metrics, values, strict=True)):
        assert metric.alias == i + 1 and metric.timestamp == 1000 + i
        assert (metric.name, metric.datatype) == ((f"m{i}", datatype) if birth else ("", 0))
        if birth:
            assert list(metric.properties.keys) == ["engUnit"] and metric.properties.values[0].string_value == "A"
        got = from_wire(datatype, getattr(metric, metric.WhichOneof("value")))
        assert got == value or (isinstance(value, float) and math.isclose(float(got), value))  # type: ignore[arg-type]


@given(typed_values())
def test_starterbus_reads_what_tahu_writes(typed: tuple[DataType, Scalar]) -> None:
    datatype, value = typed
    field = {DataType.DOUBLE: "double_value", DataType.BOOLEAN: "boolean_value", DataType.STRING: "string_value"}
    name = field.get(datatype) or ("long_value" if datatype in (DataType.INT64, DataType.UINT64) else "int_value")
    payload = tahu.Payload(timestamp=7)
    metric = payload.metrics.add(name="x", datatype=int(datatype), timestamp=9)
    setattr(
        metric,
        name,
        value % 2 ** (64 if name == "long_value" else 32)
        if isinstance(value, int) and not isinstance(value, bool)
        else value,
    )
    (decoded,) = decode_command(payload.SerializeToString()).metrics
    assert (decoded.name, decoded.timestamp, decoded.field) == ("x", 9, name)
    assert command_value(MetricDef("x", datatype, None), decoded) == value


@given(st.binary(max_size=200))
def test_any_bytes_decode_or_raise_the_typed_error(data: bytes) -> None:
    try:
        decode_command(data)
    except BadCommandPayload as exc:
        assert f"{len(data)} bytes" in str(exc)
