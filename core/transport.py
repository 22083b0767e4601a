"""The contract every transport implements, and the plugin object an entry point resolves to.

A :class:`Transport` moves raw words: it reads points (returning :class:`Reading` with the scale of its path),
writes one parameter's raw value, sends a :class:`Command` and reads a decoded :class:`Status`. It declares
what it can do in :attr:`Transport.capabilities`; anything else raises :class:`UnsupportedOperationError`.
Range, access and enum validation is NOT the transport's job: :class:`~starterbus.core.device.Device`
does it before anything reaches a transport.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import inspect
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import TYPE_CHECKING, Any

from starterbus.core.errors import ConfigurationError, UnsupportedOperationError
from starterbus.core.model import PointDef, Reading
from starterbus.core.plugin_options import PluginOption
from starterbus.core.profile import Profile
from starterbus.core.status import Command, Status
from starterbus.core.url import DeviceUrl

if TYPE_CHECKING:
    import argparse

    from starterbus.core.simulator import SimulatedStarter


class Capability(str, enum.Enum):
    READ_MEASUREMENTS = "read-measurements"
    READ_PARAMETERS = "read-parameters"
    WRITE_PARAMETERS = "write-parameters"
    COMMANDS = "commands"
    STATUS = "status"


ALL_CAPABILITIES = frozenset(Capability)


@dataclass(frozen=True, slots=True)
class PollResult:
    """One poll of one device: its status (if asked for) and the points asked for, in the order asked."""

    status: Status | None
    readings: list[Reading]


@dataclass(frozen=True, slots=True)
class PlannedRequest:
    """One request of a device's poll plan, for display (``starterbus poll FLEET --plan``).

    ``wire_time``: seconds the request and its answer occupy the line (silences included) at the line's speed;
    None where the transport cannot tell (a cyclic bus whose master refreshes inputs by itself).
    """

    text: str
    registers: int
    request_bytes: int = 0
    answer_bytes: int = 0
    wire_time: float | None = None

    def as_json(self) -> dict[str, object]:
        return {
            "request": self.text,
            "registers": self.registers,
            "request_bytes": self.request_bytes,
            "answer_bytes": self.answer_bytes,
            "wire_time": self.wire_time,
        }


@dataclass(slots=True)
class TransportCounters:
    """What one transport put on the wire since it was made (counters only grow).

    ``requests`` counts frames sent, retries included; ``transactions`` the calls that sent them; ``timeouts``
    and ``errors`` the transactions that failed (no answer; any failure); ``busy_time`` the time the transport
    held its line (0 if it does not measure it); ``wire_time`` the time its frames and silences occupied the wire.
    """

    transactions: int = 0
    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    errors: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0
    busy_time: float = 0.0
    wire_time: float = 0.0

    def _values(self) -> tuple[int, int, int, int, int, int, int, float, float]:
        return (
            self.transactions, self.requests, self.retries, self.timeouts, self.errors,
            self.bytes_sent, self.bytes_received, self.busy_time, self.wire_time,
        )  # fmt: skip

    def copy(self) -> TransportCounters:
        return TransportCounters(*self._values())

    def add(self, other: TransportCounters) -> None:
        self.transactions += other.transactions
        self.requests += other.requests
        self.retries += other.retries
        self.timeouts += other.timeouts
        self.errors += other.errors
        self.bytes_sent += other.bytes_sent
        self.bytes_received += other.bytes_received
        self.busy_time += other.busy_time
        self.wire_time += other.wire_time

    def minus(self, other: TransportCounters) -> TransportCounters:
        a, b = self._values(), other._values()
        return TransportCounters(
            a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4], a[5] - b[5], a[6] - b[6],
            a[7] - b[7], a[8] - b[8],
        )  # fmt: skip

    def as_json(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = round(value, 6) if isinstance(value, float) else value
        return out


class Transport(ABC):
    """One open path to one device. Use as a context manager; not shared between threads unless documented."""

    #: the plugin name (entry point / URL scheme)
    name: str = ""
    #: True when a run command lives only while this transport stays open (DeviceNet polled I/O: closing the
    #: connection lets the slave's watchdog soft-stop the motor); a one-shot ``start`` must hold or refuse
    run_needs_connection: bool = False

    def __init__(self, url: DeviceUrl, profile: Profile) -> None:
        self.url = url
        self.profile = profile

    # -- lifecycle -------------------------------------------------------------------------------------------

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> Transport:
        self.open()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # -- what it can do ------------------------------------------------------------------------------------

    @property
    @abstractmethod
    def capabilities(self) -> frozenset[Capability]:
        """What this transport can do with this device and these settings (PPO3 cannot read parameters)."""

    def describe(self) -> str:
        """Where this transport talks to, for messages: URL and device address."""
        return self.url.text

    def unsupported(self, what: str, why: str = "") -> UnsupportedOperationError:
        reason = f": {why}" if why else ""
        return UnsupportedOperationError(f"{self.name} ({self.describe()}) cannot {what}{reason}")

    # -- operations (override what the capabilities declare) -------------------------------------------------

    def read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        """Read raw values of measurements and/or parameters, in the order given."""
        raise self.unsupported("read parameters or measurements")

    def write_parameter(self, point: PointDef, raw: int) -> None:
        """Write one already-validated raw value."""
        raise self.unsupported("write parameters")

    def read_status(self) -> Status:
        raise self.unsupported("read the status")

    def send_command(self, command: Command) -> None:
        raise self.unsupported(f"send the command {command.value!r}")

    def identify(self) -> dict[str, object]:
        """The device's identity as the protocol reports it (DeviceNet identity object), if it has one."""
        raise self.unsupported("identify the device")

    def preview_write(self, point: PointDef, raw: int) -> list[str]:
        """The frames a write would send, as text, without sending them (``--dry-run``)."""
        raise self.unsupported("preview frames")

    def preview_command(self, command: Command) -> list[str]:
        raise self.unsupported("preview frames")

    # -- polling (a fleet poller's view; defaults built on the operations above) -------------------------------

    def poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        """The status (if ``status``) and ``points`` in as few requests as the transport can; by default
        :meth:`read_status` then :meth:`read_points`. A transport that can merge them overrides this."""
        return PollResult(self.read_status() if status else None, self.read_points(points) if points else [])

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


@dataclass(frozen=True, slots=True)
class Annotation:
    """One decoded frame/telegram for the ``decode`` command: a title, annotated fields, and an error if bad."""

    title: str
    fields: list[tuple[str, str, str]] = field(default_factory=list)  # (field, raw, meaning)
    error: str | None = None

    def as_json(self) -> dict[str, object]:
        return {
            "title": self.title,
            "fields": [{"field": f, "raw": r, "meaning": m} for f, r, m in self.fields],
            "error": self.error,
        }


class RunningSimulator(ABC):
    """A protocol front end serving simulated starters, started by ``starterbus simulate``."""

    @abstractmethod
    def describe(self) -> list[str]:
        """Lines to print: where a client connects (e.g. ``modbus-rtu: /dev/pts/4``)."""

    @abstractmethod
    def close(self) -> None: ...

    def client_urls(self) -> dict[int, str]:
        """Device address (unit, MAC, station) -> the URL a client in this process uses to reach it."""
        return {}


class TransportPlugin(ABC):
    """What a ``starterbus.transports`` entry point resolves to."""

    name: str = ""
    summary: str = ""
    #: everything this transport can do at best (a given URL may offer less)
    capabilities: frozenset[Capability] = frozenset()
    #: URL forms, for help texts
    url_forms: tuple[str, ...] = ()

    @abstractmethod
    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        """Build a transport (not yet opened) for one device. Validate the URL here: bad URL, clear error."""

    #: True when a profile naming this transport must give some of its points an address on it
    requires_point_addresses: bool = False
    #: the URL query parameter a fleet file's ``address`` of a device on this transport fills (None: it takes none)
    address_parameter: str | None = None
    #: the URL query parameter that tells the transport the fleet's poll period, s (a scanner that polls on its
    #: own then polls at the rate asked); None: the transport polls only when asked
    period_parameter: str | None = None

    def parse_address(self, value: object) -> Any:
        """A point's address on this transport, from the profile field named after the plugin (``NAME = ...``).

        Any shape the transport needs (an integer, ``(index, subindex)``, text); raise
        :class:`~starterbus.core.errors.ConfigurationError` naming the value. The default: an integer 0..0xFFFF.
        """
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
            raise ConfigurationError(f"{value!r} is not an address (an integer 0..0xFFFF)")
        return value

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        """Check this transport's table of a profile (``[transports.NAME]``) when the profile loads.

        Raise :class:`~starterbus.core.errors.ConfigurationError` naming the key and the value; the loader adds
        the file. The default accepts anything.
        """

    # -- optional hooks: simulator front ends and a decoder, declared as data -----------------------------------

    #: options of this plugin's ``starterbus simulate`` front ends (flags ``--NAME-OPTION`` unless declared)
    simulator_options: tuple[PluginOption, ...] = ()
    #: options of ``starterbus decode NAME`` (the frames themselves are given by the caller)
    decoder_options: tuple[PluginOption, ...] = ()
    #: a text shown under ``starterbus decode NAME --help`` (the frame syntax, for instance)
    decoder_help: str = ""

    def start_simulator(
        self, options: Mapping[str, object], starters: Mapping[int, SimulatedStarter]
    ) -> list[RunningSimulator]:
        """Start the front ends ``options`` ask for, serving ``starters`` (address -> starter, shared by every
        front end); return ``[]`` when none of this plugin's options is given.

        ``options`` maps the names of :attr:`simulator_options` to values (text is converted); check them with
        :func:`~starterbus.core.plugin_options.resolve_options`. Errors are
        :class:`~starterbus.core.errors.ConfigurationError` naming the option.
        """
        return []

    def decode(self, frames: Sequence[str], options: Mapping[str, object], profile: Profile | None) -> list[Annotation]:
        """Annotate ``frames`` (one text per frame or hex chunk, as the user gave them) with ``options``
        (names of :attr:`decoder_options`); ``profile`` names points and scales values when given."""
        raise UnsupportedOperationError(f"transport {self.name!r} has no decoder")

    @property
    def has_decoder(self) -> bool:
        return type(self).decode is not TransportPlugin.decode

    # -- deprecated: the argparse hooks of starterbus < 0.x; the CLI still honours them --------------------------

    def add_simulator_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Deprecated (use :attr:`simulator_options`): add ``starterbus simulate`` options to the shared parser."""

    def start_simulators(
        self, args: argparse.Namespace, profile: Profile, starters: Sequence[object]
    ) -> list[RunningSimulator]:
        """Deprecated (use :meth:`start_simulator`): start front ends from the parsed command line.

        ``args.unit`` holds the addresses, ``starters`` the simulated starters in that order, ``profile`` the
        first one's model.
        """
        return []

    def add_decode_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Deprecated (use :attr:`decoder_options`); with it, ``decode(args, profile)`` gets the parsed
        command line, the frames in ``args.data``."""

    @property
    def uses_argparse_simulator(self) -> bool:
        """True for a plugin still written against the deprecated argparse simulator hooks."""
        cls = type(self)
        return (
            cls.add_simulator_arguments is not TransportPlugin.add_simulator_arguments
            or cls.start_simulators is not TransportPlugin.start_simulators
        )

    @property
    def uses_argparse_decoder(self) -> bool:
        """True for a decoder written as the deprecated ``decode(args, profile)``."""
        if not self.has_decoder:
            return False
        try:
            return len(inspect.signature(self.decode).parameters) == 2
        except (TypeError, ValueError):  # pragma: no cover - a builtin or C callable
            return False
