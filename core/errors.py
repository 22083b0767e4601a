"""The one exception hierarchy of starterbus.

Everything starterbus raises on purpose derives from :class:`StarterbusError`. Errors caused by bytes on the
wire carry those bytes (``data``) so a message always shows what was received.
"""

from __future__ import annotations

import builtins
import enum


def _hex(data: bytes) -> str:
    return data.hex(" ").upper()


class StarterbusError(Exception):
    """Root of every error starterbus raises on purpose."""


class ConfigurationError(StarterbusError):
    """A profile, URL, fleet file or option is invalid."""


class ProfileError(ConfigurationError):
    """A device profile file is invalid; names the file and the offending key."""

    def __init__(self, source: str, key: str, message: str) -> None:
        self.source = source
        self.key = key
        super().__init__(f"{source}: {key}: {message}")


class PluginError(StarterbusError):
    """A plugin could not be found or loaded, or two plugins claim one name."""


class UnknownPointError(StarterbusError, KeyError):
    """A key or manual address names no parameter or measurement of the model."""

    def __str__(self) -> str:  # KeyError quotes its argument; keep the plain message
        return str(self.args[0]) if self.args else ""


class ValidationError(StarterbusError, ValueError):
    """A value was refused before anything was sent (range, access, enum, resolution)."""


class StateRuleError(ValidationError):
    """An operation the device's present state forbids (a parameter the profile locks while the motor runs, a
    start while faulted), or whose state cannot be proven; nothing was sent."""


class ControlSourceError(StateRuleError):
    """The starter takes its start/stop commands from elsewhere (its terminals, its keypad, another master), so
    a command from here would be ignored or would fight that control; nothing was sent. The override is
    ``force=True`` (CLI ``--force``); ``reason`` says what showed it."""

    def __init__(self, message: str, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason or message


class UnsupportedOperationError(StarterbusError):
    """The transport or the device model lacks the requested capability."""


class TransportError(StarterbusError):
    """Moving bytes or frames failed (port, socket, bus)."""


class NotOpenError(ConfigurationError):
    """A device or transport used before ``open()`` or after ``close()``: one error, whatever the transport."""


class TimeoutError(TransportError, builtins.TimeoutError):
    """No (complete) answer arrived in time. Also a builtin ``TimeoutError``."""


class CodecError(StarterbusError):
    """A frame or telegram could not be encoded or decoded.

    ``data`` holds the offending bytes; ``field`` names the failing field where one is known.
    """

    def __init__(self, message: str, data: bytes = b"", field: str | None = None) -> None:
        self.data = bytes(data)
        self.field = field
        text = message
        if field:
            text = f"{field}: {text}"
        if data:
            text = f"{text} [{_hex(self.data)}]"
        super().__init__(text)


class EncodeError(CodecError):
    """A value cannot be encoded into a frame."""


class DecodeError(CodecError):
    """Bytes received do not form a valid frame."""


class ChecksumError(DecodeError):
    """A frame's checksum (CRC) is wrong."""


class RemoteDeviceError(StarterbusError):
    """The device answered with an error of its own (Modbus exception, PKW error number, CIP status).

    ``code`` is the device's own code, ``meaning`` its text from the manual, ``protocol`` where it came from.
    """

    def __init__(
        self,
        protocol: str,
        code: int,
        meaning: str,
        detail: str = "",
        data: bytes = b"",
        additional: int | None = None,
    ) -> None:
        self.protocol = protocol
        self.code = code
        self.meaning = meaning
        self.additional = additional
        self.data = bytes(data)
        #: what the refusal means whatever the protocol, when its text says so unambiguously (else None)
        self.reason = classify_refusal(meaning)
        text = f"{protocol} error {code:#04x}: {meaning}"
        if self.reason is not None:
            text = f"{REFUSAL_TEXT[self.reason]} ({text})"
        if additional is not None:
            text += f" (additional code {additional:#04x})"
        if detail:
            text += f" ({detail})"
        if data:
            text += f" [{_hex(self.data)}]"
        super().__init__(text)


class Refusal(enum.Enum):
    """Why the simulated starter refused an operation (protocol simulators map it to their own codes)."""

    NOT_AVAILABLE = "not available"  # no such parameter/measurement
    READ_ONLY = "read only"
    OUT_OF_RANGE = "out of range"
    WRITE_PROTECTED = "write protected"  # "parameter modify" = 0
    WHILE_RUNNING = "cannot modify while running"


class SimulatorRefusal(StarterbusError):
    """The simulated starter refused an operation; protocol simulators map ``reason`` to their own codes."""

    def __init__(self, reason: Refusal, message: str) -> None:
        self.reason = reason
        super().__init__(message)


#: one message per kind of refusal, the same over every protocol
REFUSAL_TEXT = {
    Refusal.WHILE_RUNNING: "the device refuses this change while the motor runs",
    Refusal.WRITE_PROTECTED: "parameter changes are switched off on the device (its parameter-modify setting)",
    Refusal.OUT_OF_RANGE: "the device refuses the value as outside its limits",
    Refusal.NOT_AVAILABLE: "the device has no such parameter or address",
    Refusal.READ_ONLY: "the device does not allow this parameter to be changed",
}
_REFUSAL_WORDS = {
    Refusal.WHILE_RUNNING: ("while running", "device state conflict"),
    Refusal.WRITE_PROTECTED: ("modification forbidden", "parameter modify"),
    Refusal.OUT_OF_RANGE: ("out of limits", "value out of", "invalid attribute value"),
    Refusal.NOT_AVAILABLE: ("not available", "data address", "does not exist", "attribute not supported"),
    Refusal.READ_ONLY: ("cannot be modified", "not modifiable", "not settable", "read-only", "no write permission"),
}


def classify_refusal(meaning: str) -> Refusal | None:
    """The kind of refusal a device's error text names, or None when it names none or more than one (an
    exception that means "out of limits, or not modifiable" stays as the manual words it)."""
    text = meaning.casefold()
    found = {reason for reason, words in _REFUSAL_WORDS.items() if any(w in text for w in words)}
    return found.pop() if len(found) == 1 else None
