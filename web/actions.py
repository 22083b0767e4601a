"""Operator actions from the pages that need more than one call of the fleet's remote path: a restore."""

from __future__ import annotations

from starterbus.aio import AsyncFleet, RemoteNotAllowed
from starterbus.core.device import Device
from starterbus.core.errors import ConfigurationError, ValidationError
from starterbus.core.guarded import Outcome
from starterbus.core.status import Command
from starterbus.ops import backup as backups
from starterbus.ops import restore

#: the commands a page may send (the names of the fleet file's ``remote.commands``)
COMMANDS = {"start": Command.START, "stop": Command.SOFT_STOP, "reset": Command.FAULT_RESET}


async def restore_device(fleet: AsyncFleet, name: str, text: str, *, actor: str) -> list[Outcome]:
    """Restore an uploaded backup into device ``name``: planned against the device (read, compared, validated),
    refused unless the fleet file's ``remote.write`` allows every parameter it would write, then written
    through the guarded path in the device's bus worker, each write read back and audited as ``actor``."""
    try:
        backup, _profile = backups.loads(text, "the uploaded backup")
    except ConfigurationError as exc:  # not a backup: refused as invalid input, before anything is read or sent
        raise ValidationError(str(exc)) from exc
    allowed = fleet.device_config(name).remote

    def run(device: Device) -> list[Outcome]:
        plan = restore.plan(backup, device)
        refused = [p.point.key for p in plan.planned if not allowed.allows_write(p.point.key)]
        if refused:
            raise RemoteNotAllowed(
                f"{name}: the fleet file does not allow remote writes of {', '.join(refused)} "
                f"(add them to remote.write of this device in {fleet.config.source})"
            )
        before = device.guard.actor
        device.guard.actor = actor  # the restore's writes are audited as the operator's
        try:
            return restore.execute(plan, device)
        finally:
            device.guard.actor = before

    return await fleet.run(name, run)
