"""``read --raw ADDR:COUNT`` and ``write --raw ADDR=VALUE``: holding registers below the model, for experts (the
habits of mbpoll and modpoll).

A raw write bypasses the model by definition: no range, no enum, no scale, no certainty check. What it keeps
of the guarded path: it says so on stderr, asks for confirmation (``--yes`` without a terminal), writes the
audit log (refusals too), shows the exact frame with ``--dry-run`` (nothing opened, nothing sent), reads back,
and still refuses what would surprise the plant: the register of the control word (that is an actuation: use
``start``/``stop``/``reset``), and a register the model locks while the motor runs, unless the status shows it
stopped. The transport must speak the ``modbus`` address space (:class:`~starterbus.spaces.modbus.RegisterAccess`).
"""

from __future__ import annotations

import argparse
import getpass
import sys
from dataclasses import dataclass

from starterbus.cli.output import emit_json, table
from starterbus.core.audit import AuditLog
from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    ConfigurationError,
    RemoteDeviceError,
    StarterbusError,
    StateRuleError,
    UnsupportedOperationError,
    ValidationError,
)
from starterbus.core.guarded import ConfirmationRefused, GuardedOperationError
from starterbus.core.model import PointDef
from starterbus.core.status import MotorState
from starterbus.spaces.modbus import MAX_READ_REGISTERS, SPACE_NAME, RegisterAccess

WARNING = "write --raw: bypasses the model (no range, enum or scale check): the value goes to the register as given"
_IDLE = (MotorState.READY, MotorState.STOPPED)


def _number(text: str, what: str, high: int) -> int:
    try:
        value = int(text.strip(), 0)
    except ValueError:
        raise ValidationError(f"{what} {text!r}: not a number (decimal, or hex as 0x0100)") from None
    if not 0 <= value <= high:
        raise ValidationError(f"{what} {text!r}: outside 0..{high} (0x{high:X})")
    return value


def parse_span(text: str) -> tuple[int, int]:
    """``0x0100:4`` -> (0x0100, 4); ``0x0100`` -> (0x0100, 1)."""
    first, sep, count = text.partition(":")
    address = _number(first, "--raw address", 0xFFFF)
    number = _number(count, "--raw count", MAX_READ_REGISTERS) if sep else 1
    if number < 1 or address + number - 1 > 0xFFFF:
        raise ValidationError(f"--raw {text}: 1..{MAX_READ_REGISTERS} registers, none past 0xFFFF")
    return address, number


def parse_assignment(text: str) -> tuple[int, int]:
    """``0x0103=380`` -> (0x0103, 380); the value 0..65535 (or hex)."""
    address, sep, value = text.partition("=")
    if not sep:
        raise ValidationError(f"--raw {text!r}: not ADDRESS=VALUE (e.g. 0x0103=380)")
    return _number(address, "--raw address", 0xFFFF), _number(value, "--raw value", 0xFFFF)


def registers_of(device: Device, command: str) -> RegisterAccess:
    """The device's transport as raw register access, or the one-line refusal naming the transport."""
    transport = device.transport
    if isinstance(transport, RegisterAccess):
        return transport
    from starterbus.core.address_space import speakers

    raise UnsupportedOperationError(
        f"{command} --raw: the {transport.name} transport has no Modbus register address space "
        f"({device.describe()}); raw register access needs one of: {', '.join(speakers(SPACE_NAME)) or 'none'}"
    )


def _points_at(device: Device) -> dict[int, PointDef]:
    return {a: p for p in device.profile.points.values() if (a := p.address_for(SPACE_NAME)) is not None}


def cmd_read_raw(args: argparse.Namespace) -> int:
    if not args.keys:
        raise ValidationError("read --raw: give ADDRESS:COUNT (e.g. 0x0100:4)")
    spans = [parse_span(text) for text in args.keys]
    device = open_device(args.url, args.model)
    registers = registers_of(device, "read")
    known = _points_at(device)
    rows = []
    with device:
        for address, count in spans:
            for offset, value in enumerate(registers.read_registers(address, count)):
                point = known.get(address + offset)
                rows.append((address + offset, value, point.key if point is not None else None))
    if args.json:
        emit_json({
            "device": args.url, "model": device.profile.name, "raw": True,
            "registers": [{"address": f"0x{a:04X}", "value": v, "hex": f"0x{v:04X}", "key": k} for a, v, k in rows],
        })  # fmt: skip
    else:
        signed = [v - 0x10000 if v & 0x8000 else v for _, v, _ in rows]
        table(
            ["address", "dec", "hex", "signed", "key"],
            [[f"0x{a:04X}", v, f"0x{v:04X}", s, k or "-"] for (a, v, k), s in zip(rows, signed, strict=True)],
        )
    return 0


@dataclass(slots=True)
class RawOutcome:
    address: int
    value: int
    key: str | None
    old: int | None = None
    read_back: int | None = None
    result: str = "not sent"

    def as_json(self) -> dict[str, object]:
        return {"address": f"0x{self.address:04X}", "key": self.key, "old": self.old, "new": self.value,
                "read_back": self.read_back, "result": self.result}  # fmt: skip


def _refuse_control_word(device: Device, writes: list[tuple[int, int]]) -> None:
    control = device.profile.role("control_word")
    control_address = control.address_for(SPACE_NAME) if control is not None else None
    for address, _ in writes:
        if address == control_address:
            raise StateRuleError(
                f"write --raw 0x{address:04X}: the control word: a raw write there actuates; use start, stop or "
                "reset (they check the state); nothing sent"
            )


def _refuse_while_running(device: Device, writes: list[tuple[int, int]], known: dict[int, PointDef]) -> None:
    """A register the model locks while running: only with the motor stopped (the status is read to know)."""
    rules = device.profile.control.locked_while_running
    locked = [known[a].key for a, _ in writes if a in known and known[a].key in rules]
    if locked:
        state = device.guard.fresh_status().state
        if state not in _IDLE:
            raise StateRuleError(
                f"write --raw: {', '.join(locked)}: {device.profile.display_name} locks it while the motor is "
                f"{state.value}; stop the motor first; nothing sent"
            )


def _confirm(args: argparse.Namespace, question: str, frames: list[str]) -> bool:
    if args.yes:
        return True
    if not sys.stdin.isatty():
        raise ConfirmationRefused(f"{question}: refused without --yes (no terminal to confirm on)")
    for frame in frames:
        print(f"  frame: {frame}", file=sys.stderr)
    print(f"{question}? [y/N] ", end="", file=sys.stderr, flush=True)
    return sys.stdin.readline().strip().lower() in ("y", "yes")


def cmd_write_raw(args: argparse.Namespace) -> int:
    if args.accept_uncertain:
        raise ConfigurationError("write --raw: --accept-uncertain is for model values; a raw write has no model check")
    writes = [parse_assignment(text) for text in args.assignments]
    device = open_device(args.url, args.model)
    registers = registers_of(device, "write")
    known = _points_at(device)
    frames = [f for a, v in writes for f in registers.preview_register_write(a, v)]
    print(f"starterbus: warning: {WARNING}", file=sys.stderr)
    if args.dry_run:
        _show_dry_run(args, [(a, v, registers.preview_register_write(a, v)) for a, v in writes])
        return 0
    audit = AuditLog(args.audit_log)
    who = {"device": device.transport.url.text, "model": device.profile.name, "actor": f"cli:{getpass.getuser()}"}
    question = f"write --raw {', '.join(f'0x{a:04X}={v}' for a, v in writes)} to {device.describe()}"
    outcomes = [RawOutcome(a, v, known[a].key if a in known else None) for a, v in writes]
    try:
        _refuse_control_word(device, writes)
        if not _confirm(args, question, frames):
            raise ConfirmationRefused(f"{question}: not confirmed; nothing sent")
    except StarterbusError as exc:
        audit.append(**who, action="write-raw", what=question, result=f"refused: {exc}")
        raise
    with device:
        try:
            _refuse_while_running(device, writes, known)  # reads the status only when a locked register is asked
        except StarterbusError as exc:
            audit.append(**who, action="write-raw", what=question, result=f"refused: {exc}")
            raise
        failure: StarterbusError | None = None
        for outcome in outcomes:
            try:
                outcome.old = _read_one(registers, outcome.address)
                registers.write_register(outcome.address, outcome.value)
                outcome.result = "sent, not verified"
                outcome.read_back = _read_one(registers, outcome.address)
                outcome.result = "ok" if outcome.read_back == outcome.value else "mismatch"
            except StarterbusError as exc:
                failure = exc
                outcome.result = outcome.result if outcome.result != "not sent" else "failed"
            audit.append(**who, action="write-raw", **outcome.as_json())
            if failure is not None or outcome.result != "ok":
                break
    _show(args, device, outcomes, to_stderr=failure is not None or outcomes[-1].result not in ("ok", "not sent"))
    if failure is not None:
        raise failure
    mismatched = [o for o in outcomes if o.result == "mismatch"]
    if mismatched:
        o = mismatched[0]
        raise GuardedOperationError(f"0x{o.address:04X}: wrote {o.value} but read back {o.read_back}", [])
    return 0


def _show_dry_run(args: argparse.Namespace, rows: list[tuple[int, int, list[str]]]) -> None:
    """What would be sent, and nothing sent (``write``'s dry-run document, with ``"raw": true``)."""
    if args.json:
        would = [{"address": f"0x{a:04X}", "value": v, "frames": frames} for a, v, frames in rows]
        emit_json({"device": args.url, "dry_run": True, "raw": True, "would_send": would})
        return
    print(f"dry run: nothing sent to {args.url}")
    for address, value, frames in rows:
        print(f"  0x{address:04X} = {value} (0x{value:04X})")
        for frame in frames:
            print(f"    {frame}")


def _read_one(registers: RegisterAccess, address: int) -> int | None:
    """The register's value; None when the device refuses to read it (a write-only register)."""
    try:
        return registers.read_registers(address, 1)[0]
    except RemoteDeviceError:
        return None


def _show(args: argparse.Namespace, device: Device, outcomes: list[RawOutcome], *, to_stderr: bool) -> None:
    if args.json and not to_stderr:
        emit_json({"device": args.url, "model": device.profile.name, "raw": True,
                   "written": [o.as_json() for o in outcomes]})  # fmt: skip
        return
    if args.json:
        return
    rows = [[f"0x{o.address:04X}", o.key or "-", "-" if o.old is None else o.old, o.value,
             "-" if o.read_back is None else o.read_back, o.result] for o in outcomes]  # fmt: skip
    table(["address", "key", "old", "new", "read back", "result"], rows, out=sys.stderr if to_stderr else None)
