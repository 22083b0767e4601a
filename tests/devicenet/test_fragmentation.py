"""The fragmentation protocol, both directions, with acknowledgements (docs/manuals.md#fragmentation)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.transports.devicenet.codec.cip import FragmentError, FrameTooShortError, UnexpectedFrameError
from starterbus.transports.devicenet.codec.fragmentation import (
    AckStatus,
    Fragmenter,
    FragmentOverflowError,
    FragmentType,
    Reassembler,
    ack,
    decode_fragment,
    frames_for,
    split,
)

# The JJR8000 answer to Get_Attribute_Single identity attribute 7 (product name "JJR8000"): 10 bytes
PRODUCT_NAME_RESPONSE = bytes.fromhex("00 8E 07 4A 4A 52 38 30 30 30")
PRODUCT_NAME_FRAGMENTS = [bytes.fromhex("80 00 8E 07 4A 4A 52 38"), bytes.fromhex("80 81 30 30 30")]
PRODUCT_NAME_ACKS = [bytes.fromhex("80 C0 00"), bytes.fromhex("80 C1 00")]


def test_product_name_is_split_in_two_fragments() -> None:
    assert split(PRODUCT_NAME_RESPONSE) == PRODUCT_NAME_FRAGMENTS
    assert frames_for(PRODUCT_NAME_RESPONSE) == PRODUCT_NAME_FRAGMENTS
    assert frames_for(PRODUCT_NAME_RESPONSE[:8]) == [PRODUCT_NAME_RESPONSE[:8]]


def test_rockwell_example_frames_decode() -> None:
    """Slave 41B: 80 00 B2 ..., master ack 41C: 80 C0 00, slave 41B: 80 81 0D 05 04, ack 80 C1 00."""
    first = decode_fragment(bytes.fromhex("80 00 B2"))
    assert (first.kind, first.count, first.payload) == (FragmentType.FIRST, 0, b"\xb2")
    last = decode_fragment(bytes.fromhex("80 81 0D 05 04"))
    assert (last.kind, last.count, last.payload) == (FragmentType.LAST, 1, bytes.fromhex("0D 05 04"))
    acknowledgement = decode_fragment(bytes.fromhex("80 C1 00"))
    assert acknowledgement.is_ack and acknowledgement.count == 1 and acknowledgement.ack_status == 0
    assert ack(0x80, 1) == bytes.fromhex("80 C1 00")


def test_sender_and_receiver_with_acknowledgements() -> None:
    sender = Fragmenter(PRODUCT_NAME_RESPONSE)
    receiver = Reassembler()
    assert sender.current == PRODUCT_NAME_FRAGMENTS[0]
    reply, whole = receiver.feed(sender.current)
    assert (reply, whole) == (PRODUCT_NAME_ACKS[0], None)
    following = sender.on_ack(reply)
    assert following == PRODUCT_NAME_FRAGMENTS[1]
    reply, whole = receiver.feed(following)
    assert (reply, whole) == (PRODUCT_NAME_ACKS[1], PRODUCT_NAME_RESPONSE)
    assert sender.on_ack(reply) is None and sender.done


def test_sender_ignores_stale_and_refused_acks() -> None:
    sender = Fragmenter(PRODUCT_NAME_RESPONSE)
    assert sender.on_ack(bytes.fromhex("80 C5 00")) is None  # wrong count: a stale acknowledgement
    assert sender.index == 0
    with pytest.raises(FragmentError) as info:
        sender.on_ack(bytes.fromhex("80 C0 01"))  # too much data
    assert info.value.general_status == 0x15
    assert sender.done
    with pytest.raises(UnexpectedFrameError):
        Fragmenter(PRODUCT_NAME_RESPONSE).on_ack(PRODUCT_NAME_FRAGMENTS[0])  # not an ack


def test_repeated_fragment_is_acknowledged_again_not_appended() -> None:
    receiver = Reassembler()
    receiver.feed(PRODUCT_NAME_FRAGMENTS[0])
    assert receiver.feed(PRODUCT_NAME_FRAGMENTS[0]) == (PRODUCT_NAME_ACKS[0], None)  # a first restarts the series
    middle = bytes.fromhex("80 41 01 02 03 04 05 06")
    receiver.feed(middle)
    assert receiver.feed(middle) == (ack(0x80, 1), None)  # the sender missed our ack
    _, whole = receiver.feed(bytes.fromhex("80 82 07"))
    assert whole == bytes.fromhex("00 8E 07 4A 4A 52 38 01 02 03 04 05 06 07")


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        (["80 41 01"], "without a first fragment"),
        (["80 81 01"], "without a first fragment"),
        (["80 00 01", "80 42 02"], "out of order (expected 1)"),
        (["80 00 01", "80 83 02"], "out of order (expected 1)"),
        (["80 00 01", "C0 41 02"], "another transaction"),
    ],
)
def test_out_of_order_fragments_raise(frames: list[str], message: str) -> None:
    receiver = Reassembler()
    for text in frames[:-1]:
        receiver.feed(bytes.fromhex(text))
    with pytest.raises(FragmentError) as info:
        receiver.feed(bytes.fromhex(frames[-1]))
    assert message in str(info.value)
    assert info.value.general_status == 0x06  # partial transfer
    assert info.value.data == bytes.fromhex(frames[-1])
    assert not receiver.in_progress  # the series was dropped


def test_overflow_answers_too_much_data() -> None:
    receiver = Reassembler(max_message=10)
    receiver.feed(bytes.fromhex("80 00 01 02 03 04 05 06"))
    with pytest.raises(FragmentOverflowError) as info:
        receiver.feed(bytes.fromhex("80 41 07 08 09 0A 0B 0C"))
    assert info.value.ack == ack(0x80, 1, AckStatus.TOO_MUCH_DATA) == bytes.fromhex("80 C1 01")


def test_too_short_fragments() -> None:
    with pytest.raises(FrameTooShortError):
        decode_fragment(b"\x80")
    with pytest.raises(FrameTooShortError):
        decode_fragment(b"\x80\xc0")  # ack without status
    with pytest.raises(UnexpectedFrameError):
        decode_fragment(b"\x00\x00")  # fragment bit clear
    with pytest.raises(UnexpectedFrameError):
        Reassembler().feed(bytes.fromhex("80 C0 00"))


def test_count_wraps_modulo_64() -> None:
    message = bytes([0]) + bytes(range(200)) + bytes(range(200))
    frames = split(message)
    assert len(frames) > 64
    assert [f[1] & 0x3F for f in frames[62:66]] == [62, 63, 0, 1]
    receiver = Reassembler(max_message=1000)
    results = [receiver.feed(f)[1] for f in frames]
    assert results[-1] == message and all(r is None for r in results[:-1])


@given(st.integers(0, 63), st.integers(0, 1), st.binary(min_size=8, max_size=300))
def test_round_trip_through_sender_and_receiver(mac: int, xid: int, body: bytes) -> None:
    message = bytes((mac | xid << 6,)) + body
    sender = Fragmenter(message)
    receiver = Reassembler(max_message=400)
    frame: bytes | None = sender.current
    whole = None
    count = 0
    while frame is not None:
        assert len(frame) <= 8
        reply, whole = receiver.feed(frame)
        frame = sender.on_ack(reply)
        count += 1
    assert sender.done
    assert whole == message
    assert count == len(split(message))
