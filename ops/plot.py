"""The start plot: phase currents over time, the current limit as a line, the motor state as bands, the event
and the peak annotated. Drawn with matplotlib's Agg canvas (no display, no pyplot state), as a PNG.

The legend sits below the axes, where it can cover no data. The peak is searched from the event on (t >= 0):
what came before a start or a stop is not its peak; only a trip's plot looks before the event, and says so.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError, StarterbusError, UnsupportedOperationError
from starterbus.core.registry import get_profile
from starterbus.ops.history import HistoryStore
from starterbus.ops.recording import PHASES, Point, Recording, limit_in_amps

STATE_COLOURS = {
    "starting": "#f5c242",
    "running": "#4caf50",
    "stopping": "#64b5f6",
    "fault": "#e53935",
    "ready": "#bdbdbd",
    "stopped": "#757575",  # darker than ready: idle and not known to be ready
    "unknown": "#ffffff",
}
LEGEND_COLUMNS = 6


def _figure() -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise UnsupportedOperationError("plotting needs matplotlib: pip install 'starterbus[plot]'") from exc
    return Figure(figsize=(10, 5), dpi=100, layout="constrained")  # constrained: room for the legend outside


def plot_recording(rec: Recording, path: str | Path, title: str | None = None) -> None:
    """Draw one recording to ``path`` (PNG, 1000 x 500 pixels)."""
    draw(
        rec.points,
        path,
        limit_a=rec.limit_a,
        title=title or f"{rec.device} ({rec.model}): start, {rec.ended or rec.state_at_end()}",
    )


def draw(
    points: Sequence[Point],
    path: str | Path,
    *,
    limit_a: float | None,
    title: str,
    marker: str = "start",
    since: str | None = None,
    peak_before: bool = False,
) -> None:
    """:func:`figure` saved to ``path`` as a PNG."""
    figure(points, limit_a=limit_a, title=title, marker=marker, since=since, peak_before=peak_before).savefig(
        str(path), format="png"
    )


def figure(
    points: Sequence[Point],
    *,
    limit_a: float | None,
    title: str,
    marker: str = "start",
    since: str | None = None,
    peak_before: bool = False,
) -> Any:
    """The plot as a matplotlib Figure: ``marker`` labels t = 0 (the event), the x axis reads "time since
    ``since``" (default: "the" and the marker); the peak is searched from t = 0 on unless ``peak_before``."""
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
    peak = _peak(points, None if peak_before else 0.0)
    if peak is not None:
        t, amps, phase = peak
        when = f"{-t:.2f} s before the {marker}" if t < 0 else f"at {t:.2f} s"
        ax.annotate(
            f"peak {amps:.1f} A (phase {phase.upper()}) {when}",
            xy=(t, amps),
            xytext=(24, -28),
            textcoords="offset points",
            arrowprops={"arrowstyle": "->"},
        )
    handles, _ = ax.get_legend_handles_labels()
    handles += [Patch(color=STATE_COLOURS.get(s, "#eeeeee"), alpha=0.35, label=s) for s in seen]
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), LEGEND_COLUMNS),
               fontsize="small", frameon=False)  # fmt: skip
    ax.set_xlabel(f"time since {since or 'the ' + marker} (s)")
    ax.set_ylabel("phase current (A)")
    ax.set_title(title)
    highest = max((a for p in points for a in p.currents.values()), default=0.0)
    ax.set_ylim(0, max(highest, limit_a or 0.0, 1.0) * 1.15)
    ax.grid(True, alpha=0.3)
    return fig


def _bands(points: Sequence[Point]) -> list[tuple[str, float, float]]:
    bands: list[tuple[str, float, float]] = []
    for i, p in enumerate(points):
        end = points[i + 1].t if i + 1 < len(points) else p.t
        if bands and bands[-1][0] == p.state:
            bands[-1] = (p.state, bands[-1][1], end)
        else:
            bands.append((p.state, p.t, end))
    return bands


def _peak(points: Sequence[Point], since: float | None = 0.0) -> tuple[float, float, str] | None:
    """(time, amps, phase) of the highest current at or after ``since`` (None: anywhere); the first on a tie."""
    best = None
    for p in points:
        if since is not None and p.t < since:
            continue
        for phase, amps in p.currents.items():
            if best is None or amps > best[1]:
                best = (p.t, amps, phase)
    return best


# -- from history -------------------------------------------------------------------------------------------


def plot_event(
    db: str | Path, device: str, event_id: int, path: str | Path, *, after: float = 60.0, before_trip: float = 30.0
) -> int:
    """Draw history event ``event_id`` of ``device`` to ``path`` (PNG); returns the number of samples drawn."""
    fig, count = event_figure(db, device, event_id, after=after, before_trip=before_trip)
    fig.savefig(str(path), format="png")
    return count


def event_figure(
    db: str | Path, device: str, event_id: int, *, after: float = 60.0, before_trip: float = 30.0
) -> tuple[Any, int]:
    """The figure of history event ``event_id`` of ``device`` and the number of samples in it (the window:
    :func:`event_window`). Each is labelled by what it is: a start, a trip, or the change of state."""
    event, points, limit_a = event_window(db, device, event_id, after=after, before_trip=before_trip)
    marker, since = event_marker(event["kind"], event["detail"])
    fig = figure(points, limit_a=limit_a, title=f"{device}: event {event_id} ({event['text']})", marker=marker,
                 since=since, peak_before=event["kind"] == "fault")  # fmt: skip
    return fig, len(points)


def event_window(
    db: str | Path, device: str, event_id: int, *, after: float = 60.0, before_trip: float = 30.0
) -> tuple[dict[str, Any], list[Point], float | None]:
    """History event ``event_id`` of ``device``, its samples (t = 0 at the event) and the current limit in A.

    A ``start`` event (``record``) spans to its recorded end; a ``state`` event into ``starting`` (``poll
    --record``) spans to the next change of state after running was reached, another state change to the next
    change of state (and a second of the state it reached), each at most ``after`` seconds; a ``fault`` event
    shows the ``before_trip`` seconds before the trip and a few after.
    """
    with HistoryStore(db, create=False) as store:
        event = store.event(event_id)
        if event["device"] != device:
            raise ConfigurationError(f"event {event_id} is of device {event['device']!r}, not {device!r}")
        begin = float(event["time"])
        detail: Mapping[str, Any] = event["detail"]
        end = float(detail.get("end") or begin + after)
        if event["kind"] == "state":
            later = [e for e in store.events(device=device, since=begin, kind="state") if e["id"] != event_id]
            if detail.get("to") == "starting":
                ends = [float(e["time"]) for e in later if e["detail"].get("from") == "running"]
            else:
                ends = [float(e["time"]) + 1.0 for e in later if float(e["time"]) > begin]
            end = min([begin + after, *ends])
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
    return event, points, limit_a


def event_marker(kind: str, detail: Mapping[str, Any]) -> tuple[str, str]:
    """(label at t = 0, what the time axis counts from) for a history event: a start, a trip or the change."""
    if kind == "fault":
        return "trip", "the trip"
    if kind == "state" and detail.get("to") != "starting":
        change = f"{detail.get('from') or '?'} -> {detail.get('to') or '?'}"
        return change, f"the change {change}"
    return "start", "the start"


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
