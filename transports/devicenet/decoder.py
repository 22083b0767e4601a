"""Annotating DeviceNet frames for ``starterbus decode devicenet ID#DATA ...`` (candump syntax).

:class:`FrameAnnotator` is stateful across the frames it is given, in order: it reassembles fragmented explicit
messages (per identifier), remembers each slave's last explicit request to name the attribute a response
carries, and the last status parameter address a poll command selected to name the value the next poll
response reports. Every frame gives one :class:`~starterbus.core.transport.Annotation`; a frame that cannot be
decoded gives one with ``error`` set (and as many fields as could be read).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

from starterbus.core import Annotation, CanFrame, Kind, Profile, StarterbusError, annotate_candump
from starterbus.transports.devicenet.codec import cip
from starterbus.transports.devicenet.codec.assemblies import (
    INPUT_SIZES,
    OUTPUT_SIZES,
    InputAssembly,
    decode_input,
    decode_output,
)
from starterbus.transports.devicenet.codec.cip import ObjectClass, Service
from starterbus.transports.devicenet.codec.connection import (
    CONNECTION_ATTRIBUTE_NAMES,
    DEVICENET_ATTRIBUTE_NAMES,
    ConnectionAttribute,
    ConnectionState,
    DeviceNetAttribute,
    describe_choice,
)
from starterbus.transports.devicenet.codec.dupmac import decode_duplicate_mac
from starterbus.transports.devicenet.codec.explicit import (
    ErrorResponse,
    ExplicitRequest,
    ExplicitResponse,
    decode_header,
    decode_message,
)
from starterbus.transports.devicenet.codec.fragmentation import FragmentType, Reassembler, decode_fragment, is_fragment
from starterbus.transports.devicenet.codec.identity import ATTRIBUTE_NAMES, decode_attribute
from starterbus.transports.devicenet.codec.ids import Group, Group1, Group2, parse_id

Field = tuple[str, str, str]
_BAUDS = {0: "125 kbit/s", 1: "250 kbit/s", 2: "500 kbit/s"}
_EXPLICIT_IDS = {Group2.SLAVE_EXPLICIT_RESPONSE, Group2.MASTER_EXPLICIT_REQUEST, Group2.UNCONNECTED_REQUEST}


def _hex(data: bytes) -> str:
    return data.hex(" ").upper() if data else "-"


class FrameAnnotator:
    def __init__(self, profile: Profile | None = None) -> None:
        self.profile = profile
        self._reassemblers: dict[int, Reassembler] = {}
        self._fragments: dict[int, int] = {}
        self._requests: dict[int, ExplicitRequest] = {}
        self._selected: dict[int, int] = {}
        self._output_instance: dict[int, int] = {}

    def annotate_text(self, texts: Iterable[str]) -> list[Annotation]:
        return annotate_candump(texts, self.annotate, "the DeviceNet decoder")

    def annotate(self, frame: CanFrame) -> Annotation:
        fields: list[Field] = []
        try:
            ident = parse_id(frame.can_id)
        except StarterbusError as exc:
            return Annotation(frame.text(), fields, str(exc))
        title = f"{frame.text()}  {ident.describe()}"
        fields.append(
            ("identifier", f"0x{frame.can_id:03X}", f"group {int(ident.group)}, message id {ident.message_id}")
        )
        if ident.mac is not None:
            if ident.group is Group.GROUP_2 and ident.message_id == Group2.DUPLICATE_MAC_CHECK:
                role = "the MAC id being checked (the sender's own)"
            elif ident.group in (Group.GROUP_1, Group.GROUP_2):
                role = "slave"
            else:
                role = "source"
            fields.append(("MAC id", str(ident.mac), role))
        try:
            if ident.group is Group.GROUP_2 and ident.mac is not None:
                if ident.message_id in _EXPLICIT_IDS:
                    self._explicit(frame, ident.mac, ident.message_id, fields)
                elif ident.message_id == Group2.DUPLICATE_MAC_CHECK:
                    self._duplicate_mac(frame, fields)
                elif ident.message_id == Group2.POLL_COMMAND:
                    self._poll_command(frame.data, ident.mac, fields)
                else:
                    fields.append(("data", _hex(frame.data), "not used by the JJR8000 (polled + explicit only)"))
            elif ident.group is Group.GROUP_1 and ident.message_id == Group1.POLL_RESPONSE and ident.mac is not None:
                self._poll_response(frame.data, ident.mac, fields)
            else:
                fields.append(("data", _hex(frame.data), "not part of the Predefined Master/Slave Connection Set"))
        except StarterbusError as exc:
            return Annotation(title, fields, str(exc))
        return Annotation(title, fields)

    # -- explicit ----------------------------------------------------------------------------------------------

    def _explicit(self, frame: CanFrame, slave: int, message_id: int, fields: list[Field]) -> None:
        data = frame.data
        if not data:
            raise cip.FrameTooShortError("explicit message frame without data", data, "header")
        header = decode_header(data[0])
        fields.append(
            (
                "header",
                f"0x{data[0]:02X}",
                f"{'fragmented, ' if header.fragmented else ''}XID {header.xid}, master MAC {header.mac}",
            )
        )
        message = data
        if is_fragment(data):
            fragment = decode_fragment(data)
            if fragment.is_ack:
                status = fragment.ack_status
                meaning = {0: "success", 1: "too much data"}.get(status, f"unknown status {status}")
                fields.append(("fragment", f"0x{data[1]:02X}", f"acknowledgement of fragment {fragment.count}"))
                fields.append(("ack status", f"0x{status:02X}", meaning))
                return
            kind = FragmentType(fragment.kind).name.lower()
            fields.append(("fragment", f"0x{data[1]:02X}", f"{kind} fragment, count {fragment.count}"))
            fields.append(("payload", _hex(fragment.payload), f"{len(fragment.payload)} body byte(s)"))
            reassembler = self._reassemblers.setdefault(frame.can_id, Reassembler())
            try:
                _, whole = reassembler.feed(data)
            except StarterbusError:
                self._fragments.pop(frame.can_id, None)
                raise
            self._fragments[frame.can_id] = self._fragments.get(frame.can_id, 0) + 1
            if whole is None:
                return
            count = self._fragments.pop(frame.can_id, 0)
            fields.append(("reassembled", _hex(whole), f"{len(whole)} bytes from {count} fragments"))
            message = whole
        decoded = decode_message(message)
        if isinstance(decoded, ExplicitRequest):
            self._request_fields(decoded, slave, message_id, fields)
        elif isinstance(decoded, ErrorResponse):
            request = self._requests.pop(slave, None)
            cip_status = decoded.status
            fields.append(
                ("service", "0x94", "Error_Response" + (f" to {cip.service_name(request.service)}" if request else ""))
            )
            fields.append(("general status", f"0x{cip_status.general:02X}", cip_status.meaning))
            service = request.service if request else None
            extra = cip.additional_status_text(cip_status.general, cip_status.additional, service)
            fields.append(("additional status", f"0x{cip_status.additional:02X}", extra))
        else:
            self._response_fields(decoded, slave, fields)

    def _request_fields(self, request: ExplicitRequest, slave: int, message_id: int, fields: list[Field]) -> None:
        port = " (group 2 only unconnected port)" if message_id == Group2.UNCONNECTED_REQUEST else ""
        fields.append(("service", f"0x{request.service:02X}", cip.service_name(request.service) + " request" + port))
        fields.append(("class", f"0x{request.class_id:02X}", cip.class_name(request.class_id)))
        fields.append(("instance", str(request.instance), self._instance_name(request.class_id, request.instance)))
        if request.attribute is not None:
            fields.append(
                ("attribute", str(request.attribute), self._attribute_name(request.class_id, request.attribute))
            )
        if request.service == Service.ALLOCATE and len(request.data) >= 1:
            fields.append(("allocation choice", f"0x{request.data[0]:02X}", describe_choice(request.data[0])))
            if len(request.data) >= 2:
                fields.append(("allocator MAC", str(request.data[1]), "master"))
        elif request.service == Service.RELEASE and request.data:
            fields.append(("release choice", f"0x{request.data[0]:02X}", describe_choice(request.data[0])))
        elif request.data:
            meaning = self._value(request.class_id, request.instance, request.attribute, request.data)
            fields.append(("data", _hex(request.data), meaning))
        self._requests[slave] = request

    def _response_fields(self, response: ExplicitResponse, slave: int, fields: list[Field]) -> None:
        request = self._requests.pop(slave, None)
        fields.append(("service", f"0x{response.service | 0x80:02X}", cip.service_name(response.service) + " response"))
        if response.service == Service.ALLOCATE and response.data:
            body = response.data[0]
            fields.append(("message body format", str(body), {0: "DeviceNet 8/8"}.get(body, f"format {body}")))
            return
        if not response.data:
            return
        meaning = ""
        if request is not None and request.service == response.service:
            if request.service == Service.GET_ATTRIBUTES_ALL and request.class_id == ObjectClass.IDENTITY:
                meaning = "identity attributes 1-7"
            else:
                meaning = self._value(request.class_id, request.instance, request.attribute, response.data)
        fields.append(("data", _hex(response.data), meaning))

    @staticmethod
    def _instance_name(class_id: int, instance: int) -> str:
        if instance == 0:
            return "class attributes"
        if class_id == ObjectClass.CONNECTION:
            return {1: "explicit connection", 2: "polled I/O connection", 3: "bit-strobe", 4: "COS/cyclic"}.get(
                instance, ""
            )
        if class_id == ObjectClass.ASSEMBLY:
            return {1: "input, basic", 101: "input, extended", 2: "output, basic", 102: "output, extended"}.get(
                instance, ""
            )
        return ""

    @staticmethod
    def _attribute_name(class_id: int, attribute: int) -> str:
        if class_id == ObjectClass.IDENTITY:
            return ATTRIBUTE_NAMES.get(attribute, "")
        if class_id == ObjectClass.CONNECTION:
            return CONNECTION_ATTRIBUTE_NAMES.get(attribute, "")
        if class_id == ObjectClass.DEVICENET:
            return DEVICENET_ATTRIBUTE_NAMES.get(attribute, "")
        if class_id == ObjectClass.ASSEMBLY and attribute == 3:
            return "data"
        return ""

    def _value(self, class_id: int, instance: int, attribute: int | None, data: bytes) -> str:
        """Best-effort meaning of attribute data (never raises: unknown layouts stay raw)."""
        try:
            if class_id == ObjectClass.IDENTITY and instance == 1 and attribute in ATTRIBUTE_NAMES:
                value = decode_attribute(attribute, data)
                if attribute == 4 and isinstance(value, tuple):
                    return f"revision {value[0]}.{value[1]}"
                if attribute == 7:
                    return f"product name {value!r}"
                return f"{ATTRIBUTE_NAMES[attribute]} {value}"
            if class_id == ObjectClass.CONNECTION and attribute is not None:
                return self._connection_value(attribute, data)
            if class_id == ObjectClass.DEVICENET and attribute is not None:
                if attribute == DeviceNetAttribute.ALLOCATION_INFORMATION and len(data) == 2:
                    master = "none" if data[1] == 0xFF else str(data[1])
                    return f"allocated: {describe_choice(data[0])}, master MAC {master}"
                if attribute == DeviceNetAttribute.BAUD_RATE and len(data) == 1:
                    return _BAUDS.get(data[0], f"baud code {data[0]}")
                if attribute == DeviceNetAttribute.MAC_ID and len(data) == 1:
                    return f"MAC id {data[0]}"
            if class_id == ObjectClass.ASSEMBLY and attribute == 3:
                if instance in INPUT_SIZES:
                    return self._input_text(decode_input(data, instance))
                if instance in OUTPUT_SIZES:
                    return ", ".join(decode_output(data, instance).bit_names())
        except StarterbusError as exc:
            return f"cannot decode: {exc}"
        return ""

    @staticmethod
    def _connection_value(attribute: int, data: bytes) -> str:
        if attribute == ConnectionAttribute.STATE and len(data) == 1:
            return ConnectionState(data[0]).name.lower().replace("_", " ") if data[0] <= 5 else f"state {data[0]}"
        if len(data) == 2 and attribute in (
            ConnectionAttribute.PRODUCED_CONNECTION_SIZE,
            ConnectionAttribute.CONSUMED_CONNECTION_SIZE,
            ConnectionAttribute.PRODUCED_CONNECTION_PATH_LENGTH,
            ConnectionAttribute.CONSUMED_CONNECTION_PATH_LENGTH,
        ):
            return f"{struct.unpack('<H', data)[0]} bytes"
        if len(data) == 2 and attribute == ConnectionAttribute.EXPECTED_PACKET_RATE:
            ms = struct.unpack("<H", data)[0]
            return (
                f"expected packet rate {ms} ms (inactivity timeout {4 * ms} ms)"
                if ms
                else "expected packet rate 0 (no watchdog)"
            )
        if len(data) == 2 and attribute in (
            ConnectionAttribute.PRODUCED_CONNECTION_ID,
            ConnectionAttribute.CONSUMED_CONNECTION_ID,
        ):
            return f"CAN identifier 0x{struct.unpack('<H', data)[0]:03X}"
        if attribute == ConnectionAttribute.WATCHDOG_TIMEOUT_ACTION and len(data) == 1:
            return {0: "transition to timed out", 1: "auto delete", 2: "auto reset", 3: "deferred delete"}.get(
                data[0], ""
            )
        return ""

    # -- I/O and others --------------------------------------------------------------------------------------

    def _duplicate_mac(self, frame: CanFrame, fields: list[Field]) -> None:
        message = decode_duplicate_mac(frame)
        fields.append(
            (
                "request/response",
                f"0x{frame.data[0]:02X}",
                ("response" if message.response else "request") + f", port {message.port}",
            )
        )
        fields.append(("vendor id", str(message.vendor_id), ""))
        fields.append(("serial number", f"0x{message.serial_number:08X}", ""))

    def _poll_command(self, data: bytes, slave: int, fields: list[Field]) -> None:
        if not data:
            fields.append(("data", "-", "zero-length poll command: master idle"))
            return
        output = decode_output(data)
        self._output_instance[slave] = output.instance
        fields.append(("output assembly", str(output.instance), "basic" if output.instance == 2 else "extended"))
        fields.append(("byte 0", f"0x{output.bits:02X}", ", ".join(output.bit_names())))
        if output.address is not None:
            self._selected[slave] = output.address
            fields.append(
                ("byte 1", f"0x{output.address:02X}", f"status parameter {self._measurement_name(output.address)}")
            )

    def _poll_response(self, data: bytes, slave: int, fields: list[Field]) -> None:
        inputs = decode_input(data)
        fields.append(("input assembly", str(inputs.instance), "basic" if inputs.instance == 1 else "extended"))
        fields.append(("byte 0", f"0x{inputs.bits:02X}", ", ".join(inputs.bit_names()) or "no bit set"))
        if inputs.instance == 101:
            code = inputs.code or 0
            if inputs.bits & 0x01 and code:
                meaning = self.profile.faults.text(code) if self.profile else f"fault code {code}"
            else:
                meaning = "fault/warning code" if code else "no code"
            fields.append(("byte 1", f"0x{code:02X}", meaning))
        else:
            fields.append(("byte 1", f"0x{inputs.reserved:02X}", "reserved"))
        fields.append(("bytes 2-3", _hex(data[2:4]), f"L1 current {inputs.current_a} A (resolution 1 A)"))
        if inputs.instance == 101:
            fields.append(("bytes 4-5", _hex(data[4:6]), self._selected_text(slave, inputs)))

    def _input_text(self, inputs: InputAssembly) -> str:
        text = ", ".join(inputs.bit_names()) or "no bit set"
        return f"{text}; L1 {inputs.current_a} A"

    def _measurement_name(self, address: int) -> str:
        if self.profile is not None:
            point = self.profile.by_protocol_address(cip.PROTOCOL, Kind.MEASUREMENT, address)
            if point is not None:
                return f"0x{address:02X} {point.key} ({point.address})"
            return f"0x{address:02X} (not defined for {self.profile.name})"
        return f"0x{address:02X}"

    def _selected_text(self, slave: int, inputs: InputAssembly) -> str:
        value = inputs.selected_value or 0
        address = self._selected.get(slave)
        if address is None:
            return f"selected status parameter = {value} (address unknown: no poll command seen)"
        if self.profile is not None:
            point = self.profile.by_protocol_address(cip.PROTOCOL, Kind.MEASUREMENT, address)
            if point is not None:
                shown = point.to_engineering(value)
                return f"{point.key} = {shown} {point.unit}".rstrip() + f" (raw {value}, address 0x{address:02X})"
        return f"status parameter 0x{address:02X} = {value}"


def annotate_frames(texts: Iterable[str], profile: Profile | None = None) -> list[Annotation]:
    return FrameAnnotator(profile).annotate_text(texts)
