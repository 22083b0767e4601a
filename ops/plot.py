"""The start plot: phase currents over time, the current limit as a line, the motor state as bands, the start
and the peak annotated. Drawn with matplotlib's Agg canvas (no display, no pyplot state), as a PNG.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError, StarterbusError, UnsupportedOperationError
from starterbus.core.registry import get_profile
from starterbus.ops.history import HistoryStore
from starterbus.ops.record import PHASES, Point, Recording, limit_in_amps

STATE_COLOURS = {
    "starting": "#f5c242",
    "running": "#4caf50",
    "stopping": "#64b5f6",
    "fault": "#e53935",
    "ready": "#bdbdbd",
    "stopped": "#bdbdbd",
    "unknown": "#ffffff",
}


def _figure() -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise UnsupportedOperationError("plotting needs matplotlib: pip install 'starterbus[plot]'") from exc
    return Figure(figsize=(10, 5), dpi=100)


def plot_recording(rec: Recording, path: str | Path, title: str | None = None) -> None:
    """Draw one recording to ``path`` (PNG, 1000 x 500 pixels)."""
    draw(
        rec.points,
        path,
        limit_a=rec.limit_a,
        title=title or f"{rec.device} ({rec.model}): start, {rec.ended or rec.state_at_end()}",
    )


def draw(
    points: Sequence[Point], path: str | Path, *, limit_a: float | None, title: str, marker: str = "start"
) -> None:
    from matplotlib.patches import Patch

    fig = _figure()
    ax = fig.add_subplot()
    times = [p.t for p in points]
    for phase in PHASES:
        if any(phase in p.currents for p in points):
            ax.plot(times, [p.currents.get(phase, float("nan")) for p in points], label=f"phase {phase.upper()}")
    if limit_a is not None:
        ax.axhline(limit_a, color="#c62828", linestyle="--", linewidth=1.2, label=f"current limit {limit_a:.0f} A")
    seen: dict[str, None] = {}
    for state, begin, end in _bands(points):
        ax.axvspan(begin, end, color=STATE_COLOURS.get(state, "#eeeeee"), alpha=0.18, linewidth=0)
        seen[state] = None
    ax.axvline(0.0, color="black", linewidth=1)
    ax.annotate(marker, xy=(0.0, 1.0), xycoords=("data", "axes fraction"), xytext=(4, -14),
                textcoords="offset points")  # fmt: skip
    peak = _peak(points)
    if peak is not None:
        t, amps, phase = peak
        ax.annotate(
            f"peak {amps:.1f} A (phase {phase.upper()}) at {t:.2f} s",
            xy=(t, amps),
            xytext=(24, -28),
            textcoords="offset points",
            arrowprops={"arrowstyle": "->"},
        )
    handles, _ = ax.get_legend_handles_labels()
    handles += [Patch(color=STATE_COLOURS.get(s, "#eeeeee"), alpha=0.35, label=s) for s in seen]
    ax.legend(handles=handles, loc="lower right", fontsize="small")
    ax.set_xlabel(f"time since {marker} (s)")
    ax.set_ylabel("phase current (A)")
    ax.set_title(title)
    top = max([peak[1] if peak else 0.0, limit_a or 0.0, 1.0])
    ax.set_ylim(0, top * 1.15)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(str(path), format="png")


def _bands(points: Sequence[Point]) -> list[tuple[str, float, float]]:
    bands: list[tuple[str, float, float]] = []
    for i, p in enumerate(points):
        end = points[i + 1].t if i + 1 < len(points) else p.t
        if bands and bands[-1][0] == p.state:
            bands[-1] = (p.state, bands[-1][1], end)
        else:
            bands.append((p.state, p.t, end))
    return bands


def _peak(points: Sequence[Point]) -> tuple[float, float, str] | None:
    best = None
    for p in points:
        for phase, amps in p.currents.items():
            if best is None or amps > best[1]:
                best = (p.t, amps, phase)
    return best


# -- from history -------------------------------------------------------------------------------------------


def plot_event(
    db: str | Path, device: str, event_id: int, path: str | Path, *, after: float = 60.0, before_trip: float = 30.0
) -> int:
    """Draw history event ``event_id`` of ``device``; returns the number of samples drawn.

    A ``start`` event (``record``) spans to its recorded end; a ``state`` event into ``starting`` (``poll
    --record``) spans to the next change of state after running was reached, at most ``after`` seconds; a
    ``fault`` event shows the ``before_trip`` seconds before the trip and a few after.
    """
    with HistoryStore(db, create=False) as store:
        event = store.event(event_id)
        if event["device"] != device:
            raise ConfigurationError(f"event {event_id} is of device {event['device']!r}, not {device!r}")
        begin = float(event["time"])
        detail: Mapping[str, Any] = event["detail"]
        end = float(detail.get("end") or begin + after)
        if event["kind"] == "state":
            later = [
                e for e in store.events(device=device, since=begin, kind="state")
                if e["id"] != event_id and e["detail"].get("from") == "running"
            ]  # fmt: skip
            end = min([begin + after, *(float(e["time"]) for e in later)])
        lead = 0.5
        if event["kind"] == "fault":
            lead, end = before_trip, begin + 5.0
        rows = store.samples(device=device, since=begin - lead, until=end)
    if not rows:
        raise ConfigurationError(f"{db}: no samples of {device!r} around event {event_id}")
    points = [
        Point(
            round(r["time"] - begin, 4),
            r["time"],
            r["state"] or ("offline" if not r["online"] else "unknown"),
            r["fault_code"],
            {x: float(r[f"current_{x}"]) for x in PHASES if r[f"current_{x}"] is not None},
        )
        for r in rows
    ]
    limit_a = detail.get("limit_a")
    if limit_a is None:
        limit_a = _limit_from_values(rows)
    marker = "trip" if event["kind"] == "fault" else "start"
    draw(points, path, limit_a=limit_a, title=f"{device}: event {event_id} ({event['text']})", marker=marker)
    return len(points)


def _limit_from_values(rows: Sequence[Mapping[str, Any]]) -> float | None:
    """The current limit from polled parameter values (the fleet file lists current_limit and the rated current)."""
    for row in reversed(rows):
        try:
            profile = get_profile(row["model"])
        except StarterbusError:  # an unknown or removed model: no limit line
            return None
        limit, rated = profile.role("current_limit"), profile.role("rated_current")
        values = row["values"]
        if limit is not None and rated is not None and limit.key in values and rated.key in values:
            return limit_in_amps(limit, float(values[limit.key]["value"]), float(values[rated.key]["value"]))[0]
    return None
