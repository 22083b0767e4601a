"""The contract every transport implements: :class:`Transport`, a template whose public methods check the
state and the capabilities and then call the hooks a plugin overrides (the plugin object an entry point
resolves to, :class:`~starterbus.core.plugin.TransportPlugin`, lives in :mod:`starterbus.core.plugin`, above this
module: it opens a :class:`Transport`). Import the names from :mod:`starterbus.core`.

A :class:`Transport` moves raw words: it reads points (returning :class:`Reading` with the scale of its path),
writes one parameter's raw value, sends a :class:`Command` and reads a decoded :class:`Status`. It declares
what it can do in :attr:`Transport.capabilities`; anything else raises :class:`UnsupportedOperationError`.
Range, access and enum validation is NOT the transport's job: :class:`~starterbus.core.device.Device`
does it before anything reaches a transport.
"""

from __future__ import annotations

import contextlib
import enum
import threading
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from types import TracebackType
from typing import Any

from starterbus.core.errors import NotOpenError, UnsupportedOperationError
from starterbus.core.model import Kind, PointDef, Reading
from starterbus.core.polling import PlannedRequest, PollResult, PollTask, TransportCounters
from starterbus.core.profile import Profile
from starterbus.core.status import Command, Status
from starterbus.core.url import DeviceUrl

__all__ = ["ALL_CAPABILITIES", "CAPABILITY_HOOKS", "TEMPLATE_METHODS", "Capability", "Transport"]


class Capability(str, enum.Enum):
    READ_MEASUREMENTS = "read-measurements"
    READ_PARAMETERS = "read-parameters"
    WRITE_PARAMETERS = "write-parameters"
    COMMANDS = "commands"
    STATUS = "status"


ALL_CAPABILITIES = frozenset(Capability)


class _State(enum.Enum):
    NEW = "new"
    OPEN = "open"
    CLOSED = "closed"


_OPEN = _State.OPEN
_READS = frozenset({Capability.READ_MEASUREMENTS, Capability.READ_PARAMETERS})

#: the public methods the template owns: a subclass overrides the hook ``_NAME`` instead
TEMPLATE_METHODS = (
    "open", "close", "read_points", "write_parameter", "read_status", "send_command", "identify",
    "preview_write", "preview_command", "poll", "start_poll",
)  # fmt: skip

#: the hook that serves each capability (both reads share one)
CAPABILITY_HOOKS: Mapping[Capability, str] = {
    Capability.READ_MEASUREMENTS: "_read_points",
    Capability.READ_PARAMETERS: "_read_points",
    Capability.WRITE_PARAMETERS: "_write_parameter",
    Capability.STATUS: "_read_status",
    Capability.COMMANDS: "_send_command",
}


class Transport(ABC):
    """One open path to one device: a template (as python-can's ``BusABC``).

    The public methods check the state (:class:`~starterbus.core.errors.NotOpenError`, naming the transport
    and the URL, before :meth:`open` and after :meth:`close`), apply the rules every transport shares (a
    capability not declared raises :meth:`unsupported`; no points, no request) and then call the protected
    hooks a plugin overrides: ``_open``, ``_close``, ``_read_points``, ``_write_parameter``, ``_read_status``,
    ``_send_command``, ``_identify``, ``_preview_write``, ``_preview_command``, ``_poll``, ``_start_poll``. A
    hook runs only in the state it needs, so it never checks it. ``open`` and ``close`` are idempotent and a
    closed transport may be opened again (a poller reconnects). Use as a context manager; not shared between
    threads unless documented.
    """

    #: the plugin name (entry point / URL scheme)
    name: str = ""
    #: True when a run command lives only while this transport stays open (DeviceNet polled I/O: closing the
    #: connection lets the slave's watchdog soft-stop the motor); a one-shot ``start`` must hold or refuse
    run_needs_connection: bool = False

    def __init__(self, url: DeviceUrl, profile: Profile) -> None:
        self.url = url
        self.profile = profile
        self._state = _State.NEW
        self._lifecycle = threading.Lock()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        for method in TEMPLATE_METHODS:
            if method in vars(cls):
                raise TypeError(
                    f"{cls.__module__}.{cls.__qualname__} overrides {method}(): the Transport template owns it; "
                    f"override the hook _{method}() instead (docs/plugins.md)"
                )

    # -- lifecycle -------------------------------------------------------------------------------------------

    @property
    def is_open(self) -> bool:
        return self._state is _OPEN

    def open(self) -> None:
        """Connect (idempotent). If ``_open`` raises, the transport stays closed: the hook cleans up after itself."""
        with self._lifecycle:
            if self._state is not _OPEN:
                self._open()
                self._state = _OPEN

    def close(self) -> None:
        """Disconnect (idempotent); every later operation raises NotOpenError until the next :meth:`open`."""
        with self._lifecycle:
            was_open, self._state = self._state is _OPEN, _State.CLOSED
            if was_open:
                self._close()

    def __enter__(self) -> Transport:
        self.open()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _not_open(self) -> NotOpenError:
        state = " (closed)" if self._state is _State.CLOSED else ""
        return NotOpenError(
            f"{self.name} {self.url.text} is not open{state}: call open() or use the transport or its device "
            "in a with block"
        )

    @abstractmethod
    def _open(self) -> None:
        """Connect: acquire the shared line/bus/gateway (a :class:`~starterbus.core.sharing.SharedPool`), start
        threads. On failure, release what was taken and raise (TransportError naming where)."""

    @abstractmethod
    def _close(self) -> None:
        """Release everything ``_open`` took; leave no thread or descriptor behind. Called once per open."""

    # -- what it can do ------------------------------------------------------------------------------------

    @property
    @abstractmethod
    def capabilities(self) -> frozenset[Capability]:
        """What this transport can do with this device and these settings (PPO3 cannot read parameters)."""

    @classmethod
    def capability_problems(cls, declared: frozenset[Capability]) -> list[str]:
        """Where ``declared`` capabilities and the overridden hooks disagree (empty: they agree)."""
        overridden = {
            hook for hook in set(CAPABILITY_HOOKS.values()) if getattr(cls, hook) is not getattr(Transport, hook)
        }
        problems = [
            f"{c.value} is declared but {CAPABILITY_HOOKS[c]}() is not overridden"
            for c in sorted(declared)
            if CAPABILITY_HOOKS[c] not in overridden
        ]
        for hook in sorted(overridden):
            if not any(CAPABILITY_HOOKS[c] == hook for c in declared):
                problems.append(f"{hook}() is overridden but no capability it serves is declared")
        return problems

    @classmethod
    def offers_poll_tasks(cls) -> bool:
        """Whether this class can give :meth:`start_poll` tasks at all (it overrides ``_start_poll``); one of
        its connections may still poll only by blocking (``start_poll`` then gives None)."""
        return cls._start_poll is not Transport._start_poll

    def read_refusal(self, point: PointDef) -> str | None:
        """Why this connection, as its URL configures it, reads ``point`` only after taking control of the
        device (None: a read is enough). A fleet leaves such points out of its defaults and refuses them when
        listed; the default is None."""
        return None

    def describe(self) -> str:
        """Where this transport talks to, for messages: URL and device address."""
        return self.url.text

    def unsupported(self, what: str, why: str = "") -> UnsupportedOperationError:
        reason = f": {why}" if why else ""
        return UnsupportedOperationError(f"{self.name} ({self.describe()}) cannot {what}{reason}")

    def _why_not(self, capability: Capability) -> str:
        """Why this transport lacks ``capability`` here, for the refusal (default: what it offers)."""
        return f"it offers: {', '.join(sorted(c.value for c in self.capabilities)) or 'nothing'}"

    def refusal(self, capability: Capability, what: str) -> UnsupportedOperationError:
        """The error for asking ``what`` of a transport that lacks ``capability``, with the plugin's reason."""
        return self.unsupported(what, self._why_not(capability))

    def _check_capability(self, capability: Capability, what: str) -> None:
        if capability not in self.capabilities:
            raise self.refusal(capability, what)

    def _check_reads(self, points: Sequence[PointDef]) -> None:
        for point in points:
            if point.kind is Kind.PARAMETER:
                self._check_capability(Capability.READ_PARAMETERS, f"read parameters such as {point.key}")
            else:
                self._check_capability(Capability.READ_MEASUREMENTS, f"read measurements such as {point.key}")

    # -- operations: checks, then the hook ------------------------------------------------------------------

    def read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        """Read raw values of measurements and/or parameters, in the order given (none asked: none read)."""
        if self._state is not _OPEN:
            raise self._not_open()
        if not points:
            return []
        if not self.capabilities >= _READS:
            self._check_reads(points)
        return self._read_points(points)

    def write_parameter(self, point: PointDef, raw: int) -> None:
        """Write one already-validated raw value."""
        if self._state is not _OPEN:
            raise self._not_open()
        self._check_capability(Capability.WRITE_PARAMETERS, f"write parameters such as {point.key}")
        self._write_parameter(point, raw)

    def read_status(self) -> Status:
        if self._state is not _OPEN:
            raise self._not_open()
        self._check_capability(Capability.STATUS, "read the status")
        return self._read_status()

    def send_command(self, command: Command) -> None:
        if self._state is not _OPEN:
            raise self._not_open()
        self._check_capability(Capability.COMMANDS, f"send the command {command.value!r}")
        self._send_command(command)

    def identify(self) -> dict[str, object]:
        """The device's identity as the protocol reports it (DeviceNet identity object), if it has one."""
        if self._state is not _OPEN:
            raise self._not_open()
        return self._identify()

    def preview_write(self, point: PointDef, raw: int) -> list[str]:
        """The frames a write would send, as text, without sending them (``--dry-run``; open or not)."""
        self._check_capability(Capability.WRITE_PARAMETERS, f"write parameters such as {point.key}")
        return self._preview_write(point, raw)

    def preview_command(self, command: Command) -> list[str]:
        """The frames a command would send, as text, without sending them (open or not)."""
        self._check_capability(Capability.COMMANDS, f"send the command {command.value!r}")
        return self._preview_command(command)

    def poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        """The status (if ``status``) and ``points`` in as few requests as the transport can (the hook
        ``_poll``; by default ``_read_status`` then ``_read_points``)."""
        self._check_poll(points, status)
        return self._poll(points, status)

    def start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        """:meth:`poll` as a :class:`PollTask` a poller advances without blocking (many lines, one thread), or
        None where this transport (or this connection of it) polls only by blocking: then call :meth:`poll`.
        Nothing is sent before the task's first ``advance``."""
        self._check_poll(points, status)
        return self._start_poll(points, status)

    def _check_poll(self, points: Sequence[PointDef], status: bool) -> None:
        if self._state is not _OPEN:
            raise self._not_open()
        if status:
            self._check_capability(Capability.STATUS, "read the status")
        if points and not self.capabilities >= _READS:
            self._check_reads(points)

    # -- hooks (override what the capabilities declare; the template has checked the state) ------------------

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        """``points`` is never empty."""
        raise self.unsupported("read parameters or measurements")

    def _write_parameter(self, point: PointDef, raw: int) -> None:
        raise self.unsupported("write parameters")

    def _read_status(self) -> Status:
        raise self.unsupported("read the status")

    def _send_command(self, command: Command) -> None:
        raise self.unsupported(f"send the command {command.value!r}")

    def _identify(self) -> dict[str, object]:
        raise self.unsupported("identify the device")

    def _preview_write(self, point: PointDef, raw: int) -> list[str]:
        raise self.unsupported("preview frames")

    def _preview_command(self, command: Command) -> list[str]:
        raise self.unsupported("preview frames")

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        """A transport that can merge the status and the points into fewer requests overrides this."""
        return PollResult(self._read_status() if status else None, self._read_points(points) if points else [])

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        """A transport whose poll can run as a :class:`PollTask` returns one (default: None, blocking only)."""
        return None

    # -- polling helpers (plain overridable methods: no state) ----------------------------------------------

    def plan(self, points: Sequence[PointDef], status: bool) -> list[PlannedRequest]:
        """The requests :meth:`poll` sends for these arguments, without sending anything (for display)."""
        planned = [PlannedRequest("read status", 1)] if status else []
        if points:
            planned.append(PlannedRequest(f"read {', '.join(p.key for p in points)}", len(points)))
        return planned

    def probe_policy(self, timeout: float) -> contextlib.AbstractContextManager[None]:
        """Inside the context, each request is tried once (no retries) and waits at most ``timeout`` s for its
        answer: how a poller checks whether an offline device is back without holding a shared line long.
        By default nothing changes (a transport without retries or per-request timeouts of its own)."""
        return contextlib.nullcontext()

    def counters(self) -> TransportCounters | None:
        """What this transport has put on the wire so far, or None if it does not count."""
        return None
