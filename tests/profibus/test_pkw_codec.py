"""The telegram codec beyond the printed examples: codes, unknown values, errors, round trips."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core.errors import CodecError, DecodeError, EncodeError
from starterbus.transports.profibus_pkw.codec.codes import (
    Direction,
    Part,
    Ppo,
    ResponseCode,
    TaskCode,
    UnknownCode,
    response_code,
    task_code,
)
from starterbus.transports.profibus_pkw.codec.telegram import (
    NO_TASK,
    PkwRequest,
    PkwResponse,
    Ppo1In,
    Ppo1Out,
    PzdIn,
    PzdOut,
    decode,
    decode_part,
    decode_ppo1_in,
    decode_ppo1_out,
    encode,
    encode_ppo1,
    from_words,
    output_words,
    pkw_request,
    pkw_response,
    ppo1_in,
    ppo1_out,
    telegram_type,
)

words = st.integers(0, 0xFFFF)


def test_codes_are_the_manual_tables() -> None:
    assert [(c.value, c.name) for c in TaskCode] == [
        (0, "NO_TASK"), (1, "READ_PARAMETER"), (2, "WRITE_PARAMETER"), (3, "READ_MEASUREMENT"),
    ]  # fmt: skip
    assert [(c.value, c.name) for c in ResponseCode] == [
        (0, "NO_RESPONSE"), (1, "VALUE"), (2, "NO_WRITE_PERMISSION"), (3, "CANNOT_EXECUTE"),
    ]  # fmt: skip


@pytest.mark.parametrize("indh", range(256))
def test_every_indh_decodes_to_a_code_or_an_explicit_unknown(indh: int) -> None:
    out = decode_ppo1_out(bytes([indh, 7, 0, 0, 0, 9, 0, 0]))
    back = decode_ppo1_in(bytes([indh, 7, 0, 1, 0, 0, 0, 0]))
    if indh <= 3:
        assert out.task is TaskCode(indh) and back.response is ResponseCode(indh)
    else:
        assert isinstance(out.task, UnknownCode) and isinstance(back.response, UnknownCode)
        assert int(out.task) == indh and out.task.name == f"UNKNOWN_{indh}"
        assert "unknown" in str(back.response) and repr(back.response) == f"UnknownCode({indh})"
    assert out.indl == 7 and back.indl == 7
    assert task_code(indh) == indh and response_code(indh) == indh


def test_reserved_word_and_bits_are_kept_not_dropped() -> None:
    t = decode_ppo1_out(bytes.fromhex("00 00 00 00 FF F2 12 34"))
    assert t.stw == 0xFFF2 and t.spare == 0x1234
    assert encode(t) == bytes.fromhex("00 00 00 00 FF F2 12 34")


@pytest.mark.parametrize(
    ("ppo", "direction", "part", "kind"),
    [
        (Ppo.PPO1, Direction.OUT, Part.ALL, Ppo1Out),
        (Ppo.PPO1, Direction.IN, Part.ALL, Ppo1In),
        (Ppo.PPO1, Direction.OUT, Part.PKW, PkwRequest),
        (Ppo.PPO1, Direction.IN, Part.PKW, PkwResponse),
        (Ppo.PPO1, Direction.OUT, Part.PZD, PzdOut),
        (Ppo.PPO1, Direction.IN, Part.PZD, PzdIn),
        (Ppo.PPO3, Direction.OUT, Part.ALL, PzdOut),
        (Ppo.PPO3, Direction.IN, Part.ALL, PzdIn),
        (Ppo.PPO3, Direction.OUT, Part.PZD, PzdOut),
    ],
)
def test_layout_table(ppo: Ppo, direction: Direction, part: Part, kind: type) -> None:
    assert telegram_type(ppo, direction, part) is kind


def test_ppo3_has_no_pkw_area() -> None:
    with pytest.raises(EncodeError, match="PPO3 has no PKW"):
        telegram_type(Ppo.PPO3, Direction.OUT, Part.PKW)
    with pytest.raises(EncodeError, match="PPO3 has no PKW"):
        output_words(Ppo.PPO3, pkw_request(TaskCode.READ_PARAMETER, 3), 0x0009)
    assert output_words(Ppo.PPO3, NO_TASK, 0x0009) == (0x0009, 0)
    assert output_words(Ppo.PPO1, pkw_request(TaskCode.READ_PARAMETER, 3), 0x0009) == (0x0103, 0, 0x0009, 0)
    assert Ppo.PPO1.words == 4 and Ppo.PPO3.words == 2


@pytest.mark.parametrize("size", [0, 1, 2, 3, 5, 7, 9, 16])
@pytest.mark.parametrize("direction", list(Direction))
def test_wrong_length_is_a_decode_error_with_the_bytes(size: int, direction: Direction) -> None:
    data = bytes(range(1, size + 1))
    for fn in (decode_ppo1_in, decode_ppo1_out):
        with pytest.raises(DecodeError) as info:
            fn(data)
        assert info.value.data == data and info.value.field == "telegram"
    with pytest.raises(DecodeError):
        decode(data, Ppo.PPO1, direction)
    if size != 4:
        with pytest.raises(DecodeError):
            decode(data, Ppo.PPO3, direction)


@pytest.mark.parametrize(
    ("telegram", "field"),
    [
        (Ppo1Out(0x10000, 0, 0, 0), "IND"),
        (Ppo1Out(0, -1, 0, 0), "PWE"),
        (Ppo1Out(0, 0, 0x1_0000, 0), "STW"),
        (Ppo1Out(0, 0, 0, 70000), "0000 word"),
        (Ppo1In(0, 0, 0, -5), "ACT"),
        (PzdIn(2**20, 0), "ZSW"),
        (PkwRequest(0, "12"), "PWE"),  # type: ignore[arg-type]
    ],
)
def test_encode_names_the_bad_field(telegram: Ppo1Out, field: str) -> None:
    with pytest.raises(EncodeError) as info:
        encode(telegram)
    assert info.value.field == field
    if len(telegram) == 4:
        with pytest.raises(EncodeError):
            encode_ppo1(telegram)


def test_builders_check_indh_indl_and_words() -> None:
    assert pkw_request(TaskCode.WRITE_PARAMETER, 7, 350) == PkwRequest(0x0207, 350)
    assert pkw_response(ResponseCode.CANNOT_EXECUTE, 7, 3) == PkwResponse(0x0307, 3)
    with pytest.raises(EncodeError, match="INDL"):
        pkw_request(TaskCode.READ_PARAMETER, 0x100)
    with pytest.raises(EncodeError, match="INDL"):
        pkw_request(TaskCode.READ_PARAMETER, -1)
    with pytest.raises(EncodeError, match="INDH"):
        pkw_request(256, 1)
    with pytest.raises(EncodeError, match="PWE"):
        pkw_request(TaskCode.WRITE_PARAMETER, 1, 0x10000)
    with pytest.raises(EncodeError, match="PWE"):
        pkw_request(TaskCode.WRITE_PARAMETER, 1, True)
    with pytest.raises(EncodeError, match="STW"):
        ppo1_out(NO_TASK, -1)
    with pytest.raises(EncodeError, match="ACT"):
        ppo1_in(PkwResponse(0), 0, 0x10000)
    assert ppo1_out(PkwRequest(0x0102), 0x000B) == Ppo1Out(0x0102, 0, 0x000B, 0)


def test_from_words_checks_count_and_range() -> None:
    assert from_words(Ppo1In, [0x0103, 612, 0x0900, 960]) == Ppo1In(0x0103, 612, 0x0900, 960)
    with pytest.raises(DecodeError, match="has 4 words"):
        from_words(Ppo1In, [1, 2, 3])
    with pytest.raises(DecodeError) as info:
        from_words(PzdIn, [1, 0x10000])
    assert info.value.field == "ACT"


def test_codec_errors_share_the_root() -> None:
    assert issubclass(DecodeError, CodecError) and issubclass(EncodeError, CodecError)


# -- round trips ---------------------------------------------------------------------------------------------


@given(st.binary(min_size=8, max_size=8))
def test_any_eight_bytes_round_trip_both_directions(data: bytes) -> None:
    out = decode_ppo1_out(data)
    back = decode_ppo1_in(data)
    assert encode_ppo1(out) == data == encode(back)
    assert (out.ind >> 8, out.indl) == (data[0], data[1])
    assert back.pkw == PkwResponse(*struct.unpack(">2H", data[:4]))
    assert back.pzd == PzdIn(*struct.unpack(">2H", data[4:]))


@given(st.binary(min_size=4, max_size=4), st.sampled_from(list(Direction)))
def test_any_four_bytes_round_trip_as_ppo3_and_as_halves(data: bytes, direction: Direction) -> None:
    assert encode(decode(data, Ppo.PPO3, direction)) == data
    for part in (Part.PKW, Part.PZD):
        assert encode(decode_part(data, Ppo.PPO1, direction, part)) == data


@given(st.integers(0, 3), st.integers(0, 255), words, words, words)
def test_built_requests_round_trip(task: int, indl: int, pwe: int, stw: int, spare: int) -> None:
    telegram = ppo1_out(pkw_request(task, indl, pwe), stw, spare)
    decoded = decode_ppo1_out(encode_ppo1(telegram))
    assert decoded == telegram
    assert decoded.task is TaskCode(task) and decoded.indl == indl and decoded.pwe == pwe
    assert decoded.stw == stw and decoded.spare == spare


@given(st.integers(0, 255), st.integers(0, 255), words, words, words)
def test_built_responses_round_trip(code: int, indl: int, pwe: int, zsw: int, act: int) -> None:
    telegram = ppo1_in(pkw_response(code, indl, pwe), zsw, act)
    decoded = decode_ppo1_in(encode(telegram))
    assert decoded == telegram and int(decoded.response) == code and decoded.indl == indl
    assert isinstance(decoded.response, ResponseCode) == (code <= 3)


@given(st.lists(words, min_size=0, max_size=6))
def test_word_lists_of_any_other_length_are_refused(values: list[int]) -> None:
    if len(values) == 4:
        assert from_words(Ppo1Out, values) == Ppo1Out(*values)
    else:
        with pytest.raises(DecodeError):
            from_words(Ppo1Out, values)
