"""Restoring a backup into a device: diff first, validate all, write only what differs, in the device's order.

Order and rules:

1. a backup of another model is refused;
2. the device's parameters are read and compared with the backup; only differing, writable parameters are
   planned; settings of the link itself (address, baud rate, parity, stop bits, bus type) are never written
   here (the next read-back would go to the old address or speed): they are reported as ``not restored``
   with the reason, as are actions disguised as parameters (``factory_reset``) and per-unit calibrations
   (``test_program_*``);
3. every planned value is validated by the guarded path before anything is sent: range, enum, access,
   certainty (uncertain codes need ``accept_uncertain``) and the state rule (parameters the profile locks
   while running need a stopped motor);
4. the write-protect parameter (``parameter_modify``) is set to "enabled" first when it forbids writes, and
   written with the backup's value last;
5. the writes are confirmed once, then sent one by one, each read back and audited (the core's guard).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from starterbus.core.device import Device
from starterbus.core.errors import StarterbusError, UnsupportedOperationError, ValidationError
from starterbus.core.guarded import Outcome, PlannedWrite
from starterbus.core.model import PointDef, Value
from starterbus.core.profile import Profile
from starterbus.core.transport import Capability
from starterbus.ops.backup import Backup, take_backup
from starterbus.ops.diff import ParameterSet, Row, compare

#: parameters a restore never writes, with the reason it says
NOT_RESTORED: dict[str, str] = {
    "slave_address": "a setting of the link itself: write it on its own, then reconnect",
    "baudrate": "a setting of the link itself: write it on its own, then reconnect",
    "parity": "a setting of the link itself: write it on its own, then reconnect",
    "stop_bits": "a setting of the link itself: write it on its own, then reconnect",
    "bus_type": "a setting of the link itself: write it on its own, then reconnect",
    "profibus_type": "a setting of the link itself: write it on its own, then reconnect",
    "factory_reset": "an action (restore factory defaults), not a setting",
}
_CALIBRATION_PREFIX = "test_program_"


def not_restored_reason(point: PointDef) -> str | None:
    if point.key in NOT_RESTORED:
        return NOT_RESTORED[point.key]
    if point.key.startswith(_CALIBRATION_PREFIX):
        return "a calibration of this unit, not a setting to copy"
    if not point.writable:
        return "read-only"
    return None


@dataclass(slots=True)
class RestorePlan:
    device: str
    rows: list[Row]  # the diff, backup (a) against device (b)
    writes: list[tuple[PointDef, int]]  # in the order they will be sent
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (key, why it is not written)
    planned: list[PlannedWrite] = field(default_factory=list)  # validated by the guard
    unprotect: tuple[PointDef, int, int] | None = None  # (protect point, enabled raw, original raw)


def _enabled_raw(point: PointDef) -> int:
    if point.enum is not None:
        for raw, label in point.enum.labels.items():
            if label.en.casefold() in ("enabled", "allowed", "yes", "on") and raw != 0:
                return raw
    return 1


def plan(backup: Backup, device: Device, *, accept_uncertain: bool = False) -> RestorePlan:
    """Read the device, compare, order and validate the writes (through the guard); sends no write."""
    profile: Profile = device.profile
    if backup.model != profile.name:
        raise ValidationError(
            f"this is a backup of a {backup.model} and {device.describe()} is a {profile.name}: "
            "a backup is restored only into the same model (compare them with `starterbus diff`); nothing sent"
        )
    if Capability.READ_PARAMETERS not in device.capabilities:
        raise UnsupportedOperationError(
            f"{device.transport.name} ({device.transport.describe()}) cannot read parameters, so a restore could "
            "neither compare nor read back; use a path with a parameter channel (Modbus RTU, Profibus PPO1)"
        )
    current = take_backup(device)
    rows = compare(
        ParameterSet("backup", profile, backup.raws()), ParameterSet(device.describe(), profile, current.raws())
    )
    result = RestorePlan(device.describe(), rows, [])
    protect_key = profile.control.write_protect_key
    protect_row: Row | None = None
    for row in rows:
        point = profile.points[row.key]
        why = not_restored_reason(point)
        if why is not None:
            result.skipped.append((row.key, why))
        elif row.raw_a is None:
            result.skipped.append((row.key, "not in the backup"))
        elif row.key == protect_key:
            protect_row = row
        else:
            result.writes.append((point, row.raw_a))
    if protect_key and result.writes:
        point = profile.points[protect_key]
        now = current.raws()[protect_key]
        wanted = protect_row.raw_a if protect_row is not None and protect_row.raw_a is not None else now
        if now == 0:
            enabled = _enabled_raw(point)
            result.unprotect = (point, enabled, now)
            result.writes.insert(0, (point, enabled))
            if wanted != enabled:
                result.writes.append((point, wanted))
        elif wanted != now:
            result.writes.append((point, wanted))
    elif protect_row is not None and protect_row.raw_a is not None:
        result.writes.append((profile.points[protect_key], protect_row.raw_a))
    if result.writes:
        result.planned = device.guard.plan_writes(
            [(p, _as_value(p, raw)) for p, raw in result.writes],
            accept_uncertain=accept_uncertain,
        )
    return result


def execute(restore: RestorePlan, device: Device, *, accept_uncertain: bool = False) -> list[Outcome]:
    """Write the plan through the guarded path (one confirmation, each write read back and audited).

    If a write fails after the write protection was lifted, the protection is put back (also audited) before
    the error is re-raised; ``device.guard.last_outcomes`` then holds what happened to each parameter.
    """
    if not restore.writes:
        return []
    items = [(p.point, p.raw) for p in restore.planned]
    try:
        return device.guard.write(
            [(point, _as_value(point, raw)) for point, raw in items], accept_uncertain=accept_uncertain
        )
    except StarterbusError:
        outcomes = list(device.guard.last_outcomes)
        if restore.unprotect is not None and outcomes and outcomes[0].ok:
            point, _, original = restore.unprotect
            try:
                outcomes += device.guard.write([(point, _as_value(point, original))])
            except StarterbusError:
                outcomes += device.guard.last_outcomes
        device.guard.last_outcomes = outcomes
        raise


def _as_value(point: PointDef, raw: int) -> float | int | str:
    """The guard takes engineering values; hand it the exact raw word back (bit fields and enums as raw)."""
    if point.bits or point.enum is not None:
        return str(raw)
    return Value.from_raw(point, raw).value
