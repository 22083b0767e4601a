"""The conformance kit's settings, hooks, fixtures and helpers, shared by its test groups
(:mod:`starterbus.testing.conformance` says how a plugin uses the kit)."""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterator, Mapping, Sequence

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import Refusal, StarterbusError, UnsupportedOperationError
from starterbus.core.model import Kind, PointDef
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.transport import Capability, Transport
from starterbus.testing.faults import Fault, FaultControl, FaultNotSupported, FaultsNotProvided, with_query


class ConformanceNotice(UserWarning):
    """What the kit could not check as it should (shown in pytest's warnings summary)."""


def raw_values(point: PointDef) -> list[int]:
    """The valid raw values of a point, lowest first (an enum's codes; else its two ends)."""
    if point.enum is not None:
        return sorted(v for v in point.enum.labels if point.raw_min <= v <= point.raw_max)
    return [point.raw_min, point.raw_max]


def phase(starter: SimulatedStarter) -> Phase:
    return starter.phase


def is_open(transport: Transport) -> bool:
    return transport.is_open  # read through a call: mypy would keep an earlier assert's narrowing


def open_fds() -> int:
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:  # not Linux: the thread check still runs
        return 0


class KitBase:
    """The kit's settings, hooks, fixtures and helpers (the tests are in the subclasses)."""

    transport: str = ""
    model: str = "jjr5000"
    #: parameters the kit may write (default: writable, not locked while running, addressed on this transport)
    writable_sample = 4

    #: the URL parameters of the answer timeout (seconds) and of the retries of a read (None: the transport has
    #: none; the tests that need them skip)
    url_timeout: str | None = None
    url_retries: str | None = None
    #: a transport whose URL names no retries (``url_retries`` None) but never sends a request again: 0 (the tests
    #: that ask for no retries then run without the parameter; those that ask for some skip)
    fixed_retries: int | None = None
    #: seconds a slow answer takes in the slow-device test: longer than the transport's default timeout (a
    #: transport that ignores the URL's timeout fails), shorter than the timeout the kit then gives (twice this)
    slow_answer: float = 0.8
    #: the timeout the kit gives in the URL for the silent, late, duplicating, busy and unreachable tests
    fault_timeout: float = 0.2
    #: a start through the kit takes bus control (the control word's bit 3 reaches the starter)
    takes_bus_control: bool = True
    #: the status carries the phase currents (the model has them)
    status_has_currents: bool = True
    #: a poll merges adjacent points into fewer requests than points (a register transport)
    merges_requests: bool = False

    def serve(self, starter: SimulatedStarter) -> contextlib.AbstractContextManager[str]:
        """Serve ``starter`` behind the transport under test; a context manager giving the URL a client opens."""
        raise NotImplementedError("a conformance test class must implement serve(starter)")

    def serve_units(self, starters: Sequence[SimulatedStarter]) -> contextlib.AbstractContextManager[list[str]]:
        """Serve several starters on ONE link (one line, bus or gateway), each at its own device address; a
        context manager giving their URLs in the same order. Not implemented: the test skips, saying so."""
        raise NotImplementedError

    def faults(self, starter: SimulatedStarter) -> contextlib.AbstractContextManager[FaultControl]:
        """The fault hook (:mod:`starterbus.testing.faults`): while active, the requests reaching ``starter``
        (served by :meth:`serve`) are recorded and the fault the kit sets applies. Not implemented: every fault
        test skips, saying so."""
        raise FaultsNotProvided

    def refusal_code(self, profile: Profile, reason: Refusal) -> int | None:
        """The device's code for this refusal of the simulated starter, as the plugin's simulator answers it
        (None: the kit checks only that the code's meaning is the model's text for it)."""
        return None

    def invalid_url_values(self, profile: Profile) -> Mapping[str, Sequence[str]]:
        """Values of URL parameters that must be refused beyond ``x``, ``-1`` and the empty value (a device
        address outside the model's range, a speed the model does not offer)."""
        return {}

    # -- fixtures -------------------------------------------------------------------------------------------

    @pytest.fixture
    def profile(self) -> Profile:
        return get_profile(self.model)

    @pytest.fixture
    def starter(self, profile: Profile) -> SimulatedStarter:
        return SimulatedStarter(profile, ManualClock(0.0), load=0.5)

    @pytest.fixture
    def url(self, starter: SimulatedStarter) -> Iterator[str]:
        with self.serve(starter) as url:
            yield url

    @pytest.fixture
    def device(self, url: str, profile: Profile) -> Iterator[Device]:
        with open_device(url, profile) as device:
            yield device

    # -- helpers for the fault tests ----------------------------------------------------------------------

    @contextlib.contextmanager
    def tap(self, starter: SimulatedStarter) -> Iterator[FaultControl]:
        """:meth:`faults`, or a skip naming what is missing."""
        try:
            context = self.faults(starter)
        except FaultsNotProvided:
            pytest.skip(
                f"{type(self).__name__} implements no faults(starter) hook: the silent, slow, late, duplicating, "
                "busy and unreachable device tests, sent-once and preview-equals-sent checks are skipped"
            )
        with context as control:
            yield control

    def set_fault(self, control: FaultControl, fault: Fault, delay: float = 0.0) -> None:
        try:
            control.set(fault, delay)
        except FaultNotSupported as exc:
            pytest.skip(f"{type(self).__name__}'s simulator cannot make the device {fault.value}: {exc}")

    def url_with(self, url: str, *, timeout: float | None = None, retries: int | None = None) -> str:
        """``url`` with the kit's timeout and retries (skips when the transport names no such parameter)."""
        params: dict[str, object] = {}
        if timeout is not None:
            if self.url_timeout is None:
                pytest.skip(f"{type(self).__name__} names no URL timeout parameter (url_timeout)")
            params[self.url_timeout] = f"{timeout:g}"
        if retries is not None:
            if self.url_retries is not None:
                params[self.url_retries] = retries
            elif retries != self.fixed_retries:
                pytest.skip(
                    f"{type(self).__name__} names no URL retries parameter (url_retries)"
                    + ("" if self.fixed_retries is None else f"; it always makes {self.fixed_retries} retries")
                )
        return with_query(url, **params)

    def two_parameters(self, device: Device, starter: SimulatedStarter) -> tuple[PointDef, PointDef]:
        """Two readable parameters the kit gives different values in the starter (an answer to one is never
        the other's value)."""
        if Capability.READ_PARAMETERS not in device.capabilities:
            pytest.skip(f"{self.transport} does not declare {Capability.READ_PARAMETERS.value}")
        points = [p for p in self.addressed(device, Kind.PARAMETER) if p.raw_max > p.raw_min]
        if len(points) < 2:
            pytest.skip(f"{device.profile.display_name} has fewer than two parameters {self.transport} reads")
        first, second = points[0], points[-1]
        low, high = raw_values(first)[0], raw_values(second)[-1]
        if low == high:
            high = raw_values(second)[0]
        starter.params[first.key], starter.params[second.key] = low, high
        return first, second

    # -- helpers --------------------------------------------------------------------------------------------

    def addressed(self, device: Device, kind: Kind) -> list[PointDef]:
        """Points of this kind the transport can address (a point with no address here is refused, not read)."""
        points = device.profile.parameters if kind is Kind.PARAMETER else device.profile.measurements
        usable = []
        for point in points:
            try:
                device.transport.preview_write(point, point.raw_min) if point.writable else None
            except UnsupportedOperationError:
                continue
            except StarterbusError:
                pass
            usable.append(point)
        return usable

    def candidates(self, device: Device, *, certain: bool = True) -> list[PointDef]:
        """Parameters the kit may write: writable, not locked while running, more than one value, addressed on
        this transport, and (``certain``) with both ends of the range certain (codes printed in the manual)."""
        locked = device.profile.control.locked_while_running | {device.profile.control.write_protect_key}
        points = [
            p
            for p in self.addressed(device, Kind.PARAMETER)
            if p.writable
            and p.key not in locked
            and p.raw_max > p.raw_min
            and (not certain or (p.uncertainty(p.raw_min) is None and p.uncertainty(p.raw_max) is None))
        ]
        return points[: self.writable_sample]

    def write_targets(self, device: Device) -> tuple[list[PointDef], bool]:
        """The parameters the write tests use, and whether writing them needs ``accept_uncertain=True``.

        Those whose codes are printed in the manual; failing that (a model that states no certainty), the
        others, written with ``accept_uncertain=True``, and a :class:`ConformanceNotice` warning says so in the
        test's output. None at all, while the transport declares writes: the test fails, naming the model.
        """
        points = self.candidates(device)
        if points:
            return points, False
        points = self.candidates(device, certain=False)
        if not points:
            pytest.fail(
                f"{self.transport} declares {Capability.WRITE_PARAMETERS.value} but {device.profile.display_name} "
                "has no parameter the kit may write (writable, not locked while running, more than one value, "
                f"addressed on {self.transport}): give the kit a model that has one"
            )
        warnings.warn(
            ConformanceNotice(
                f"{device.profile.display_name} states no parameter whose codes are all printed in the manual: "
                f"the write tests use {', '.join(p.key for p in points)} with accept_uncertain=True"
            ),
            stacklevel=2,
        )
        return points, True
