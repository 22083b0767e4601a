"""Classic CAN frames as the decoders see them: an 11-bit identifier, 0-8 data bytes, and candump text.

Every CAN protocol's codec and decoder (DeviceNet built in, CANopen as a plugin) reads the same text: candump's
compact syntax ``ID#DATA`` (``41B#8000B2``, ``41B#80.00.B2``, ``41B#80 00 B2``), or a ``candump -L`` log line
(``(1.5) can0 41B#8000B2``). Extended (29-bit) identifiers, remote frames and CAN FD frames are refused with a
:class:`~starterbus.core.errors.DecodeError` naming the reader that refuses them. No python-can here.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from starterbus.core.errors import DecodeError, EncodeError, StarterbusError
from starterbus.core.plugin import Annotation

MAX_STANDARD_ID = 0x7FF
MAX_DATA = 8

_CANDUMP_RE = re.compile(r"^([0-9A-Fa-f]{1,8})#((?:[0-9A-Fa-f]{2}[.]?)*)$")


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One classic CAN data frame with a standard (11-bit) identifier."""

    can_id: int
    data: bytes = b""

    def __post_init__(self) -> None:
        if isinstance(self.can_id, bool) or not 0 <= self.can_id <= MAX_STANDARD_ID:
            raise EncodeError(f"CAN identifier {self.can_id!r} is not an 11-bit identifier", field="can_id")
        if len(self.data) > MAX_DATA:
            raise EncodeError(f"{len(self.data)} data bytes do not fit a CAN frame (max 8)", self.data, "data")

    def text(self) -> str:
        """candump form: ``41B#8000B2`` (three hex digits of identifier, data without separators)."""
        return f"{self.can_id:03X}#{self.data.hex().upper()}"

    def __str__(self) -> str:
        return self.text()


def parse_candump(text: str, reader: str = "this decoder") -> CanFrame:
    """One frame in candump syntax (see the module); ``reader`` names who refuses what it does not read."""
    fields = text.split()
    marked = [i for i, part in enumerate(fields) if "#" in part]
    token = "".join(fields[marked[0] :]) if marked else "".join(fields)
    raw = token.encode(errors="replace")
    if "##" in token:
        raise DecodeError(f"{token!r} is a CAN FD frame; {reader} reads classic CAN only", raw, "frame")
    if "#R" in token.upper():
        raise DecodeError(f"{token!r} is a remote frame; {reader} reads data frames only", raw, "frame")
    match = _CANDUMP_RE.fullmatch(token)
    if match is None:
        raise DecodeError(f"{text!r} is not a candump frame ID#DATA (e.g. 41B#8000B2)", raw, "frame")
    id_text, data_text = match.groups()
    can_id = int(id_text, 16)
    if len(id_text) > 3 or can_id > MAX_STANDARD_ID:
        raise DecodeError(
            f"{id_text} is an extended (29-bit) identifier; {reader} reads 11-bit ones only", raw, "can_id"
        )
    data = bytes.fromhex(data_text.replace(".", ""))
    if len(data) > MAX_DATA:
        raise DecodeError(f"{len(data)} data bytes do not fit a CAN frame (max 8)", data, "data")
    return CanFrame(can_id, data)


def annotate_candump(
    texts: Iterable[str], annotate: Callable[[CanFrame], Annotation], reader: str = "this decoder"
) -> list[Annotation]:
    """Each text read as a frame and annotated; a text that is no frame becomes an annotation with its error."""
    out = []
    for text in texts:
        try:
            frame = parse_candump(text, reader)
        except StarterbusError as exc:
            out.append(Annotation(text.strip(), [], str(exc)))
            continue
        out.append(annotate(frame))
    return out
