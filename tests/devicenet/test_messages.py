"""Duplicate MAC ID check messages, identity attributes, candump frames."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core import CanFrame, DecodeError, EncodeError, Profile
from starterbus.transports.devicenet.codec.cip import FrameTooLongError, FrameTooShortError, UnexpectedFrameError
from starterbus.transports.devicenet.codec.dupmac import DuplicateMacCheck, decode_duplicate_mac, is_duplicate_mac
from starterbus.transports.devicenet.codec.frames import parse_candump
from starterbus.transports.devicenet.codec.identity import Identity, decode_attribute, decode_identity
from starterbus.transports.devicenet.settings import profile_identity


def test_jjr8000_duplicate_mac_vector() -> None:
    """docs/manuals.md#duplicate-mac-id-check: the JJR8000 (vendor 819 = 0x0333) sends 00 33 03 s0 s1 s2 s3."""
    message = DuplicateMacCheck(5, False, 819, 0x44332211)
    assert message.frame() == CanFrame(0x42F, bytes.fromhex("00 33 03 11 22 33 44"))
    assert decode_duplicate_mac(message.frame()) == message
    response = DuplicateMacCheck(5, True, 819, 0x44332211, port=2)
    assert response.data()[0] == 0x82
    assert decode_duplicate_mac(response.frame()) == response
    assert is_duplicate_mac(message.frame()) and not is_duplicate_mac(CanFrame(0x42E))


def test_duplicate_mac_errors() -> None:
    with pytest.raises(FrameTooShortError):
        decode_duplicate_mac(CanFrame(0x42F, bytes(6)))
    with pytest.raises(FrameTooLongError):
        decode_duplicate_mac(CanFrame(0x42F, bytes(8)))
    with pytest.raises(UnexpectedFrameError):
        decode_duplicate_mac(CanFrame(0x42E, bytes(7)))
    with pytest.raises(EncodeError):
        DuplicateMacCheck(5, False, 0x10000, 0).data()


@given(st.integers(0, 63), st.booleans(), st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF), st.integers(0, 127))
def test_duplicate_mac_round_trip(mac: int, response: bool, vendor: int, serial: int, port: int) -> None:
    message = DuplicateMacCheck(mac, response, vendor, serial, port)
    assert decode_duplicate_mac(message.frame()) == message


def test_identity_attributes_as_the_manual_says(jjr8000: Profile) -> None:
    identity = profile_identity(jjr8000, serial_number=0x01020304)
    assert identity.attribute(1) == bytes.fromhex("33 03")  # vendor 819
    assert identity.attribute(2) == bytes.fromhex("2D 00")  # device type 45 (0x2D)
    assert identity.attribute(7) == b"\x07JJR8000"  # SHORT_STRING
    assert identity.attribute(6) == bytes.fromhex("04 03 02 01")
    assert identity.attribute(8) is None
    raw = {n: identity.attribute(n) or b"" for n in range(1, 8)}
    assert decode_identity(raw) == identity
    assert identity.attributes_all() == b"".join(raw[n] for n in range(1, 8))
    assert profile_identity(jjr8000, product_name="JJR8000-X").product_name == "JJR8000-X"


@pytest.mark.parametrize(
    ("number", "data", "error"),
    [(1, b"\x33", FrameTooShortError), (1, b"\x33\x03\x00", FrameTooLongError), (7, b"\x07JJR", FrameTooShortError),
     (7, b"\x02JJR", FrameTooLongError), (7, b"", FrameTooShortError), (4, b"\x01", FrameTooShortError)],
)  # fmt: skip
def test_identity_attribute_length_errors(number: int, data: bytes, error: type[DecodeError]) -> None:
    with pytest.raises(error):
        decode_attribute(number, data)


def test_identity_refuses_bad_values() -> None:
    with pytest.raises(EncodeError):
        Identity(vendor_id=70000)
    with pytest.raises(EncodeError):
        Identity(revision=(1, 300))
    with pytest.raises(EncodeError):
        Identity(product_name="X" * 33)


@pytest.mark.parametrize(
    ("text", "frame"),
    [
        ("41B#8000B2", CanFrame(0x41B, bytes.fromhex("80 00 B2"))),
        ("41b#80.00.b2", CanFrame(0x41B, bytes.fromhex("80 00 B2"))),
        ("41B#80 00 B2", CanFrame(0x41B, bytes.fromhex("80 00 B2"))),
        ("(1700000000.5) can0 3C5#2100060000", CanFrame(0x3C5, bytes.fromhex("21 00 06 00 00"))),
        ("407#", CanFrame(0x407, b"")),
    ],
)
def test_candump_syntax(text: str, frame: CanFrame) -> None:
    assert parse_candump(text) == frame
    assert parse_candump(frame.text()) == frame


@pytest.mark.parametrize(
    "text",
    ["", "41B", "41B#8", "41B#800", "12345678#00", "800#00", "41B#R", "41B##100", "41B#001122334455667788", "x#00"],
)
def test_candump_refuses(text: str) -> None:
    with pytest.raises(DecodeError):
        parse_candump(text)


@given(st.integers(0, 0x7FF), st.binary(max_size=8))
def test_candump_round_trip(can_id: int, data: bytes) -> None:
    frame = CanFrame(can_id, data)
    assert parse_candump(frame.text()) == frame
