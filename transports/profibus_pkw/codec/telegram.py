"""The vendor's Profibus DP telegrams (PPO1 / PPO3), sans-IO: bytes <-> words <-> named tuples.

docs/manuals.md#3-profibus-dp-pkw-and-pzd-telegrams. Every word is big-endian. A telegram is a
:class:`~typing.NamedTuple` whose fields are exactly its words in wire order, so decoding is one ``struct``
unpack and encoding one pack; the meaning of the words (task or response code in INDH, address in INDL) is read
through properties::

    PPO1 ("type I", 4 words)   master -> slave: IND  PWE  STW  0000      (Ppo1Out)
                               slave -> master: IND  PWE  ZSW  ACT       (Ppo1In)
    PPO3 ("type III", 2 words) master -> slave: STW  0000                (PzdOut)
                               slave -> master: ZSW  ACT                 (PzdIn)

The first two words of PPO1 are the PKW area (:class:`PkwRequest` / :class:`PkwResponse`), the last two the PZD
area; a PPO3 telegram IS the PZD area. The manual prints its examples as four-byte PKW-only or PZD-only parts,
which :func:`decode_part` reads.

INDH codes the manual does not define decode to :class:`UnknownCode` (an ``int`` that says so), never an error;
a non-zero reserved ``0000`` word is kept as it came (``spare``). Wrong lengths raise :class:`DecodeError` with
the bytes; words that do not fit 16 bits (or INDH/INDL that do not fit a byte) raise :class:`EncodeError`.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from typing import NamedTuple, TypeVar

from starterbus.core import DecodeError, EncodeError, Label
from starterbus.transports.profibus_pkw.codec.codes import (
    RESPONSES,
    TASKS,
    Direction,
    Part,
    Ppo,
    ResponseCode,
    TaskCode,
    UnknownCode,
)

__all__ = [
    "PkwRequest",
    "PkwResponse",
    "Ppo1In",
    "Ppo1Out",
    "PzdIn",
    "PzdOut",
    "Telegram",
    "decode",
    "decode_part",
    "decode_ppo1_in",
    "decode_ppo1_out",
    "encode",
    "error_label",
    "from_words",
    "pkw_request",
    "pkw_response",
    "telegram_type",
]

# -- telegram types (fields = words in wire order) ---------------------------------------------------------


class PkwRequest(NamedTuple):
    """PKW area master -> slave: IND (INDH task, INDL address) and PWE (value to write, else 0)."""

    ind: int
    pwe: int = 0

    @property
    def task(self) -> TaskCode | UnknownCode:
        return TASKS[(self.ind >> 8) & 0xFF]

    @property
    def indl(self) -> int:
        return self.ind & 0xFF


class PkwResponse(NamedTuple):
    """PKW area slave -> master: IND (INDH response, INDL address) and PWE (value or error number)."""

    ind: int
    pwe: int = 0

    @property
    def response(self) -> ResponseCode | UnknownCode:
        return RESPONSES[(self.ind >> 8) & 0xFF]

    @property
    def indl(self) -> int:
        return self.ind & 0xFF


class PzdOut(NamedTuple):
    """PZD area master -> slave (= the whole PPO3 output): STW (control word) and a reserved 0000 word."""

    stw: int
    spare: int = 0


class PzdIn(NamedTuple):
    """PZD area slave -> master (= the whole PPO3 input): ZSW (status word) and ACT (phase A current, 0.1 A)."""

    zsw: int
    act: int


class Ppo1Out(NamedTuple):
    """PPO1 master -> slave: IND, PWE, STW, 0000."""

    ind: int
    pwe: int
    stw: int
    spare: int = 0

    @property
    def task(self) -> TaskCode | UnknownCode:
        return TASKS[(self.ind >> 8) & 0xFF]

    @property
    def indl(self) -> int:
        return self.ind & 0xFF

    @property
    def pkw(self) -> PkwRequest:
        return PkwRequest(self.ind, self.pwe)

    @property
    def pzd(self) -> PzdOut:
        return PzdOut(self.stw, self.spare)


class Ppo1In(NamedTuple):
    """PPO1 slave -> master: IND, PWE, ZSW, ACT."""

    ind: int
    pwe: int
    zsw: int
    act: int

    @property
    def response(self) -> ResponseCode | UnknownCode:
        return RESPONSES[(self.ind >> 8) & 0xFF]

    @property
    def indl(self) -> int:
        return self.ind & 0xFF

    @property
    def pkw(self) -> PkwResponse:
        return PkwResponse(self.ind, self.pwe)

    @property
    def pzd(self) -> PzdIn:
        return PzdIn(self.zsw, self.act)


Telegram = Ppo1Out | Ppo1In | PzdOut | PzdIn | PkwRequest | PkwResponse
T = TypeVar("T", Ppo1Out, Ppo1In, PzdOut, PzdIn, PkwRequest, PkwResponse)

# (direction, part or ppo) -> type; the table the generic functions and the decoder use.
_TYPES: Mapping[tuple[Direction, Part], type[Telegram]] = {
    (Direction.OUT, Part.PKW): PkwRequest,
    (Direction.IN, Part.PKW): PkwResponse,
    (Direction.OUT, Part.PZD): PzdOut,
    (Direction.IN, Part.PZD): PzdIn,
}
_FIELD_TEXT = {
    "ind": "IND",
    "pwe": "PWE",
    "stw": "STW",
    "zsw": "ZSW",
    "act": "ACT",
    "spare": "0000 word",
}


def telegram_type(ppo: Ppo, direction: Direction, part: Part = Part.ALL) -> type[Telegram]:
    """The named tuple for one PPO type, direction and part (PPO3 has no PKW part)."""
    if part is Part.ALL:
        if ppo is Ppo.PPO1:
            return Ppo1Out if direction is Direction.OUT else Ppo1In
        part = Part.PZD
    elif part is Part.PKW and not ppo.has_pkw:
        raise EncodeError(f"{ppo.name} has no PKW area", field="ppo")
    return _TYPES[(direction, part)]


# -- codec ----------------------------------------------------------------------------------------------------

_S2 = struct.Struct(">2H")
_S4 = struct.Struct(">4H")
_STRUCTS = {2: _S2, 4: _S4}
_new = tuple.__new__
_pack4 = _S4.pack
_unpack4 = _S4.unpack
_structerror = struct.error


def _encode_error(telegram: Sequence[object]) -> EncodeError:
    fields = getattr(telegram, "_fields", ())
    for i, word in enumerate(telegram):
        if not isinstance(word, int) or isinstance(word, bool) or not 0 <= word <= 0xFFFF:
            name = _FIELD_TEXT.get(fields[i], fields[i]) if i < len(fields) else f"word {i}"
            return EncodeError(f"{word!r} is not a 16-bit word", field=name)
    return EncodeError(f"{type(telegram).__name__} has {len(telegram)} words, expected 2 or 4", field="telegram")


def encode(telegram: Telegram) -> bytes:
    """Any telegram or part -> its big-endian bytes."""
    try:
        return _STRUCTS[len(telegram)].pack(*telegram)
    except (_structerror, KeyError, TypeError):
        raise _encode_error(telegram) from None


def encode_ppo1(telegram: Ppo1Out | Ppo1In) -> bytes:
    """The PPO1 hot path: one precompiled pack of the four words."""
    try:
        return _pack4(*telegram)
    except (_structerror, TypeError):
        raise _encode_error(telegram) from None


def decode_ppo1_out(data: bytes) -> Ppo1Out:
    if len(data) != 8:
        raise DecodeError(f"a PPO1 master->slave telegram is 8 bytes, got {len(data)}", data, "telegram")
    return _new(Ppo1Out, _unpack4(data))


def decode_ppo1_in(data: bytes) -> Ppo1In:
    """The PPO1 hot path: length check and one precompiled unpack."""
    if len(data) != 8:
        raise DecodeError(f"a PPO1 slave->master telegram is 8 bytes, got {len(data)}", data, "telegram")
    return _new(Ppo1In, _unpack4(data))


def decode(data: bytes, ppo: Ppo, direction: Direction) -> Telegram:
    """Bytes of one whole telegram -> its named tuple."""
    return decode_part(data, ppo, direction, Part.ALL)


def decode_part(data: bytes, ppo: Ppo, direction: Direction, part: Part = Part.ALL) -> Telegram:
    """Bytes of a telegram or of its PKW / PZD half (the manual's four-byte examples) -> named tuple."""
    kind = telegram_type(ppo, direction, part)
    size = 2 * len(kind._fields)
    data = bytes(data)
    if len(data) != size:
        what = f"{ppo.name} {direction.value}" + ("" if part is Part.ALL else f" {part.value.upper()} part")
        raise DecodeError(f"{what} is {size} bytes, got {len(data)}", data, "telegram")
    return _new(kind, _STRUCTS[size // 2].unpack(data))


def from_words(kind: type[T], words: Sequence[int]) -> T:
    """Words (e.g. Modbus registers of a gateway) -> telegram, checking count and 16-bit range."""
    if len(words) != len(kind._fields):
        raise DecodeError(f"{kind.__name__} has {len(kind._fields)} words, got {len(words)}: {list(words)}")
    for i, word in enumerate(words):
        if not 0 <= word <= 0xFFFF:
            raise DecodeError(f"{word!r} is not a 16-bit word", field=_FIELD_TEXT[kind._fields[i]])
    return _new(kind, tuple(words))


# -- building --------------------------------------------------------------------------------------------------


def _ind(code: int, index: int, what: str) -> int:
    if not 0 <= code <= 0xFF:
        raise EncodeError(f"{code!r} does not fit INDH (0-255)", field=f"INDH ({what})")
    if not 0 <= index <= 0xFF:
        raise EncodeError(f"address {index!r} does not fit INDL (0-255)", field="INDL")
    return (code << 8) | index


def _word(value: int, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
        raise EncodeError(f"{value!r} is not a 16-bit word", field=field)
    return value


def pkw_request(task: int, index: int = 0, value: int = 0) -> PkwRequest:
    """Build a PKW request, checking that INDH, INDL and PWE fit."""
    return PkwRequest(_ind(int(task), index, "task"), _word(value, "PWE"))


def pkw_response(response: int, index: int = 0, value: int = 0) -> PkwResponse:
    return PkwResponse(_ind(int(response), index, "response"), _word(value, "PWE"))


NO_TASK = PkwRequest(0, 0)
NO_RESPONSE = PkwResponse(0, 0)


def ppo1_out(pkw: PkwRequest, stw: int, spare: int = 0) -> Ppo1Out:
    return Ppo1Out(pkw.ind, pkw.pwe, _word(stw, "STW"), _word(spare, "0000 word"))


def ppo1_in(pkw: PkwResponse, zsw: int, act: int) -> Ppo1In:
    return Ppo1In(pkw.ind, pkw.pwe, _word(zsw, "ZSW"), _word(act, "ACT"))


def output_words(ppo: Ppo, pkw: PkwRequest, stw: int) -> tuple[int, ...]:
    """The master's output area for one cycle (PPO3 carries no PKW; a pending task there is an error)."""
    if ppo is Ppo.PPO1:
        return (pkw.ind, pkw.pwe, stw, 0)
    if pkw.ind or pkw.pwe:
        raise EncodeError("PPO3 has no PKW area: parameter tasks need PPO1", field="ppo")
    return (stw, 0)


def error_label(errors: Mapping[int, Label], number: int) -> Label:
    """The meaning of an error number after response 3, from the MODEL's own table (JJR5000 != JJR8000)."""
    label = errors.get(number)
    if label is not None:
        return label
    return Label(f"unknown error {number}", f"未知错误 {number}")


def hex_text(data: bytes) -> str:
    return data.hex(" ").upper()
