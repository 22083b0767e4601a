"""What goes into and out of the Sparkplug B edge session (``session.py``): its options, and the actions it asks
its driver to take (publish a message, run a command through the guarded path, reconnect)."""

from __future__ import annotations

from dataclasses import dataclass, field

from starterbus.core.errors import ConfigurationError
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
    topic: str = ""  # where it came from, for the audit log
    asked: str = ""  # what it asked, as the DCMD said it (``Device Control/Start=True``)


@dataclass(frozen=True, slots=True)
class CommandAudit:
    """A command that the session refused or ignored: the driver appends it to the audit log (with its actor)."""

    device: str | None  # the fleet device; None for an NCMD
    topic: str
    asked: str
    result: str  # ``refused: REASON`` or ``ignored: REASON``


@dataclass(frozen=True, slots=True)
class Reconnect:
    """The primary host went offline (NDEATH was published if the node was born): disconnect and connect again,
    to the next server of the list if there are several (new bdSeq)."""


@dataclass(frozen=True, slots=True)
class HistoryReady:
    """Buffered DDATA of a born device can go out: call ``EdgeSession.history`` until it returns nothing."""


Action = Publish | CommandRequest | CommandAudit | Reconnect | HistoryReady


@dataclass(frozen=True, slots=True)
class SessionOptions:
    group: str
    node: str
    refresh: float = 0.0  # republish every value of a device this often, s (0: never)
    # bounds of the default (in-memory) buffer; an injected store has its own
    buffer_messages: int = 1_000_000
    buffer_size: int = 100_000_000  # bytes of stored records
    buffer_age: float = 86_400.0
    command_max_age: float = 10.0  # s: an older DCMD is refused
    command_max_skew: float = 5.0  # s: a DCMD dated further in the future is refused (the clocks disagree)
    command_max_bytes: int = 65_536  # a larger NCMD/DCMD is refused before it is parsed
    first_round_wait: float = 30.0  # s after the CONNACK: the births wait for every device's first poll until then
    commands_allowed: bool = True  # False on a plaintext connection unless explicitly allowed
    primary_host: str | None = None
    servers: int = 1  # brokers in the list: with several, a primary host offline on this one means the next

    def __post_init__(self) -> None:
        for option, value in (("age", self.command_max_age), ("skew", self.command_max_skew)):
            if not value >= 0:
                raise ConfigurationError(f"--command-max-{option} {value:g}: must be 0 or more (seconds)")
        if self.command_max_bytes < 1:
            raise ConfigurationError(f"--command-max-bytes {self.command_max_bytes}: must be 1 or more")
