"""Human annotation of RTU frames for ``starterbus decode modbus-rtu`` (pure: bytes in, annotations out).

A request followed by its response in one byte string is split and the response is annotated against the
request (register names for the values). A lone FC03 response is named with ``address`` when given.
"""

from __future__ import annotations

from starterbus.core import (
    Annotation,
    CodecError,
    Kind,
    PointDef,
    Profile,
    decode_status_word,
    describe_control_word,
)
from starterbus.transports.modbus.codec.crc import CRC_LENGTH, crc_bytes
from starterbus.transports.modbus.codec.decoding import decode_request, decode_response, request_length
from starterbus.transports.modbus.codec.messages import (
    BROADCAST,
    EXCEPTION_BIT,
    STANDARD_EXCEPTION_TEXTS,
    FunctionCode,
    ReadRequest,
    ReadResponse,
    WriteRegistersResponse,
    WriteRequest,
    WriteResponse,
)
from starterbus.transports.modbus.settings import TRANSPORT, max_read_registers, modbus_settings

Field = tuple[str, str, str]


def _hex(data: bytes) -> str:
    return data.hex(" ").upper()


def exception_meaning(profile: Profile | None, code: int) -> str:
    if profile is not None:
        text = modbus_settings(profile).exception_text(code)
        return f"{text} for {profile.display_name}" if text.startswith("unknown") else text
    return STANDARD_EXCEPTION_TEXTS.get(code, f"unknown exception code {code}")


class Annotator:
    def __init__(self, profile: Profile | None, *, crc: bool = True) -> None:
        self.profile = profile
        self.crc = crc
        self.tail = CRC_LENGTH if crc else 0

    # -- register names and values ----------------------------------------------------------------------

    def point(self, address: int) -> PointDef | None:
        if self.profile is None:
            return None
        return self.profile.by_protocol_address(TRANSPORT, Kind.MEASUREMENT, address) or (
            self.profile.by_protocol_address(TRANSPORT, Kind.PARAMETER, address)
        )

    def register_text(self, address: int) -> str:
        point = self.point(address)
        if point is None:
            if self.profile is None:
                return f"register 0x{address:04X}"
            return f"register 0x{address:04X}: not in the {self.profile.display_name} map (exception 02)"
        return f"0x{address:04X} {point.key}: {point.name_en} ({point.address})"

    def value_text(self, address: int | None, raw: int, *, written: bool = False) -> str:
        point = self.point(address) if address is not None else None
        if point is None:
            return f"raw {raw} (0x{raw:04X})"
        assert self.profile is not None
        roles = self.profile.roles
        if point.key == roles.get("control_word"):
            return "control word: " + ", ".join(describe_control_word(raw))
        if point.key == roles.get("status_word"):
            return "status word: " + self.status_text(raw)
        if point.enum is not None:
            label = point.enum.label(raw)
            text = f"{label.en} ({raw})" if label is not None else f"unknown value {raw}"
        else:
            eng = point.to_engineering(raw)
            text = f"{eng} {point.unit}".rstrip() + (f" (raw {raw})" if point.scale != 1 else "")
        if written:
            if point.kind is Kind.MEASUREMENT or not point.writable:
                text += "; read-only: the device answers exception 03"
            elif not point.raw_min <= raw <= point.raw_max or (point.enum is not None and raw not in point.enum.labels):
                lo, hi = point.to_engineering(point.raw_min), point.to_engineering(point.raw_max)
                text += f"; outside {lo}..{hi} {point.unit}".rstrip() + ": the device answers exception 03"
        return text

    def status_text(self, word: int) -> str:
        assert self.profile is not None
        status = decode_status_word(
            word, self.profile.faults, bit12_is_mains_voltage=self.profile.control.bit12_is_mains_voltage
        )
        parts = [status.state.value]
        if status.fault:
            parts[0] = f"fault {status.fault_code}: {status.fault_text}"
        flags = [
            ("soft starting", status.starting), ("running", status.running), ("soft stopping", status.stopping),
            ("ready", bool(status.ready)), ("bus control", bool(status.bus_control)),
            ("mains voltage", bool(status.mains_voltage)),
        ]  # fmt: skip
        parts += [name for name, on in flags if on and name != parts[0]]
        if status.unknown_bits:
            parts.append(f"unknown bits 0x{status.unknown_bits:04X}")
        return ", ".join(parts)

    # -- frames -----------------------------------------------------------------------------------------

    def _head(self, frame: bytes) -> list[Field]:
        unit = frame[0]
        who = "broadcast (every slave, no answer)" if unit == BROADCAST else f"unit {unit}"
        function = frame[1] if len(frame) > 1 else 0
        base = function & ~EXCEPTION_BIT
        names: dict[int, str] = {
            FunctionCode.READ_HOLDING_REGISTERS: "FC03 read holding registers (parameters and measurements)",
            FunctionCode.WRITE_SINGLE_REGISTER: "FC06 write single register",
        }
        if function & EXCEPTION_BIT:
            meaning = f"exception response to FC{base:02X}"
        else:
            meaning = names.get(function, f"FC{function:02X}: not supported by these devices (exception 01)")
        fields = [("unit", f"{unit:02X}", who)]
        if len(frame) > 1:
            fields.append(("function", f"{function:02X}", meaning))
        return fields

    def _crc_field(self, frame: bytes) -> tuple[Field, str | None]:
        if not self.crc:
            return ("crc", "(none)", f"printed without CRC; on the wire append {_hex(crc_bytes(frame))}"), None
        body, received = frame[:-CRC_LENGTH], frame[-CRC_LENGTH:]
        right = crc_bytes(body)
        if received == right:
            return ("crc", _hex(received), "good"), None
        error = f"bad CRC {_hex(received)}, the right CRC is {_hex(right)}"
        return (
            "crc",
            _hex(received),
            f"BAD: the right CRC is {_hex(right)} (printed without CRC? use --no-crc)",
        ), error

    def request(self, frame: bytes) -> tuple[Annotation, ReadRequest | WriteRequest | None]:
        fields = self._head(frame)
        try:
            crc_field, crc_error = self._crc_field(frame) if len(frame) > self.tail else (None, None)
            body_frame = frame if not self.crc or crc_error is None else frame[:-CRC_LENGTH] + crc_bytes(frame[:-2])
            request = decode_request(body_frame, crc=self.crc)
        except CodecError as exc:
            return Annotation(f"request ({len(frame)} bytes): malformed", fields, str(exc)), None
        title = "request"
        result: ReadRequest | WriteRequest | None = None
        if isinstance(request, ReadRequest):
            result = request
            fields.append(("address", _hex(frame[2:4]), self.register_text(request.address)))
            limit = max_read_registers(self.profile) if self.profile is not None else 125
            note = f"{request.count} register(s)"
            if not 1 <= request.count <= limit:
                note += f": outside 1..{limit}, the device answers exception 03"
            fields.append(("count", _hex(frame[4:6]), note))
            for offset in range(1, min(request.count, 16)):
                fields.append(("", "", self.register_text(request.address + offset)))
            title = f"request: read {request.count} register(s) from 0x{request.address:04X}"
        elif isinstance(request, WriteRequest):
            result = request
            fields.append(("address", _hex(frame[2:4]), self.register_text(request.address)))
            fields.append(("value", _hex(frame[4:6]), self.value_text(request.address, request.value, written=True)))
            title = f"request (or its echo): write 0x{request.value:04X} to 0x{request.address:04X}"
        else:
            fields.append(("data", _hex(request.data), "function not supported by these devices"))
            title = f"request: FC{request.function:02X}"
        if request.unit != BROADCAST:
            title += f" at unit {request.unit}"
        if crc_field is not None:
            fields.append(crc_field)
        return Annotation(title, fields, crc_error), result

    def response(self, frame: bytes, request: ReadRequest | WriteRequest | None, address: int | None) -> Annotation:
        fields = self._head(frame)
        if len(frame) <= self.tail + 1:
            return Annotation(f"response ({len(frame)} bytes): malformed", fields, "too short for a Modbus frame")
        crc_field, crc_error = self._crc_field(frame)
        checked = frame if not self.crc or crc_error is None else frame[:-CRC_LENGTH] + crc_bytes(frame[:-2])
        try:
            response = decode_response(checked, crc=self.crc, request=request)
        except CodecError as exc:
            what = "malformed"
            return Annotation(f"response ({len(frame)} bytes): {what}", [*fields, crc_field], str(exc))
        if isinstance(response, ReadResponse):
            start = request.address if isinstance(request, ReadRequest) else address
            fields.append(("byte count", f"{frame[2]:02X}", f"{frame[2]} bytes = {len(response.values)} register(s)"))
            for i, raw in enumerate(response.values):
                reg = None if start is None else start + i
                name = self.register_text(reg) + " = " if reg is not None else ""
                fields.append((f"value[{i}]", _hex(frame[3 + 2 * i : 5 + 2 * i]), name + self.value_text(reg, raw)))
            title = f"response: {len(response.values)} register(s) from unit {response.unit}"
            if start is None and self.profile is not None:
                title += " (give --address or the request first to name them)"
        elif isinstance(response, WriteResponse):
            fields.append(("address", _hex(frame[2:4]), self.register_text(response.address)))
            fields.append(("value", _hex(frame[4:6]), self.value_text(response.address, response.value)))
            title = (
                f"response: write 0x{response.value:04X} to 0x{response.address:04X} confirmed by unit {response.unit}"
            )
        elif isinstance(response, WriteRegistersResponse):  # a gateway's answer to FC16
            fields.append(("address", _hex(frame[2:4]), self.register_text(response.address)))
            fields.append(("count", _hex(frame[4:6]), f"{response.count} register(s)"))
            title = f"response: write of {response.count} register(s) from 0x{response.address:04X} confirmed"
        else:
            fields.append(("exception code", f"{response.code:02X}", exception_meaning(self.profile, response.code)))
            title = f"exception response from unit {response.unit} to FC{response.function:02X}"
        fields.append(crc_field)
        return Annotation(title, fields, crc_error)

    # -- splitting ------------------------------------------------------------------------------------

    def request_size(self, data: bytes) -> int:
        length = request_length(data[:11])
        if length is None:
            return len(data)
        return length - CRC_LENGTH + self.tail

    def response_size(self, data: bytes) -> int:
        if len(data) < 2:
            return len(data)
        function = data[1]
        if function & EXCEPTION_BIT:
            return 3 + self.tail
        if function == FunctionCode.READ_HOLDING_REGISTERS and len(data) >= 3:
            return 3 + data[2] + self.tail
        if function == FunctionCode.WRITE_SINGLE_REGISTER:
            return 6 + self.tail
        return len(data)

    def guess_is_request(self, data: bytes) -> bool:
        if len(data) < 2 or data[1] & EXCEPTION_BIT:
            return False
        if data[1] == FunctionCode.READ_HOLDING_REGISTERS:
            return len(data) >= 6 + self.tail and (len(data) != 3 + data[2] + self.tail or len(data) == 6 + self.tail)
        return data[1] != FunctionCode.WRITE_SINGLE_REGISTER or len(data) >= 6 + self.tail


def annotate(
    data: bytes,
    profile: Profile | None,
    *,
    direction: str | None = None,
    crc: bool = True,
    address: int | None = None,
) -> list[Annotation]:
    """Annotate one frame, or a request followed by its response."""
    if not data:
        return [Annotation("nothing to decode", [], "no bytes given")]
    annotator = Annotator(profile, crc=crc)
    out = _annotate(annotator, data, direction, address)
    if crc and any(a.error for a in out) and _reads_without_crc(data):
        first = out[0]
        hint = "these bytes read as a frame printed without its CRC: add --no-crc"
        out[0] = Annotation(first.title, first.fields, f"{first.error}; {hint}" if first.error else hint)
    return out


def _reads_without_crc(data: bytes) -> bool:
    """True if ``data`` decodes cleanly as frames without CRC (a request, a response, or both)."""
    try:
        return not any(a.error for a in _annotate(Annotator(None, crc=False), data, None, None))
    except CodecError:
        return False


def _annotate(annotator: Annotator, data: bytes, direction: str | None, address: int | None) -> list[Annotation]:
    is_request = annotator.guess_is_request(data) if direction is None else direction == "request"
    out: list[Annotation] = []
    if is_request:
        size = min(len(data), annotator.request_size(data))
        annotation, request = annotator.request(data[:size])
        out.append(annotation)
        rest = data[size:]
        if rest:
            if direction == "request":
                out.append(Annotation("trailing bytes", [("data", _hex(rest), "after the request")], "trailing bytes"))
            else:
                out.extend(_responses(annotator, rest, request, address))
        return out
    return _responses(annotator, data, None, address)


def _responses(
    annotator: Annotator, data: bytes, request: ReadRequest | WriteRequest | None, address: int | None
) -> list[Annotation]:
    size = annotator.response_size(data)
    # a short response (e.g. the JJR8000 manual's '02 06 02 01 90') is annotated whole and reported malformed
    frame = data if size > len(data) else data[:size]
    out = [annotator.response(frame, request, address)]
    rest = data[len(frame) :]
    if rest:
        out.append(Annotation("trailing bytes", [("data", _hex(rest), "after the response")], "trailing bytes"))
    return out
