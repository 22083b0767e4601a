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
    """The primary host went offline (NDEATH was published if the node was born): disconnect and connect again,
    to the next server of the list if there are several (new bdSeq)."""


@dataclass(frozen=True, slots=True)
class HistoryReady:
    """Buffered DDATA of a born device can go out: call ``EdgeSession.history`` until it returns nothing."""


Action = Publish | CommandRequest | Reconnect | HistoryReady


@dataclass(frozen=True, slots=True)
class SessionOptions:
    group: str
    node: str
    refresh: float = 0.0  # republish every value of a device this often, s (0: never)
    # bounds of the default (in-memory) buffer; an injected store has its own
    buffer_messages: int = 1_000_000
    buffer_size: int = 100_000_000  # bytes of stored records
    buffer_age: float = 86_400.0
    command_max_age: float = 10.0
    commands_allowed: bool = True  # False on a plaintext connection unless explicitly allowed
    primary_host: str | None = None
    servers: int = 1  # brokers in the list: with several, a primary host offline on this one means the next
