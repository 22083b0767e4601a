"""The simulated soft starter shared by every protocol simulator.

One :class:`SimulatedStarter` holds a model's parameters and a motor state machine driven by an injectable
clock. Protocol front ends (Modbus slave, Profibus DP slave, DeviceNet node) translate their frames into
calls here and map a :class:`SimulatorRefusal` to their own error codes, so every protocol sees the same
device and the same rules.

State machine (times from the profile's ramp and stop-time parameters)::

    stopped --start--> starting --ramp time--> running --soft stop--> stopping --stop time--> stopped
       any state --fault--> fault (motor off, current 0) --fault reset--> stopped

Current while starting rises linearly from 0 to the current limit (limit x rated current) over the first
quarter of the ramp time and is held there until the ramp ends; running current is ``load`` x rated current;
it falls linearly to 0 over the soft stop time.

Control word semantics: a register write (Modbus FC06, a PKW-free one-off write) acts on levels: start bit 1
on a stopped motor starts it, start bit falling 1 -> 0 soft-stops it. A cyclic write (PZD, DeviceNet poll)
acts on edges only, so a held start bit never restarts a motor after a fault reset. Bit 2 (fault reset) acts
when it appears. Models with ``bus_control_required`` (JJR8000) ignore commands while bit 3 is 0.

Every control output that reaches the starter is recorded in :attr:`SimulatedStarter.control_writes` (what
counts: :mod:`starterbus.core.control_log`); the conformance kit uses it to prove that reads never actuate.
"""

from __future__ import annotations

import enum
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from starterbus.core.address_space import space_of
from starterbus.core.control_log import ControlLog, ControlWrite, counts
from starterbus.core.errors import Refusal, SimulatorRefusal
from starterbus.core.model import Kind, PointDef
from starterbus.core.profile import Profile
from starterbus.core.status import (
    CW_BUS_CONTROL,
    CW_RESET,
    CW_START,
    encode_status_word,
)

Clock = Callable[[], float]


class ManualClock:
    """A clock that moves only when told: deterministic simulations in tests."""

    def __init__(self, start: float = 0.0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("a clock does not go backwards")
        self.now += seconds


class Phase(str, enum.Enum):
    STOPPED = "stopped"
    STARTING = "starting"
    RUNNING = "running"
    STOPPING = "stopping"
    FAULT = "fault"


_TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0}


@dataclass(frozen=True, slots=True)
class StarterSnapshot:
    phase: Phase
    current_a: float
    fault_code: int | None
    control_word: int
    status_word: int


class SimulatedStarter:
    """A deterministic soft starter of one model. Thread-safe: every public method holds ``lock``."""

    def __init__(
        self,
        profile: Profile,
        clock: Clock | None = None,
        *,
        load: float = 0.8,
        values: Mapping[str, int] | None = None,
        mains_on: bool = True,
    ) -> None:
        self.profile = profile
        self.clock: Clock = clock or time.monotonic
        self.lock = threading.RLock()
        self.load = load
        self.mains_on = mains_on
        self.warning = False
        self.params: dict[str, int] = {}
        for point in profile.parameters:
            default = point.default if point.default is not None else point.raw_min
            if point.enum is not None and default not in point.enum.labels:
                default = min(v for v in point.enum.labels if point.raw_min <= v <= point.raw_max)
            self.params[point.key] = default
        if profile.control.source_key:  # commissioned for the bus: start/stop from any master, as in a plant
            self.params[profile.control.source_key] = profile.control.source_bus_codes[0]
        for key, raw in (values or {}).items():
            self.params[profile.point(key).key] = raw
        self._phase = Phase.STOPPED
        self.phase_since = self.clock()
        self.fault_code: int | None = None
        self.control_word = 0
        self.start_count = 0
        self.max_start_current = 0.0
        self.max_run_current = 0.0
        self.run_seconds = 0.0
        self.last_fault_code = 0
        self.last_fault_current = 0.0
        self._stop_from_current = 0.0
        self._last_tick = self.phase_since
        self._addr: dict[tuple[str, Kind, object], PointDef] = {
            (proto, p.kind, addr): p for p in profile.points.values() for proto, addr in p.addresses.items()
        }
        self.events: list[tuple[float, str]] = []  # (time, what happened) for demos and tests
        self._control_log = ControlLog()

    # -- control outputs received -------------------------------------------------------------------------

    @property
    def control_writes(self) -> list[ControlWrite]:
        """The control outputs that reached the starter, oldest first (the last few hundred; what counts:
        :mod:`starterbus.core.control_log`). Starting or stopping through :meth:`start` / :meth:`soft_stop`
        (the keypad, the terminals) is not a control output and is not recorded."""
        with self.lock:
            return list(self._control_log.records)

    @property
    def control_writes_total(self) -> int:
        """How many control outputs reached the starter in all (a mark for :meth:`control_writes_since`)."""
        with self.lock:
            return self._control_log.total

    def control_writes_since(self, mark: int) -> list[ControlWrite]:
        """The control outputs recorded after :attr:`control_writes_total` was ``mark``."""
        with self.lock:
            return self._control_log.since(mark)

    # -- addressing ---------------------------------------------------------------------------------------

    def point_at(self, transport: str, kind: Kind, address: object) -> PointDef:
        """The point at ``address`` in an address space (its name, or a transport's that speaks it)."""
        point = self._addr.get((transport, kind, address))
        if point is None:
            point = self._addr.get((space_of(transport), kind, address))
        if point is None:
            shown = f"{address:#06x}" if isinstance(address, int) else repr(address)
            raise SimulatorRefusal(Refusal.NOT_AVAILABLE, f"no {kind.value} at {transport} address {shown}")
        return point

    # -- engineering helpers --------------------------------------------------------------------------------

    def _eng(self, role: str, fallback: float) -> float:
        point = self.profile.role(role)
        if point is None:
            return fallback
        return float(point.to_engineering(self.params[point.key]))

    @property
    def rated_current(self) -> float:
        return self._eng("rated_current", 100.0)

    @property
    def current_limit_multiple(self) -> float:
        point = self.profile.role("current_limit")
        if point is None:
            return 3.0
        value = float(point.to_engineering(self.params[point.key]))
        return value / 100.0 if point.unit == "%" else value

    def _seconds(self, role: str, fallback: float) -> float:
        point = self.profile.role(role)
        if point is None:
            return fallback
        return float(point.to_engineering(self.params[point.key])) * _TIME_UNITS.get(point.unit, 1.0)

    # -- state machine ------------------------------------------------------------------------------------

    def _current_at(self, phase: Phase, elapsed: float) -> float:
        rated = self.rated_current
        if phase is Phase.STARTING:
            ramp = max(self._seconds("ramp_time", 10.0), 1e-9)
            limit = self.current_limit_multiple * rated
            return limit * min(1.0, elapsed / (ramp / 4))
        if phase is Phase.RUNNING:
            return self.load * rated
        if phase is Phase.STOPPING:
            stop = self._seconds("stop_time", 0.0)
            if stop <= 0:
                return 0.0
            return max(0.0, self._stop_from_current * (1 - elapsed / stop))
        return 0.0

    @property
    def phase(self) -> Phase:
        """The motor's state now (advances the state machine to the clock)."""
        with self.lock:
            self._advance()
            return self._phase

    def _set_phase(self, phase: Phase, at: float, why: str) -> None:
        self._phase = phase
        self.phase_since = at
        self.events.append((at, f"{phase.value}: {why}"))

    def _advance(self) -> None:
        now = self.clock()
        while True:
            elapsed = now - self.phase_since
            if self._phase is Phase.STARTING:
                ramp = self._seconds("ramp_time", 10.0)
                end = min(elapsed, ramp)
                self.max_start_current = max(self.max_start_current, self._current_at(Phase.STARTING, end))
                if elapsed >= ramp:
                    self._set_phase(Phase.RUNNING, self.phase_since + ramp, "ramp complete")
                    continue
            elif self._phase is Phase.RUNNING:
                self.max_run_current = max(self.max_run_current, self._current_at(Phase.RUNNING, elapsed))
            elif self._phase is Phase.STOPPING:
                stop = self._seconds("stop_time", 0.0)
                if elapsed >= stop:
                    self._set_phase(Phase.STOPPED, self.phase_since + stop, "soft stop complete")
                    continue
            break
        if self._phase in (Phase.STARTING, Phase.RUNNING, Phase.STOPPING):
            self.run_seconds += max(0.0, now - self._last_tick)
        self._last_tick = now

    def current(self) -> float:
        """Phase current now, in A."""
        with self.lock:
            self._advance()
            return self._current_at(self._phase, self.clock() - self.phase_since)

    def snapshot(self) -> StarterSnapshot:
        with self.lock:
            return StarterSnapshot(self.phase, self.current(), self.fault_code, self.control_word, self.status_word())

    # -- commands -------------------------------------------------------------------------------------------

    def start(self, why: str = "start command") -> bool:
        with self.lock:
            self._advance()
            if self._phase is not Phase.STOPPED or not self.mains_on:
                return False
            self.start_count += 1
            self._set_phase(Phase.STARTING, self.clock(), why)
            return True

    def soft_stop(self, why: str = "soft stop command") -> bool:
        with self.lock:
            self._advance()
            if self._phase not in (Phase.STARTING, Phase.RUNNING):
                return False
            now = self.clock()
            self._stop_from_current = self._current_at(self._phase, now - self.phase_since)
            self._set_phase(Phase.STOPPING, now, why)
            self._advance()
            return True

    def fault_reset(self) -> bool:
        with self.lock:
            self._advance()
            if self._phase is not Phase.FAULT:
                return False
            self.fault_code = None
            self._set_phase(Phase.STOPPED, self.clock(), "fault reset")
            return True

    def inject_fault(self, code: int) -> None:
        """Trip with any 6-bit fault code (known to the fault table or not): the motor stops at once."""
        if not 0 < code <= 0x3F:
            raise ValueError(f"fault code {code} is not 1..63")
        with self.lock:
            self._advance()
            self.last_fault_current = self._current_at(self._phase, self.clock() - self.phase_since)
            self.last_fault_code = code
            self.fault_code = code
            self._set_phase(Phase.FAULT, self.clock(), f"fault {code}: {self.profile.faults.text(code)}")

    def command_lost(self, why: str = "command connection lost") -> None:
        """Safe state when a cyclic master disappears: the run command it held is dropped (soft stop, recorded
        in :attr:`control_writes`).

        A motor started another way (keypad, terminals, ``start()``) is not the lost master's to stop.
        """
        with self.lock:
            if self.control_word & CW_START:
                self.control_word &= ~CW_START
                self._control_log.add(ControlWrite(self.clock(), self.control_word, True, why, lost=True))
                self.soft_stop(why)

    def write_control_word(self, word: int, *, cyclic: bool = False, source: str = "") -> None:
        """A master's control word: one-off (``cyclic=False``, acts on levels) or one cycle of a cyclic output
        (acts on edges). ``source`` names the front end and service in :attr:`control_writes`."""
        if not 0 <= word <= 0xFFFF:
            raise SimulatorRefusal(Refusal.OUT_OF_RANGE, f"control word {word!r} is not 16 bits")
        with self.lock:
            prev = self.control_word
            if counts(word, prev, cyclic=cyclic):
                self._control_log.add(ControlWrite(self.clock(), word, cyclic, source))
            self.control_word = word
            if self.profile.control.bus_control_required and not word & CW_BUS_CONTROL:
                return
            if self.profile.control.bus_control_required and not prev & CW_BUS_CONTROL:
                prev = 0  # taking bus control: the command bits count as new
            if word & CW_RESET and (not cyclic or not prev & CW_RESET):
                self.fault_reset()
            starting = word & CW_START
            if starting and (not cyclic or not prev & CW_START):
                self.start()
            elif not starting and prev & CW_START:
                self.soft_stop()

    # -- registers -------------------------------------------------------------------------------------------

    def status_word(self) -> int:
        with self.lock:
            self._advance()
            phase = self._phase
            return encode_status_word(
                fault_code=self.fault_code,
                starting=phase is Phase.STARTING,
                running=phase is Phase.RUNNING,
                stopping=phase is Phase.STOPPING,
                ready=phase is Phase.STOPPED and self.mains_on,
                bus_control=bool(self.control_word & CW_BUS_CONTROL),
                mains_voltage=self.mains_on and self.profile.control.bit12_is_mains_voltage,
            )

    @property
    def at_reference(self) -> bool:
        with self.lock:
            self._advance()
            return self._phase is Phase.RUNNING

    def _amps_raw(self, point: PointDef, amps: float) -> int:
        return max(point.raw_min, min(point.raw_max, round(amps / point.scale)))

    def read(self, point: PointDef) -> int:
        """Raw value of any point of the profile, as the device would report it now."""
        with self.lock:
            if point.kind is Kind.PARAMETER:
                return self.params[point.key]
            self._advance()
            roles = self.profile.roles
            key = point.key
            if key == roles.get("control_word"):
                return self.control_word
            if key == roles.get("status_word"):
                return self.status_word()
            if key in roles.get("phase_currents", ()):
                return self._amps_raw(point, self.current())
            if key == roles.get("max_start_current"):
                return self._amps_raw(point, self.max_start_current)
            if key == roles.get("max_run_current"):
                return self._amps_raw(point, self.max_run_current)
            if key == roles.get("start_count"):
                return min(point.raw_max, self.start_count)
            if key == roles.get("run_time"):
                seconds_per_unit = _TIME_UNITS.get(point.unit, 3600.0) * point.scale
                return min(point.raw_max, int(self.run_seconds / seconds_per_unit))
            if key == roles.get("last_fault_code"):
                return self.last_fault_code
            if key == roles.get("last_fault_current"):
                return self._amps_raw(point, self.last_fault_current)
            return point.raw_min

    def write(self, point: PointDef, raw: int) -> None:
        """Write a parameter as the device would, refusing exactly where the manual says it refuses."""
        with self.lock:
            if point.kind is not Kind.PARAMETER or not point.writable:
                raise SimulatorRefusal(Refusal.READ_ONLY, f"{point.key} is read-only")
            if not point.raw_min <= raw <= point.raw_max or (point.enum is not None and raw not in point.enum.labels):
                raise SimulatorRefusal(
                    Refusal.OUT_OF_RANGE, f"{point.key}: {raw} outside {point.raw_min}..{point.raw_max}"
                )
            protect = self.profile.control.write_protect_key
            if protect and point.key != protect and self.params[protect] == 0:
                raise SimulatorRefusal(Refusal.WRITE_PROTECTED, f"parameter writes are forbidden ({protect} = 0)")
            self._advance()
            if point.key in self.profile.control.locked_while_running and self._phase in (
                Phase.STARTING,
                Phase.RUNNING,
                Phase.STOPPING,
            ):
                raise SimulatorRefusal(Refusal.WHILE_RUNNING, f"{point.key} cannot be modified while running")
            self.params[point.key] = raw
