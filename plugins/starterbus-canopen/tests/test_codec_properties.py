"""Properties of the pure pieces: PDO codecs round-trip; the decoder never raises anything but typed errors."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st
from starterbus_canopen.codes import Tpdo1, decode_rpdo1, encode_rpdo1
from starterbus_canopen.decoder import FrameAnnotator, parse_candump

from starterbus.core import CanFrame, DecodeError, get_profile

words = st.integers(0, 0xFFFF)


@given(words, words)
def test_tpdo1_round_trips(status: int, current: int) -> None:
    assert Tpdo1.decode(Tpdo1(status, current).encode()) == Tpdo1(status, current)


@given(words)
def test_rpdo1_round_trips(word: int) -> None:
    assert decode_rpdo1(encode_rpdo1(word)) == word


@given(st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=12))
def test_any_frames_annotate_without_crashing(frames: list[tuple[int, bytes]]) -> None:
    annotator = FrameAnnotator(get_profile("example_canopen_starter"))
    for can_id, data in frames:
        frame = CanFrame(can_id, data)
        assert parse_candump(frame.text()) == frame
        annotation = annotator.annotate(frame)
        assert annotation.title.startswith(frame.text())


@given(st.text(max_size=30))
def test_any_text_parses_or_raises_a_decode_error(text: str) -> None:
    try:
        parse_candump(text)
    except DecodeError:
        pass
