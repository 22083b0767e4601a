"""Recording a start: status and phase currents as fast as the line allows, from the start command (or the
next start seen) until the motor runs (plus a short settling time), a fault, or a time limit.

The samples are written as CSV, into the history schema (:mod:`starterbus.ops.history`: one ``samples`` row
each and a ``start`` event whose detail holds the current limit), and as a PNG plot (:mod:`starterbus.ops.plot`).
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from starterbus.core.device import Device
from starterbus.core.errors import StarterbusError, UnsupportedOperationError
from starterbus.core.model import PointDef
from starterbus.core.status import Command, MotorState, Status
from starterbus.core.timestamps import iso_time
from starterbus.core.transport import Capability
from starterbus.ops.history import HistoryStore

_ACTIVE = frozenset({MotorState.STARTING, MotorState.RUNNING})
PHASES = ("a", "b", "c")


@dataclass(frozen=True, slots=True)
class Point:
    """One status read: seconds since the start, wall time, state, fault code and the phase currents (A)."""

    t: float
    time: float
    state: str
    fault_code: int | None
    currents: dict[str, float]


@dataclass(slots=True)
class Recording:
    device: str
    model: str
    started: float  # wall time of the start (command sent, or first seen)
    points: list[Point] = field(default_factory=list)
    limit_a: float | None = None  # the current limit in A, when the parameters could be read
    rated_a: float | None = None
    commanded: bool = False
    ended: str = ""  # why the recording stopped

    def state_at_end(self) -> str:
        return self.points[-1].state if self.points else "unknown"


def current_limit_amps(device: Device) -> tuple[float | None, float | None]:
    """(current limit in A, rated current in A) from the device's parameters; (None, None) if unreadable."""
    limit, rated = device.profile.role("current_limit"), device.profile.role("rated_current")
    if limit is None or rated is None or Capability.READ_PARAMETERS not in device.capabilities:
        return None, None
    values = device.read(limit, rated)
    return limit_in_amps(limit, float(values[limit.key].value), float(values[rated.key].value))


def limit_in_amps(limit: PointDef, limit_value: float, rated_a: float) -> tuple[float, float]:
    """A current limit is a multiple of the rated current: in % (JJR5000, SSD1) or x In (JJR8000)."""
    factor = limit_value / 100.0 if limit.unit.strip() == "%" else limit_value
    return factor * rated_a, rated_a


def record_start(
    device: Device,
    *,
    start: bool,
    limit: float = 60.0,
    settle: float = 1.0,
    name: str | None = None,
    clock: Callable[[], float] = time.monotonic,
    wall: Callable[[], float] = time.time,
    interval: float = 0.0,
    sleep: Callable[[float], None] = time.sleep,
) -> Recording:
    """Record one start of an open device (see the module docstring); ``start`` sends the start command
    through the guarded path (confirmation, audit), else the next start the device makes is waited for.

    ``limit`` bounds the whole recording (and the wait for a start), in seconds.
    """
    if Capability.STATUS not in device.capabilities:
        raise UnsupportedOperationError(f"{device.transport.name} cannot read the status, so it cannot record a start")
    if start and device.transport.run_needs_connection:
        raise UnsupportedOperationError(
            f"{device.transport.name}: the run command lives only while this program holds the connection, so a "
            "start recorded here would end in a soft stop when `record` exits; record without --start while a "
            "long-running `poll --record`/`serve` starts the motor, or `plot` that start from its history"
        )
    limit_a, rated_a = current_limit_amps(device)
    rec = Recording(name or device.transport.url.text, device.profile.name, wall(), limit_a=limit_a, rated_a=rated_a)
    deadline = clock() + limit
    t0 = clock()
    if start:
        rec.commanded = True
        rec.started, t0 = wall(), clock()
        device.command(Command.START, timeout=limit)
    else:
        while True:
            status = device.status()
            if status.state is MotorState.STARTING:
                rec.started, t0 = wall(), clock()
                rec.points.append(_point(status, 0.0, rec.started))
                break
            if clock() >= deadline:
                rec.ended = f"no start seen within {limit:g} s"
                return rec
            sleep(interval)
    running_since: float | None = None
    while True:
        status = device.status()
        now = clock()
        rec.points.append(_point(status, now - t0, rec.started + (now - t0)))
        if status.fault:
            rec.ended = f"fault {status.fault_code}: {status.fault_text}"
            break
        if status.state is MotorState.RUNNING and running_since is None:
            running_since = now
        if running_since is not None and now - running_since >= settle:
            rec.ended = "running"
            break
        if status.state not in _ACTIVE and now - t0 > settle:
            rec.ended = f"stopped ({status.state.value}) before running"
            break
        if now >= deadline:
            rec.ended = f"time limit {limit:g} s reached while {status.state.value}"
            break
        sleep(interval)
    return rec


def _point(status: Status, t: float, at: float) -> Point:
    return Point(
        round(t, 4),
        at,
        status.state.value,
        status.fault_code if status.fault else None,
        {k: float(v.value) for k, v in status.currents.items()},
    )


# -- outputs ------------------------------------------------------------------------------------------------


def write_csv(rec: Recording, path: str | Path) -> None:
    with Path(path).open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(["t_s", "time", "state", "fault_code", *(f"current_{p}_A" for p in PHASES)])
        for p in rec.points:
            out.writerow(
                [f"{p.t:.4f}", iso_time(p.time), p.state, p.fault_code or "", *(p.currents.get(x, "") for x in PHASES)]
            )


def write_db(rec: Recording, path: str | Path) -> int:
    """Append the recording to a history database; returns the id of its ``start`` event."""
    with HistoryStore(path) as store:
        event = store.add_event(
            rec.started,
            rec.device,
            "start",
            f"recorded start ({'commanded' if rec.commanded else 'seen'}): {rec.ended}",
            detail={
                "limit_a": rec.limit_a,
                "rated_a": rec.rated_a,
                "end": rec.points[-1].time if rec.points else rec.started,
                "ended": rec.ended,
                "samples": len(rec.points),
            },
        )
        for p in rec.points:
            store.add_sample(
                {
                    "time": p.time,
                    "device": rec.device,
                    "model": rec.model,
                    "online": 1,
                    "state": p.state,
                    "fault_code": p.fault_code,
                    **{f"current_{x}": p.currents.get(x) for x in PHASES},
                    "values": {},
                }
            )
    return event


def write_all(rec: Recording, directory: str | Path) -> dict[str, Path]:
    """CSV, SQLite and PNG of one recording in ``directory``, named after the device and the start time."""
    from starterbus.ops.plot import plot_recording

    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    stem = "start-" + time.strftime("%Y%m%d-%H%M%S", time.gmtime(rec.started))
    paths = {"csv": folder / f"{stem}.csv", "db": folder / "starts.db", "png": folder / f"{stem}.png"}
    write_csv(rec, paths["csv"])
    write_db(rec, paths["db"])
    try:
        plot_recording(rec, paths["png"])
    except StarterbusError:
        del paths["png"]
        raise
    return paths
