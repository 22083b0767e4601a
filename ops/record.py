"""Recording a start: status and phase currents as fast as the line allows, from the start command (or the
next start seen) until the motor runs (plus a short settling time), a fault, or a time limit.

The samples are written as CSV, into the history schema (:mod:`starterbus.ops.history`: one ``samples`` row
each and a ``start`` event whose detail holds the current limit), and as a PNG plot (:mod:`starterbus.ops.plot`).

Everything a recording needs is checked before the start command: the output directory (:func:`prepare_output`),
the motor's state (not already going), and, in the guarded path, who controls the starter. Once the motor was
started, a failure no longer loses the samples: sampling stops and returns what it has (``Recording.ended``
says why), and :func:`write_all` saves each output it can, reporting the others.
"""

from __future__ import annotations

import csv
import sqlite3
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from starterbus.core.command_rules import check_command
from starterbus.core.device import Device
from starterbus.core.errors import ConfigurationError, StarterbusError, StateRuleError, UnsupportedOperationError
from starterbus.core.status import Command, MotorState, Status
from starterbus.core.timestamps import iso_time
from starterbus.core.transport import Capability
from starterbus.ops.history import HistoryStore
from starterbus.ops.plot import plot_recording
from starterbus.ops.recording import PHASES, Point, Recording, limit_in_amps

_ACTIVE = frozenset({MotorState.STARTING, MotorState.RUNNING})


def current_limit_amps(device: Device) -> tuple[float | None, float | None]:
    """(current limit in A, rated current in A) from the device's parameters; (None, None) if unreadable."""
    limit, rated = device.profile.role("current_limit"), device.profile.role("rated_current")
    if limit is None or rated is None or Capability.READ_PARAMETERS not in device.capabilities:
        return None, None
    values = device.read(limit, rated)
    return limit_in_amps(limit, float(values[limit.key].value), float(values[rated.key].value))


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
    force: bool = False,
    announce: Callable[[], None] | None = None,
) -> Recording:
    """Record one start of an open device (see the module docstring); ``start`` sends the start command
    through the guarded path (confirmation, audit; ``force``: even though the starter is controlled from
    elsewhere), else the next start the device makes is waited for.

    ``limit`` bounds the whole recording (and the wait for a start), in seconds. After the start, an error or
    Ctrl-C ends the sampling, not the recording: it is returned with ``failed`` set. ``announce`` is called once
    the checks passed, right before the start (or the wait for one).
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
        _check_idle(device, force)
    if announce is not None:
        announce()
    if start:
        rec.commanded = True
        rec.started, t0 = wall(), clock()
        device.command(Command.START, timeout=limit, force=force)
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
    try:
        _sample(device, rec, t0, (deadline, limit), settle, clock, interval, sleep)
    except (StarterbusError, KeyboardInterrupt) as exc:
        rec.failed = True
        rec.ended = "interrupted (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else f"sampling failed: {exc}"
    return rec


def _check_idle(device: Device, force: bool) -> None:
    """A start can be recorded only from a motor at rest, that this master may start (the guard's rules, here
    before anything is announced; the guard checks them again)."""
    status = device.status()
    if status.state in (*_ACTIVE, MotorState.STOPPING):
        raise StateRuleError(
            f"{device.describe()} is already {status.state.value}: there is no start to record; stop it first (or "
            "record without --start to wait for its next start); nothing sent"
        )
    check_command(device, Command.START, status, force=force)


def _sample(
    device: Device,
    rec: Recording,
    t0: float,
    until: tuple[float, float],  # (deadline, the limit it came from)
    settle: float,
    clock: Callable[[], float],
    interval: float,
    sleep: Callable[[float], None],
) -> None:
    deadline, limit = until
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


def _point(status: Status, t: float, at: float) -> Point:
    return Point(
        round(t, 4),
        at,
        status.state.value,
        status.fault_code if status.fault else None,
        {k: float(v.value) for k, v in status.currents.items()},
    )


# -- outputs ------------------------------------------------------------------------------------------------


def write_csv(rec: Recording, path: str | Path, *, overwrite: bool = True) -> None:
    with Path(path).open("w" if overwrite else "x", newline="", encoding="utf-8") as f:
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


DB_NAME = "starts.db"


def prepare_output(directory: str | Path) -> Path:
    """The output directory, made and proven writable, its ``starts.db`` (if any) a history database: checked
    before the start, so that a recording never starts a motor it cannot save."""
    folder = Path(directory)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".starterbus-probe-"):
            pass
    except FileExistsError:
        raise ConfigurationError(f"{folder}: exists and is not a directory (give a directory); nothing sent") from None
    except OSError as exc:
        raise ConfigurationError(f"{folder}: cannot write there ({exc.strerror or exc}); nothing sent") from None
    db = folder / DB_NAME
    if db.exists():
        try:
            HistoryStore(db, create=False).close()
        except ConfigurationError as exc:
            raise ConfigurationError(f"{exc} (record appends to it; give another directory); nothing sent") from None
    return folder


@dataclass(frozen=True, slots=True)
class Saved:
    """What :func:`write_all` saved (kind -> file) and what it could not (kind -> why)."""

    files: dict[str, Path]
    errors: dict[str, str]


def free_stem(folder: Path, started: float) -> str:
    """``start-YYYYmmdd-HHMMSS`` (UTC) of the start, with ``-2``, ``-3``... while a recording has that name."""
    stem = "start-" + time.strftime("%Y%m%d-%H%M%S", time.gmtime(started))
    n, name = 1, stem
    while any((folder / f"{name}.{ext}").exists() for ext in ("csv", "png")):
        n += 1
        name = f"{stem}-{n}"
    return name


def write_all(rec: Recording, directory: str | Path, *, plot: bool = True) -> Saved:
    """CSV, SQLite (appended to ``starts.db``) and, with ``plot``, PNG of one recording in ``directory``.

    Never overwrites (see :func:`free_stem`). Each output is tried even when another failed: the samples of a
    motor that was started are worth whatever can be kept. Plotting needs matplotlib (``ops.extras``).
    """
    folder = Path(directory)
    stem = free_stem(folder, rec.started)
    targets = {"csv": folder / f"{stem}.csv", "db": folder / DB_NAME}
    if plot:
        targets["png"] = folder / f"{stem}.png"
    saved = Saved({}, {})
    for kind, path in targets.items():
        try:
            if kind == "csv":
                write_csv(rec, path, overwrite=False)
            elif kind == "db":
                write_db(rec, path)
            else:
                plot_recording(rec, path)
            saved.files[kind] = path
        except (OSError, StarterbusError, sqlite3.Error, ImportError) as exc:  # ImportError: no matplotlib
            saved.errors[kind] = f"{path}: {exc}"
    return saved
