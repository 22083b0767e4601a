"""The conformance kit's fault hook: how a plugin lets the kit make its simulated device misbehave.

A test class implements :meth:`TransportConformance.faults <starterbus.testing.conformance.TransportConformance.faults>`
for its simulator: a context manager, for one served starter, that yields a :class:`FaultControl`. While it is
active the simulator records every request that reaches that device (in the notation of the transport's
previews, so the kit can compare a preview with what was then sent) and applies the fault the kit sets:

========================  ============================================================================================
:attr:`Fault.SILENT`      the device acts on each request (a write is written) and its answer is lost
:attr:`Fault.SLOW`        each answer comes ``delay`` s late; the kit's URL timeout is longer than that
:attr:`Fault.LATE`        each answer comes ``delay`` s late, after the client's timeout (the kit sets the timeout)
:attr:`Fault.DUPLICATE`   each answer is sent twice, back to back
:attr:`Fault.BUSY`        each request is refused with the protocol's "busy" answer; nothing is acted on
:attr:`Fault.UNREACHABLE` a gateway in front of the device answers "the target device failed to respond"
========================  ============================================================================================

:class:`DeviceTap` is a ready-made :class:`FaultControl`: the simulator's hook calls :meth:`DeviceTap.record`
with each request and asks :attr:`DeviceTap.fault` what to do. A fault the simulator cannot produce makes
:meth:`DeviceTap.set` raise :class:`FaultNotSupported` (list it in ``unsupported``): the kit then skips the
test that needs it, with the reason. Without a ``faults`` hook every fault test skips, saying so.
"""

from __future__ import annotations

import enum
import threading
from collections.abc import Iterable, Mapping, Sequence
from typing import Protocol


class Fault(str, enum.Enum):
    SILENT = "silent"
    SLOW = "slow"
    LATE = "late"
    DUPLICATE = "duplicate"
    BUSY = "busy"
    UNREACHABLE = "unreachable"


class FaultNotSupported(Exception):
    """The simulator cannot produce this fault (the kit skips the test that needs it)."""


class FaultsNotProvided(Exception):
    """The test class implements no ``faults`` hook (the kit skips every fault test)."""


class FaultControl(Protocol):
    """What the kit drives: the requests seen and the fault in force."""

    @property
    def requests(self) -> Sequence[str]:
        """Every request that reached the device since the context began, oldest first, as preview text."""
        ...

    def set(self, fault: Fault | None, delay: float = 0.0) -> None:
        """Apply ``fault`` to every later request (None: behave again); ``delay`` for SLOW and LATE."""
        ...


class DeviceTap:
    """A :class:`FaultControl` a simulator's hook feeds (thread-safe: the simulator serves in its own thread)."""

    def __init__(self, unsupported: Iterable[Fault] | Mapping[Fault, str] = ()) -> None:
        """``unsupported``: the faults the simulator cannot produce, or a mapping of each to the reason."""
        self.reasons = dict(unsupported) if isinstance(unsupported, Mapping) else {}
        self.unsupported = frozenset(unsupported)
        self._lock = threading.Lock()
        self._requests: list[str] = []
        self._fault: tuple[Fault | None, float] = (None, 0.0)

    @property
    def requests(self) -> list[str]:
        with self._lock:
            return list(self._requests)

    @property
    def fault(self) -> tuple[Fault | None, float]:
        """The fault in force and its delay (read by the simulator's hook for each request)."""
        return self._fault

    def record(self, request: str) -> tuple[Fault | None, float]:
        """Note one request that reached the device; returns the fault to apply to it."""
        with self._lock:
            self._requests.append(request)
            return self._fault

    def set(self, fault: Fault | None, delay: float = 0.0) -> None:
        if fault in self.unsupported:
            generic = f"the simulator cannot make the device {fault.value if fault else None}"
            raise FaultNotSupported(self.reasons.get(fault) or generic)
        with self._lock:
            self._fault = (fault, delay)


def preview_text(frames: Sequence[str]) -> list[str]:
    """Frames as text compared regardless of case and spacing."""
    return [" ".join(frame.split()).upper() for frame in frames]


#: a byte of a preview that the transport does not write (a cyclic protocol's word left as it is in the device's
#: output area): it matches whatever byte the device then sees
UNWRITTEN = "--"


def same_frames(sent: Sequence[str], preview: Sequence[str]) -> bool:
    """``sent`` (as :func:`preview_text` gives it) is what ``preview`` says, a preview's ``--`` matching any byte."""
    if len(sent) != len(preview):
        return False
    for frame, planned in zip(sent, preview, strict=True):
        got, want = frame.split(), planned.split()
        if len(got) != len(want) or any(w not in (g, UNWRITTEN) for g, w in zip(got, want, strict=True)):
            return False
    return True


def with_query(url: str, **params: object) -> str:
    """``url`` with these query parameters set (replaced in place, or appended)."""
    base, _, query = url.partition("?")
    pairs = [item.partition("=") for item in query.split("&") if item]
    items = {key: value for key, _, value in pairs}
    for key, value in params.items():
        items[key] = str(value)
    return base + ("?" + "&".join(f"{k}={v}" for k, v in items.items()) if items else "")


def query_keys(url: str) -> list[str]:
    """The query parameters a URL gives, in order."""
    return [item.partition("=")[0] for item in url.partition("?")[2].split("&") if item]
