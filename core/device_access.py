"""What the guarded path (:mod:`starterbus.core.guarded`) and the rules of a command
(:mod:`starterbus.core.command_rules`) use of a device: its unguarded primitives. A
:class:`~starterbus.core.device.Device` is one; naming them here keeps the arrows one way (the device holds its
guard, the guard and the rules import this)."""

from __future__ import annotations

from typing import Protocol

from starterbus.core.model import PointDef, Value
from starterbus.core.profile import Profile
from starterbus.core.status import Command, Status
from starterbus.core.transport_template import Capability, Transport


class DeviceAccess(Protocol):
    transport: Transport
    profile: Profile

    @property
    def capabilities(self) -> frozenset[Capability]: ...

    def describe(self) -> str: ...

    def read_value(self, key: str | PointDef) -> Value: ...

    def status(self) -> Status: ...

    def validate_write(self, key: str | PointDef, value: float | int | str) -> tuple[PointDef, int]: ...

    def send_write(self, point: PointDef, raw: int) -> None: ...

    def check_command(self, command: Command) -> None: ...

    def send_command(self, command: Command) -> None: ...
