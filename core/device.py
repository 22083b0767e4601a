"""The Device facade: keys and engineering units in, validated raw values to the transport.

Everything a user can get wrong is checked here BEFORE the transport is called: unknown keys, read-only
points, values out of range, off the resolution or not in the enum, and capabilities the transport or the
model lacks. A write that fails validation sends nothing.

Writes and commands go through the device's :class:`~starterbus.core.guarded.Guard`: certainty and state
rules, confirmation, audit record, read-back (the value, or the state reached). ``send_write`` and
``send_command`` are the unguarded primitives the guard itself uses.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from types import TracebackType

from starterbus.core.audit import AuditLog
from starterbus.core.errors import NotOpenError, UnsupportedOperationError, ValidationError
from starterbus.core.guarded import Confirm, Guard, Outcome, always
from starterbus.core.model import Kind, PointDef, Reading, Value
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile, get_transport
from starterbus.core.status import Command, Status
from starterbus.core.transport_template import Capability, Transport
from starterbus.core.url import DeviceUrl

#: key lists a Device keeps resolved and checked (a poller repeats a handful of them)
RESOLVED_SIZE = 256


class _Resolved:
    """The points one key list resolved to, what the check was made against (a different profile, transport or
    set of capabilities resolves and checks again), and the last readings with the values made of them."""

    __slots__ = ("capabilities", "last", "points", "profile", "transport")

    def __init__(
        self, points: tuple[PointDef, ...], profile: Profile, transport: Transport, capabilities: frozenset[Capability]
    ) -> None:
        self.points = points
        self.profile = profile
        self.transport = transport
        self.capabilities = capabilities
        self.last: tuple[tuple[Reading, ...], dict[str, Value]] = ((), {})


class Device:
    """One soft starter reached through one transport."""

    def __init__(
        self,
        transport: Transport,
        profile: Profile,
        *,
        audit: AuditLog | None = None,
        actor: str | None = None,
        confirm: Confirm = always,
    ) -> None:
        self.transport = transport
        self.profile = profile
        self.guard = Guard(self, audit=audit, actor=actor, confirm=confirm)
        self.is_open = False
        self._resolved: dict[tuple[str | PointDef, ...], _Resolved] = {}

    @property
    def capabilities(self) -> frozenset[Capability]:
        return self.transport.capabilities

    def describe(self) -> str:
        return f"{self.profile.display_name} at {self.transport.describe()}"

    # -- lifecycle -----------------------------------------------------------------------------------------

    def open(self) -> Device:
        if not self.is_open:
            self.transport.open()
            self.is_open = True
        return self

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self.transport.close()

    def _require_open(self) -> None:
        if not self.is_open:
            raise NotOpenError(f"{self.describe()} is not open (use `with open_device(...) as device:` or open())")

    def __enter__(self) -> Device:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # -- checks ------------------------------------------------------------------------------------------

    def _require(self, capability: Capability, what: str, offered: frozenset[Capability] | None = None) -> None:
        """Raise unless the transport offers ``capability`` (``offered``: its capabilities, if just read)."""
        offered = self.transport.capabilities if offered is None else offered
        if capability not in offered:
            raise self.transport.refusal(capability, what)

    def resolve(self, keys: Iterable[str | PointDef]) -> list[PointDef]:
        return [k if isinstance(k, PointDef) else self.profile.point(k) for k in keys]

    def _check_readable(self, points: Iterable[PointDef], offered: frozenset[Capability] | None = None) -> None:
        for point in points:
            if point.kind is Kind.PARAMETER:
                self._require(Capability.READ_PARAMETERS, f"read parameters such as {point.key}", offered)
            else:
                self._require(Capability.READ_MEASUREMENTS, f"read measurements such as {point.key}", offered)

    def _resolve_readable(self, keys: tuple[str | PointDef, ...], offered: frozenset[Capability]) -> _Resolved:
        """``keys`` resolved and checked readable with the ``offered`` capabilities, kept for the next read."""
        points = tuple(self.resolve(keys))
        self._check_readable(points, offered)  # raises before anything is kept
        resolved = _Resolved(points, self.profile, self.transport, offered)
        try:
            if len(self._resolved) >= RESOLVED_SIZE:
                self._resolved.clear()
            self._resolved[keys] = resolved
        except TypeError:  # a PointDef among the keys (not hashable): resolved each time
            pass
        return resolved

    def validate_write(self, key: str | PointDef, value: float | int | str) -> tuple[PointDef, int]:
        """Resolve and validate one write; returns the point and its raw value. Sends nothing."""
        point = key if isinstance(key, PointDef) else self.profile.point(key)
        if point.kind is not Kind.PARAMETER:
            raise ValidationError(f"{point.key} ({point.address}) is a measurement, not a writable parameter")
        if not point.writable:
            raise ValidationError(f"{point.key} ({point.address}) is read-only")
        raw = point.to_raw(value)
        self._require(Capability.WRITE_PARAMETERS, f"write parameters such as {point.key}")
        return point, raw

    # -- operations -----------------------------------------------------------------------------------------

    def read(self, *keys: str | PointDef) -> dict[str, Value]:
        """Read parameters and/or measurements by key or manual address; values in engineering units."""
        transport, offered = self.transport, self.transport.capabilities
        try:
            resolved = self._resolved.get(keys)
        except TypeError:  # a PointDef among the keys (not hashable)
            resolved = None
        if (
            resolved is None
            or resolved.profile is not self.profile
            or resolved.transport is not transport
            or resolved.capabilities != offered
        ):
            resolved = self._resolve_readable(keys, offered)
        if not self.is_open:
            self._require_open()
        readings = tuple(transport.read_points(resolved.points))
        last_readings, values = resolved.last
        if readings != last_readings:  # the same readings (often the same objects) give the same (immutable) values
            values = {r.point.key: r.value(transport.name) for r in readings}
            resolved.last = (readings, values)  # one assignment: another thread sees the old pair or the new one
        return dict(values)

    def read_value(self, key: str | PointDef) -> Value:
        return next(iter(self.read(key).values()))

    def write(self, key: str | PointDef, value: float | int | str, *, accept_uncertain: bool = False) -> Outcome:
        """Write one parameter through the guarded path; returns the verified outcome (``.read_back``)."""
        return self.guard.write([(key, value)], accept_uncertain=accept_uncertain)[0]

    def write_many(
        self, values: Mapping[str, float | int | str], *, accept_uncertain: bool = False, actor: str | None = None
    ) -> list[Outcome]:
        """Validate ALL values first; only if every one is valid, write them in order, each read back.

        ``actor`` (who asks: ``mqtt:CLIENT``, ``opcua:USER``) overrides the device's for the audit record.
        """
        return self.guard.write(values, accept_uncertain=accept_uncertain, actor=actor)

    def send_write(self, point: PointDef, raw: int) -> None:
        """Unguarded: hand one already-validated raw value to the transport (the guard's primitive)."""
        self._require_open()
        self.transport.write_parameter(point, raw)

    def status(self) -> Status:
        self._require(Capability.STATUS, "read the status")
        self._require_open()
        status = self.transport.read_status()
        self.guard.note_status(status)
        return status

    def check_command(self, command: Command) -> None:
        self._require(Capability.COMMANDS, f"send the command {command.value!r}")

    def send_command(self, command: Command) -> None:
        """Unguarded: send a command without confirmation, audit or read-back (the guard's primitive)."""
        self.check_command(command)
        self._require_open()
        self.transport.send_command(command)

    def command(
        self, command: Command, *, timeout: float | None = None, actor: str | None = None, force: bool = False
    ) -> Outcome:
        """Send a command through the guarded path; returns the outcome with the state reached.

        Refused, nothing sent, while the starter is controlled from elsewhere (its control-source parameter, or a
        motor its status shows driven by the terminals, the keypad or another master):
        :class:`~starterbus.core.errors.ControlSourceError`; ``force=True`` sends it anyway (and the audit record
        says what it overrode). A start on a faulted starter is refused whatever ``force`` says.
        """
        return self.guard.command(command, timeout=timeout, actor=actor, force=force)

    def start(self, *, timeout: float | None = None, force: bool = False) -> Outcome:
        return self.command(Command.START, timeout=timeout, force=force)

    def stop(self, *, timeout: float | None = None, force: bool = False) -> Outcome:
        return self.command(Command.SOFT_STOP, timeout=timeout, force=force)

    def reset(self, *, timeout: float | None = None, force: bool = False) -> Outcome:
        return self.command(Command.FAULT_RESET, timeout=timeout, force=force)


def open_device(
    url: str | DeviceUrl,
    model: str | Profile,
    *,
    audit: AuditLog | None = None,
    actor: str | None = None,
    confirm: Confirm = always,
) -> Device:
    """Build a :class:`Device` (not yet opened) from a URL whose scheme names the transport plugin.

    ``audit`` (default: the user's audit log), ``actor`` (who asks, recorded with every write and command)
    and ``confirm`` (a hook shown each proposal; default: the call itself is the intent) set up its guard.
    """
    parsed = url if isinstance(url, DeviceUrl) else DeviceUrl.parse(url)
    profile = model if isinstance(model, Profile) else get_profile(model)
    plugin = get_transport(parsed.transport)
    if not profile.supports(plugin.name):
        raise UnsupportedOperationError(profile.no_interface(plugin.name))
    return Device(plugin.open(parsed, profile), profile, audit=audit, actor=actor, confirm=confirm)
