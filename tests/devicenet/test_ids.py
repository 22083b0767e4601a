"""CAN identifiers of message groups 1-4 (docs/manuals.md#can-identifiers; the Rockwell
fragment example uses MAC 3)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core import DecodeError, EncodeError
from starterbus.transports.devicenet.codec import ids
from starterbus.transports.devicenet.codec.ids import DeviceNetId, Group, build_id, parse_id

# (identifier, group, message id, MAC) - docs/manuals.md#can-identifiers and the predefined set for slave 5
VECTORS = [
    (0x3C5, Group.GROUP_1, 15, 5),  # slave poll response 0x3C0 + S
    (0x42D, Group.GROUP_2, 5, 5),  # master poll command 0x405 + 8 S
    (0x42C, Group.GROUP_2, 4, 5),  # master explicit request 0x404 + 8 S
    (0x42B, Group.GROUP_2, 3, 5),  # slave explicit response 0x403 + 8 S
    (0x42E, Group.GROUP_2, 6, 5),  # group 2 only unconnected request 0x406 + 8 S
    (0x42F, Group.GROUP_2, 7, 5),  # duplicate MAC ID check 0x407 + 8 own
    (0x407, Group.GROUP_2, 7, 0),  # the master's own check at MAC 0
    (0x41B, Group.GROUP_2, 3, 3),  # Rockwell fragment example: slave response
    (0x41C, Group.GROUP_2, 4, 3),  # ... and the master's acknowledgement
    (0x000, Group.GROUP_1, 0, 0),
    (0x3FF, Group.GROUP_1, 15, 63),
    (0x5FF, Group.GROUP_2, 7, 63),
    (0x600, Group.GROUP_3, 0, 0),
    (0x7BF, Group.GROUP_3, 6, 63),
    (0x7C0, Group.GROUP_4, 0, None),
    (0x7EF, Group.GROUP_4, 0x2F, None),
]


@pytest.mark.parametrize(("can_id", "group", "message_id", "mac"), VECTORS)
def test_vectors_build_and_parse(can_id: int, group: Group, message_id: int, mac: int | None) -> None:
    assert build_id(group, message_id, mac) == can_id
    assert parse_id(can_id) == DeviceNetId(group, message_id, mac)
    assert parse_id(can_id).can_id == can_id


def test_predefined_set_helpers() -> None:
    assert ids.poll_response_id(5) == 0x3C5
    assert ids.poll_command_id(5) == 0x42D
    assert ids.explicit_request_id(5) == 0x42C
    assert ids.explicit_response_id(5) == 0x42B
    assert ids.unconnected_request_id(5) == 0x42E
    assert ids.duplicate_mac_id(5) == 0x42F


@pytest.mark.parametrize("can_id", [0x7F0, 0x7FF, 0x800, -1, 0x1FFFFFFF])
def test_invalid_identifiers(can_id: int) -> None:
    with pytest.raises(DecodeError):
        parse_id(can_id)


@pytest.mark.parametrize(
    ("group", "message_id", "mac"),
    [(1, 16, 0), (2, 8, 0), (3, 7, 0), (4, 0x30, None), (1, 0, 64), (2, 0, -1), (4, 0, 5), (2, 0, None)],
)
def test_build_refuses(group: int, message_id: int, mac: int | None) -> None:
    with pytest.raises(EncodeError):
        build_id(group, message_id, mac)


def test_describe_names_the_message() -> None:
    assert "poll response" in parse_id(0x3C5).describe()
    assert "duplicate MAC ID check" in parse_id(0x42F).describe()
    assert parse_id(0x7C1).describe() == "group 4 message id 1"


@given(st.integers(0, 0x7EF))
def test_every_valid_identifier_round_trips(can_id: int) -> None:
    parsed = parse_id(can_id)
    assert build_id(parsed.group, parsed.message_id, parsed.mac) == can_id


@given(st.sampled_from([1, 2, 3]), st.integers(0, 63), st.data())
def test_round_trip_from_fields(group: int, mac: int, data: st.DataObject) -> None:
    limit = {1: 15, 2: 7, 3: 6}[group]
    message_id = data.draw(st.integers(0, limit))
    assert parse_id(build_id(group, message_id, mac)) == DeviceNetId(Group(group), message_id, mac)
