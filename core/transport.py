"""The contract every transport implements, and the plugin object an entry point resolves to.

A :class:`Transport` moves raw words: it reads points (returning :class:`Reading` with the scale of its path),
writes one parameter's raw value, sends a :class:`Command` and reads a decoded :class:`Status`. It declares
what it can do in :attr:`Transport.capabilities`; anything else raises :class:`UnsupportedOperationError`.
Range, access and enum validation is NOT the transport's job: :class:`~starterbus.core.device.Device`
does it before anything reaches a transport.
"""

from __future__ import annotations

import argparse
import enum
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

from starterbus.core.errors import UnsupportedOperationError
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile
from starterbus.core.status import Command, Status
from starterbus.core.url import DeviceUrl


class Capability(str, enum.Enum):
    READ_MEASUREMENTS = "read-measurements"
    READ_PARAMETERS = "read-parameters"
    WRITE_PARAMETERS = "write-parameters"
    COMMANDS = "commands"
    STATUS = "status"


ALL_CAPABILITIES = frozenset(Capability)


class Transport(ABC):
    """One open path to one device. Use as a context manager; not shared between threads unless documented."""

    #: the plugin name (entry point / URL scheme)
    name: str = ""

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

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        """Check this transport's table of a profile (``[transports.NAME]``) when the profile loads.

        Raise :class:`~starterbus.core.errors.ConfigurationError` naming the key and the value; the loader adds
        the file. The default accepts anything.
        """

    # -- optional hooks for the CLI ---------------------------------------------------------------------------

    def add_simulator_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Add this transport's ``starterbus simulate`` options (e.g. ``--modbus-rtu PORT``)."""

    def start_simulators(
        self, args: argparse.Namespace, profile: Profile, starters: Sequence[object]
    ) -> list[RunningSimulator]:
        """Start the front ends the parsed options ask for, serving the given simulated starters.

        ``starters`` are :class:`~starterbus.core.simulator.SimulatedStarter` objects shared by every front end
        (one per ``--unit``); return nothing when no option of this transport was given.
        """
        return []

    def add_decode_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Options of ``starterbus decode NAME``; HEX arguments are added by the CLI as ``args.data``."""

    def decode(self, args: argparse.Namespace, profile: Profile | None) -> list[Annotation]:
        raise UnsupportedOperationError(f"transport {self.name!r} has no decoder")

    @property
    def has_decoder(self) -> bool:
        return type(self).decode is not TransportPlugin.decode
