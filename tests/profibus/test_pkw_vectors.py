"""Every golden vector of docs/manuals.md#profibus-golden-vectors, byte for byte, both ways, for both models."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from starterbus.core.errors import DecodeError
from starterbus.core.model import Kind, Value
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.core.status import decode_status_word
from starterbus.transports.profibus_pkw.codec.codes import Direction, Part, Ppo, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import (
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
    error_label,
)
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

if TYPE_CHECKING:
    from starterbus.tests.profibus.conftest import Pair, RunningStarter, Vector


def test_table_covers_every_printed_example(vectors: tuple[Vector, ...]) -> None:
    # 10 halves per model: PZD start out/in/fault, PKW read param out/in, write out/in/refused, read meas out/in
    assert sum(v.model == "jjr5000" for v in vectors) == 10
    assert sum(v.model == "jjr8000" for v in vectors) == 10
    assert len({v.id for v in vectors}) == len(vectors)


def test_decode_whole(golden: Vector) -> None:
    telegram = decode_part(golden.data, Ppo.PPO1, golden.direction, golden.part)
    assert telegram == golden.telegram
    assert type(telegram) is type(golden.telegram)
    if golden.code is not None:
        code = telegram.task if isinstance(telegram, PkwRequest) else telegram.response  # type: ignore[union-attr]
        assert code == golden.code
        assert telegram.indl == golden.indl  # type: ignore[union-attr]


def test_encode(golden: Vector) -> None:
    assert encode(golden.telegram) == golden.data


def test_pzd_halves_are_ppo3_telegrams(vectors: tuple[Vector, ...]) -> None:
    pzd = [v for v in vectors if v.part is Part.PZD]
    assert len(pzd) == 6
    for v in pzd:
        assert decode(v.data, Ppo.PPO3, v.direction) == v.telegram
        assert encode(v.telegram) == v.data


def test_every_shorter_prefix_is_refused_with_its_bytes(golden: Vector) -> None:
    for n in range(len(golden.data)):
        with pytest.raises(DecodeError) as info:
            decode_part(golden.data[:n], Ppo.PPO1, golden.direction, golden.part)
        assert info.value.data == golden.data[:n]


@pytest.mark.parametrize("garbage", [b"\x00", b"\xff\xff", b"\x01\x02\x00\x00"])
def test_trailing_garbage_is_refused_never_a_value(golden: Vector, garbage: bytes) -> None:
    data = golden.data + garbage
    with pytest.raises(DecodeError) as info:
        decode_part(data, Ppo.PPO1, golden.direction, golden.part)
    assert info.value.data == data
    assert data.hex(" ").upper() in str(info.value)


def test_meaning_with_the_model(golden: Vector, profiles: dict[str, Profile]) -> None:
    profile = profiles[golden.model]
    telegram = golden.telegram
    if isinstance(telegram, (PkwRequest, PkwResponse)):
        if golden.key is not None:
            assert golden.indl is not None
            kind = Kind.MEASUREMENT if golden.key.startswith("phase") else Kind.PARAMETER
            if isinstance(telegram, PkwRequest):
                kind = Kind.MEASUREMENT if telegram.task == TaskCode.READ_MEASUREMENT else Kind.PARAMETER
            point = profile.by_protocol_address("profibus-pkw", kind, golden.indl)
            assert point is not None and point.key == golden.key
            if golden.value is not None:
                assert Value.from_raw(point, telegram.pwe).value == golden.value
        if golden.error is not None:
            errors = profile.transport_settings("profibus-pkw")["errors"]
            assert error_label(errors, telegram.pwe).en.startswith(golden.error)
    elif isinstance(telegram, PzdIn):
        status = decode_status_word(
            telegram.zsw, profile.faults, bit12_is_mains_voltage=profile.control.bit12_is_mains_voltage
        )
        for attribute, expected in golden.status.items():
            assert getattr(status, attribute) == expected, attribute
        assert telegram.act * 0.1 == pytest.approx(golden.value)


def test_error_three_means_different_things_per_model(profiles: dict[str, Profile]) -> None:
    e5 = profiles["jjr5000"].transport_settings("profibus-pkw")["errors"]
    e8 = profiles["jjr8000"].transport_settings("profibus-pkw")["errors"]
    assert error_label(e5, 3).en.startswith("illegal data value")
    assert error_label(e8, 3).en == "cannot modify while running"
    assert error_label(e8, 0).en == "parameter not available"
    assert 0 not in e5  # JJR5000's numbers start at 1
    assert error_label(e5, 0).en == "unknown error 0"
    assert error_label(e8, 77).en == "unknown error 77"


@pytest.mark.parametrize("model", ["jjr5000", "jjr8000"])
def test_whole_ppo1_telegrams_are_the_printed_halves_joined(model: str, vectors: tuple[Vector, ...]) -> None:
    halves: dict[tuple[Direction, Part], list[Vector]] = {(v.direction, v.part): [] for v in vectors}
    for v in vectors:
        if v.model == model:
            halves[(v.direction, v.part)].append(v)
    for pkw in halves[(Direction.OUT, Part.PKW)]:
        for pzd in halves[(Direction.OUT, Part.PZD)]:
            data = pkw.data + pzd.data
            telegram = decode_ppo1_out(data)
            assert telegram == Ppo1Out(*pkw.telegram, *pzd.telegram)
            assert telegram.pkw == pkw.telegram and telegram.pzd == pzd.telegram
            assert encode_ppo1(telegram) == data == encode(telegram)
    for pkw in halves[(Direction.IN, Part.PKW)]:
        for pzd in halves[(Direction.IN, Part.PZD)]:
            data = pkw.data + pzd.data
            telegram_in = decode_ppo1_in(data)
            assert telegram_in == Ppo1In(*pkw.telegram, *pzd.telegram)
            assert telegram_in.pkw == pkw.telegram and telegram_in.pzd == pzd.telegram
            assert encode_ppo1(telegram_in) == data


def test_the_manual_notes_bit_11_in_the_start_example() -> None:
    pzd = decode_part(bytes.fromhex("09 00 03 C0"), Ppo.PPO3, Direction.IN)
    assert isinstance(pzd, PzdIn) and pzd.zsw & (1 << 11)


def test_out_halves_are_also_ppo3_out() -> None:
    assert decode(bytes.fromhex("00 0B 00 00"), Ppo.PPO3, Direction.OUT) == PzdOut(0x000B)


def test_simulated_slave_answers_the_printed_bytes(
    pair: Pair, profiles: dict[str, Profile], clock: ManualClock, running_starter: RunningStarter
) -> None:
    profile = profiles[pair.model]
    starter = (
        running_starter(profile, clock, **pair.values)
        if pair.running
        else SimulatedStarter(profile, clock, values=pair.values)
    )
    slave = SimulatedDpSlave(starter, Ppo.PPO1)
    stw = 0x0009 if pair.running else 0x0008
    request = decode_part(pair.request, Ppo.PPO1, Direction.OUT, Part.PKW)
    assert isinstance(request, PkwRequest)
    ind, pwe = request
    words = slave.exchange((ind, pwe, stw, 0))
    answer = encode(PkwResponse(words[0], words[1]))
    assert answer == pair.response, pair.note
    # the slave keeps showing the answer while the master repeats the task
    assert slave.exchange((ind, pwe, stw, 0))[:2] == words[:2]


def test_pairs_cover_every_printed_pkw_response(vectors: tuple[Vector, ...], pairs: tuple[Pair, ...]) -> None:
    printed = {(v.model, v.data) for v in vectors if v.direction is Direction.IN and v.part is Part.PKW}
    assert printed == {(p.model, p.response) for p in pairs}
