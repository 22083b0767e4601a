"""What goes into and out of the Sparkplug B edge session (``session.py``): its options, and the actions it asks
its driver to take (publish a message, run a command through the guarded path, reconnect)."""

from __future__ import annotations

from dataclasses import dataclass, field

from starterbus.core.status import Command


@dataclass(frozen=True, slots=True)
class Publish:
    topic: str
    payload: bytes
    qos: int = 0


@dataclass(frozen=True, slots=True)
class CommandRequest:
    """A DCMD accepted by the session, to run through the guarded path; report with :meth:`command_done`."""

    device: str
    command: Command | None = None
    writes: dict[str, float | int | str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Reconnect:
    """The primary host went offline: NDEATH was published; disconnect and connect again (new bdSeq)."""


Action = Publish | CommandRequest | Reconnect


@dataclass(frozen=True, slots=True)
class SessionOptions:
    group: str
    node: str
    refresh: float = 0.0  # republish every value of a device this often, s (0: never)
    buffer_messages: int = 10_000
    buffer_age: float = 3600.0
    command_max_age: float = 10.0
    commands_allowed: bool = True  # False on a plaintext connection unless explicitly allowed
    primary_host: str | None = None
