"""The slave's side of the codec: what a simulated soft starter answers to each request (no I/O).

The rules follow the manuals (docs/manuals.md#2-modbus-rtu) and are written down in ``docs/modbus.md``:

- function codes other than 03 and 06: exception 01;
- FC03 with a quantity of 0 or more than the model's ``max_read_registers``: exception 03 (the Modbus
  application protocol checks the quantity before the address); any register of the range not in the map:
  exception 02; both data areas (measurements and parameters) are readable;
- FC06 to an address not in the map: 02; to the control word: drives the state machine (always echoed);
  to another measurement: 03 ("parameter cannot be modified"); to a parameter: the simulated starter decides,
  its refusals map to 02 (not available), 03 (out of range, read-only, locked while running) and 04 ("parameter
  modify" = 0; models without an exception 04 in their profile answer 03);
- unit 0 is the broadcast address: writes go to every starter, nothing is answered, reads are ignored;
- requests for units not served here are ignored (another slave on the line answers them).
"""

from __future__ import annotations

from collections.abc import Mapping

from starterbus.core import Kind, PointDef, Profile, Refusal, SimulatedStarter, SimulatorRefusal
from starterbus.transports.modbus.codec.messages import (
    BROADCAST,
    AnyRequest,
    ExceptionCode,
    ExceptionResponse,
    OtherRequest,
    ReadRequest,
    ReadResponse,
    Response,
    WriteRequest,
    WriteResponse,
)
from starterbus.transports.modbus.settings import PROTOCOL, max_read_registers, modbus_settings

__all__ = ["SlaveLogic", "point_at", "refusal_code"]


def refusal_code(profile: Profile, reason: Refusal) -> int:
    """The exception code a refusal of the simulated starter becomes on Modbus."""
    if reason is Refusal.NOT_AVAILABLE:
        return ExceptionCode.ILLEGAL_DATA_ADDRESS
    exceptions = modbus_settings(profile).exceptions
    if reason is Refusal.WRITE_PROTECTED and ExceptionCode.PARAMETER_MODIFY_FORBIDDEN in exceptions:
        return ExceptionCode.PARAMETER_MODIFY_FORBIDDEN
    return ExceptionCode.ILLEGAL_DATA_VALUE


def point_at(starter: SimulatedStarter, address: int) -> PointDef:
    """The point at a register, measurements first (raises SimulatorRefusal NOT_AVAILABLE)."""
    try:
        return starter.point_at(PROTOCOL, Kind.MEASUREMENT, address)
    except SimulatorRefusal:
        return starter.point_at(PROTOCOL, Kind.PARAMETER, address)


class SlaveLogic:
    """Answers requests for the starters of one line, keyed by unit id."""

    def __init__(self, starters: Mapping[int, SimulatedStarter]) -> None:
        if not starters:
            raise ValueError("a Modbus slave needs at least one simulated starter")
        for unit in starters:
            if not 1 <= unit <= 247:
                raise ValueError(f"unit id {unit} is not 1..247 (0 is the broadcast address)")
        self.starters = dict(starters)

    def handle(self, request: AnyRequest) -> Response | None:
        """The answer to send, or None when the slave stays silent (broadcast, other unit)."""
        if request.unit == BROADCAST:
            if isinstance(request, WriteRequest):
                for starter in self.starters.values():
                    self._write(starter, request)
            return None
        served = self.starters.get(request.unit)
        if served is None:
            return None
        if isinstance(request, OtherRequest):
            return ExceptionResponse(request.unit, request.function, ExceptionCode.ILLEGAL_FUNCTION)
        if isinstance(request, ReadRequest):
            return self._read(served, request)
        return self._write(served, request)

    @staticmethod
    def _read(starter: SimulatedStarter, request: ReadRequest) -> Response:
        limit = max_read_registers(starter.profile)
        if not 1 <= request.count <= limit:
            return ExceptionResponse(request.unit, request.function, ExceptionCode.ILLEGAL_DATA_VALUE)
        values = []
        with starter.lock:
            for address in range(request.address, request.address + request.count):
                try:
                    if address > 0xFFFF:
                        raise SimulatorRefusal(Refusal.NOT_AVAILABLE, f"register {address:#x} does not exist")
                    values.append(starter.read(point_at(starter, address)))
                except SimulatorRefusal as refusal:
                    code = refusal_code(starter.profile, refusal.reason)
                    return ExceptionResponse(request.unit, request.function, code)
        return ReadResponse(request.unit, tuple(v & 0xFFFF for v in values))

    @staticmethod
    def _write(starter: SimulatedStarter, request: WriteRequest) -> Response:
        profile = starter.profile
        try:
            point = point_at(starter, request.address)
            if point.key == profile.roles.get("control_word"):
                starter.write_control_word(
                    request.value, cyclic=False, source=f"Modbus FC{request.function:02d} unit {request.unit}"
                )
            elif point.kind is Kind.MEASUREMENT:
                raise SimulatorRefusal(Refusal.READ_ONLY, f"{point.key} is a measurement")
            else:
                starter.write(point, request.value)
        except SimulatorRefusal as refusal:
            code = refusal_code(profile, refusal.reason)
            return ExceptionResponse(request.unit, request.function, code)
        return WriteResponse(request.unit, request.address, request.value)
