"""Annotating CANopen frames for ``starterbus decode canopen ID#DATA ...`` (candump syntax, 11-bit ids).

Pure: :class:`FrameAnnotator` is fed frames in order and follows segmented SDO transfers per node. NMT, SYNC,
EMCY, TIME, PDOs (TPDO1/RPDO1 of this plugin's design decoded through the profile when one is given), SDO
(expedited, segmented, abort with the code's meaning, block transfers named), heartbeat/boot-up/node guarding and
LSS. Every frame gives one :class:`Annotation`; a frame that cannot be decoded gives one with ``error`` set.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass

from starterbus.core import (
    Annotation,
    CanFrame,
    DecodeError,
    PointDef,
    Profile,
    StarterbusError,
    annotate_candump,
    decode_status_word,
    describe_control_word,
)
from starterbus.core import parse_candump as _parse_candump
from starterbus_canopen.codes import (
    ERROR_REGISTER_BITS,
    NMT_COMMANDS,
    NMT_STATES,
    Tpdo1,
    abort_meaning,
    decode_rpdo1,
    emcy_meaning,
)
from starterbus_canopen.od import PdoLayout
from starterbus_canopen.settings import PLUGIN_NAME

Field = tuple[str, str, str]
_PDOS = {0x180: "TPDO1", 0x200: "RPDO1", 0x280: "TPDO2", 0x300: "RPDO2", 0x380: "TPDO3", 0x400: "RPDO3",
         0x480: "TPDO4", 0x500: "RPDO4"}  # fmt: skip


READER = "the CANopen decoder"


def parse_candump(text: str) -> CanFrame:
    """One frame in candump syntax (``605#4001200000000000``, ``605#40.01.20...``, a ``candump -L`` line), as
    every starterbus decoder reads it (:func:`starterbus.core.parse_candump`)."""
    return _parse_candump(text, READER)


def _hex(data: bytes) -> str:
    return data.hex(" ").upper() if data else "-"


def _need(data: bytes, size: int, what: str) -> None:
    if len(data) < size:
        raise DecodeError(f"{what} needs {size} bytes, got {len(data)}", data, what)


@dataclass
class _Segmented:
    index: int
    subindex: int
    upload: bool
    size: int | None
    data: bytearray


class FrameAnnotator:
    def __init__(self, profile: Profile | None = None) -> None:
        self.profile = profile
        self.layout = PdoLayout.of(profile) if profile is not None and profile.supports(PLUGIN_NAME) else None
        self._points: dict[tuple[int, int], PointDef] = {}
        if profile is not None:
            for point in profile.points.values():
                where = point.addresses.get(PLUGIN_NAME)
                if where is not None:
                    self._points[(int(where[0]), int(where[1]))] = point
        self._transfers: dict[int, _Segmented] = {}

    def annotate_text(self, texts: Iterable[str]) -> list[Annotation]:
        return annotate_candump(texts, self.annotate, READER)

    def annotate(self, frame: CanFrame) -> Annotation:
        fields: list[Field] = []
        can_id, data = frame.can_id, frame.data
        function, node = can_id & 0x780, can_id & 0x7F
        title = frame.text()
        try:
            if can_id == 0x000:
                title += "  NMT"
                self._nmt(data, fields)
            elif can_id == 0x080:
                title += "  SYNC"
                fields.append(("counter", _hex(data), f"{data[0]}" if data else "no counter"))
            elif can_id == 0x100:
                title += "  TIME"
                fields.append(("time of day", _hex(data), "ms after midnight (28 bits), days since 1984-01-01"))
            elif can_id in (0x7E4, 0x7E5):
                title += "  LSS " + ("slave response" if can_id == 0x7E4 else "master request")
                fields.append(("data", _hex(data), f"command specifier 0x{data[0]:02X}" if data else "empty"))
            elif node == 0:
                raise DecodeError(f"node id 0 is not valid with function code 0x{function:03X}")
            elif function == 0x080:
                title += f"  EMCY node {node}"
                self._emcy(data, fields)
            elif function in _PDOS:
                title += f"  {_PDOS[function]} node {node}"
                self._pdo(_PDOS[function], data, fields)
            elif function in (0x580, 0x600):
                client = function == 0x600
                title += (
                    f"  SDO {'request (client -> server)' if client else 'response (server -> client)'} node {node}"
                )
                self._sdo(node, client, data, fields)
            elif function == 0x700:
                title += f"  heartbeat node {node}"
                self._heartbeat(data, fields)
            else:
                fields.append(("data", _hex(data), f"function code 0x{function:03X} is not in the predefined set"))
        except StarterbusError as exc:
            return Annotation(title, fields, str(exc))
        return Annotation(title, fields)

    # -- services ------------------------------------------------------------------------------------------------

    def _nmt(self, data: bytes, fields: list[Field]) -> None:
        _need(data, 2, "NMT")
        cs, node = data[0], data[1]
        fields.append(("command", f"0x{cs:02X}", NMT_COMMANDS.get(cs, "unknown NMT command")))
        fields.append(("node", f"0x{node:02X}", "all nodes" if node == 0 else f"node {node}"))
        if cs not in NMT_COMMANDS:
            raise DecodeError(f"unknown NMT command 0x{cs:02X}", data, "command")

    def _emcy(self, data: bytes, fields: list[Field]) -> None:
        _need(data, 8, "EMCY")
        code, register = struct.unpack_from("<HB", data)
        fields.append(("error code", f"0x{code:04X}", emcy_meaning(code)))
        bits = [name or f"bit {i}" for i, name in enumerate(ERROR_REGISTER_BITS) if register & (1 << i)]
        fields.append(("error register", f"0x{register:02X}", ", ".join(bits) or "no error"))
        fields.append(("manufacturer data", _hex(data[3:]), ""))

    def _heartbeat(self, data: bytes, fields: list[Field]) -> None:
        _need(data, 1, "heartbeat")
        state = data[0] & 0x7F
        meaning = NMT_STATES.get(state, "unknown state")
        if data[0] & 0x80:
            meaning += " (node guarding, toggle bit set)"
        fields.append(("state", f"0x{data[0]:02X}", meaning))

    def _value(self, index: int, subindex: int, raw: int) -> str:
        point = self._points.get((index, subindex))
        if point is None:
            return f"{raw}"
        label = point.enum.label(raw) if point.enum is not None else None
        shown = label.en if label is not None else f"{point.to_engineering(raw)} {point.unit}".strip()
        return f"{point.key} = {shown} (raw {raw})"

    def _pdo(self, name: str, data: bytes, fields: list[Field]) -> None:
        layout = self.layout
        if layout is None or name not in ("TPDO1", "RPDO1"):
            fields.append(("data", _hex(data), "mapping unknown (give --model of a canopen profile)"))
            return
        if name == "RPDO1":
            word = decode_rpdo1(data)
            fields.append((layout.control_word.key, f"0x{word:04X}", ", ".join(describe_control_word(word))))
            return
        sample = Tpdo1.decode(data)
        assert self.profile is not None
        status = decode_status_word(
            sample.status_word, self.profile.faults, bit12_is_mains_voltage=self.profile.control.bit12_is_mains_voltage
        )
        meaning = status.state.value + (f", fault {status.fault_code}: {status.fault_text}" if status.fault else "")
        fields.append((layout.status_word.key, f"0x{sample.status_word:04X}", meaning))
        if layout.current is not None:
            point = layout.current
            fields.append(
                (point.key, f"0x{sample.current_raw:04X}", f"{point.to_engineering(sample.current_raw)} {point.unit}")
            )

    def _sdo(self, node: int, client: bool, data: bytes, fields: list[Field]) -> None:
        _need(data, 8, "SDO")
        command = data[0]
        cs = command >> 5
        if cs == 4:  # abort, both directions
            index, subindex, code = struct.unpack_from("<HBL", data, 1)
            self._transfers.pop(node, None)
            fields.append(("command", f"0x{command:02X}", "abort transfer"))
            fields.append(("object", f"0x{index:04X}:{subindex:02X}", self._name(index, subindex)))
            fields.append(("abort code", f"0x{code:08X}", abort_meaning(code)))
            return
        if client:
            self._sdo_request(node, cs, command, data, fields)
        else:
            self._sdo_response(node, cs, command, data, fields)

    def _name(self, index: int, subindex: int) -> str:
        point = self._points.get((index, subindex))
        return point.key if point is not None else ""

    def _initiate(self, data: bytes, fields: list[Field], what: str) -> tuple[int, int]:
        index, subindex = struct.unpack_from("<HB", data, 1)
        fields.append(("command", f"0x{data[0]:02X}", what))
        fields.append(("object", f"0x{index:04X}:{subindex:02X}", self._name(index, subindex)))
        return index, subindex

    def _expedited(self, data: bytes, fields: list[Field], index: int, subindex: int) -> None:
        command = data[0]
        size = 4 - ((command >> 2) & 3) if command & 0x01 else 4
        raw = int.from_bytes(data[4 : 4 + size], "little")
        fields.append(("data", _hex(data[4 : 4 + size]), self._value(index, subindex, raw)))

    def _sdo_request(self, node: int, cs: int, command: int, data: bytes, fields: list[Field]) -> None:
        if cs == 1:  # initiate download
            expedited = bool(command & 0x02)
            index, subindex = self._initiate(data, fields, "initiate download" + (" (expedited)" if expedited else ""))
            if expedited:
                self._expedited(data, fields, index, subindex)
            else:
                size = struct.unpack_from("<L", data, 4)[0] if command & 0x01 else None
                fields.append(("size", _hex(data[4:]), f"{size} bytes" if size is not None else "not indicated"))
                self._transfers[node] = _Segmented(index, subindex, False, size, bytearray())
        elif cs == 2:  # initiate upload
            self._initiate(data, fields, "initiate upload")
        elif cs == 0:  # download segment
            self._segment(node, data, fields, upload=False)
        elif cs == 3:  # upload segment request
            fields.append(("command", f"0x{command:02X}", f"upload segment request, toggle {command >> 4 & 1}"))
        elif cs in (5, 6):
            fields.append(("command", f"0x{command:02X}", "block upload" if cs == 5 else "block download"))
        else:
            raise DecodeError(f"unknown SDO client command specifier {cs}", data, "command")

    def _sdo_response(self, node: int, cs: int, command: int, data: bytes, fields: list[Field]) -> None:
        if cs == 2:  # initiate upload response
            expedited = bool(command & 0x02)
            index, subindex = self._initiate(data, fields, "upload response" + (" (expedited)" if expedited else ""))
            if expedited:
                self._expedited(data, fields, index, subindex)
            else:
                size = struct.unpack_from("<L", data, 4)[0] if command & 0x01 else None
                fields.append(("size", _hex(data[4:]), f"{size} bytes follow" if size is not None else "not indicated"))
                self._transfers[node] = _Segmented(index, subindex, True, size, bytearray())
        elif cs == 3:  # initiate download response
            self._initiate(data, fields, "download confirmed")
        elif cs == 0:  # upload segment
            self._segment(node, data, fields, upload=True)
        elif cs == 1:  # download segment response
            fields.append(("command", f"0x{command:02X}", f"download segment confirmed, toggle {command >> 4 & 1}"))
        elif cs in (5, 6):
            fields.append(("command", f"0x{command:02X}", "block download" if cs == 5 else "block upload"))
        else:
            raise DecodeError(f"unknown SDO server command specifier {cs}", data, "command")

    def _segment(self, node: int, data: bytes, fields: list[Field], upload: bool) -> None:
        command = data[0]
        unused, last, toggle = (command >> 1) & 7, command & 1, (command >> 4) & 1
        payload = data[1 : 8 - unused]
        what = f"{'upload' if upload else 'download'} segment, toggle {toggle}" + (", last" if last else "")
        fields.append(("command", f"0x{command:02X}", what))
        fields.append(("data", _hex(payload), f"{len(payload)} bytes"))
        transfer = self._transfers.get(node)
        if transfer is None or transfer.upload != upload:
            return
        transfer.data += payload
        if last:
            del self._transfers[node]
            text = bytes(transfer.data)
            shown = text.decode("ascii") if text.isascii() and text.decode("ascii").isprintable() else _hex(text)
            fields.append((f"0x{transfer.index:04X}:{transfer.subindex:02X}", _hex(text), f"complete: {shown}"))
            if transfer.size is not None and transfer.size != len(text):
                raise DecodeError(f"segmented transfer carried {len(text)} bytes, announced {transfer.size}", text)


def annotate_frames(texts: Iterable[str], profile: Profile | None = None) -> list[Annotation]:
    return FrameAnnotator(profile).annotate_text(texts)
