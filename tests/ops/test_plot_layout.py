"""The plots read right: the legend covers no data (it sits outside the axes), an event is labelled by what it
is (a start, a trip, a change of state), and its peak is searched from the event on (a trip's says "before")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.text import Annotation

from starterbus.ops.history import HistoryStore
from starterbus.ops.plot import event_figure, figure, plot_event
from starterbus.ops.recording import Point

from .test_record import check_png


def _rendered(fig: Any) -> Any:
    canvas: Any = FigureCanvasAgg(fig)  # (its draw and get_renderer are untyped)
    canvas.draw()
    return canvas.get_renderer()


def assert_legend_covers_no_data(fig: Any) -> None:
    renderer = _rendered(fig)
    (ax,) = fig.axes
    legends = [*fig.legends, *([ax.get_legend()] if ax.get_legend() else [])]
    assert len(legends) == 1
    box = legends[0].get_window_extent(renderer)
    assert not box.overlaps(ax.get_window_extent(renderer)), "the legend lies inside the axes"
    for line in ax.get_lines():
        for x, y in line.get_transform().transform(line.get_xydata()):
            assert not box.contains(x, y), f"the legend covers {line.get_label()} at ({x:.0f}, {y:.0f}) px"


def _annotations(fig: Any) -> dict[str, Annotation]:
    return {a.get_text(): a for a in fig.axes[0].texts if isinstance(a, Annotation)}


def _peak(fig: Any) -> tuple[str, float]:
    ((text, note),) = [(t, a) for t, a in _annotations(fig).items() if t.startswith("peak")]
    return text, float(note.xy[0])


def test_the_legend_of_a_recorded_start_covers_no_running_current() -> None:
    """A long run after the start: the running current lies along the bottom right, where the legend was."""
    points = []
    for n in range(200):
        t = n * 0.05
        amps, state = (min(1300.0, t * 900), "starting") if t < 6 else (300.0, "running")
        points.append(Point(round(t, 4), 1000 + t, state, None, {"a": amps, "b": amps * 0.98, "c": amps * 1.01}))
    fig = figure(points, limit_a=1365.0, title="conveyor (jjr5000): start, running")
    assert_legend_covers_no_data(fig)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["phase A", "phase B", "phase C", "current limit 1365 A", "starting", "running"]
    assert fig.axes[0].get_xlabel() == "time since the start (s)" and "start" in _annotations(fig)


def write_history(db: Path) -> dict[str, int]:
    """Device m1 starts at t=100, runs from 102, is soft-stopped at 105 (the current falls from 320 A) and is
    ready at 108; it trips at 104. Samples every 0.1 s from 99.5 s; the events' ids by name."""

    def change(store: HistoryStore, at: float, before: str, after: str) -> int:
        return store.add_event(at, "m1", "state", f"{before} -> {after}", detail={"from": before, "to": after})

    with HistoryStore(db) as store:
        ids = {
            "start": change(store, 100.0, "ready", "starting"),
            "stop": change(store, 105.0, "running", "stopping"),
            "ready": change(store, 108.0, "stopping", "ready"),
            "trip": store.add_event(104.0, "m1", "fault", "7: motor locked rotor", code=7),
        }
        for n in range(120):
            t = round(99.5 + n * 0.1, 4)
            if t < 100:
                amps, state = 0.0, "ready"
            elif t < 102:
                amps, state = min(1000.0, (t - 100) * 2000), "starting"
            elif t < 105:
                amps, state = 320.0, "running"
            elif t < 108:
                amps, state = max(0.0, 300 - (t - 105) * 150), "stopping"
            else:
                amps, state = 0.0, "ready"
            values = {"current_limit": {"value": 350}, "motor_rated_current": {"value": 390}}
            store.add_sample({"time": t, "device": "m1", "model": "jjr5000", "online": 1, "state": state,
                              "current_a": amps, "values": values})  # fmt: skip
    return ids


@pytest.fixture
def history(tmp_path: Path) -> tuple[Path, dict[str, int]]:
    db = tmp_path / "h.db"
    return db, write_history(db)


def test_a_stop_event_is_labelled_as_the_change_with_its_peak_after_it(history: tuple[Path, dict[str, int]]) -> None:
    db, ids = history
    fig, count = event_figure(db, "m1", ids["stop"])
    notes = _annotations(fig)
    assert "running -> stopping" in notes and "start" not in notes
    assert fig.axes[0].get_xlabel() == "time since the change running -> stopping (s)"
    text, at = _peak(fig)
    assert at >= 0 and text == "peak 300.0 A (phase A) at 0.00 s"  # not the 320 A of running before the stop
    times = [x for line in fig.axes[0].get_lines() for x in line.get_xdata() if line.get_label() == "phase A"]
    assert min(times) < 0 and max(times) == pytest.approx(4.0)  # to the next change (ready at +3 s) and 1 s on
    assert count == len(times)
    assert_legend_covers_no_data(fig)


def test_a_start_event_has_its_peak_after_the_start(history: tuple[Path, dict[str, int]]) -> None:
    db, ids = history
    fig, _ = event_figure(db, "m1", ids["start"])
    assert "start" in _annotations(fig) and fig.axes[0].get_xlabel() == "time since the start (s)"
    text, at = _peak(fig)
    assert text == "peak 1000.0 A (phase A) at 0.50 s" and at == pytest.approx(0.5)
    assert_legend_covers_no_data(fig)


def test_a_trip_looks_back_and_says_so(history: tuple[Path, dict[str, int]]) -> None:
    db, ids = history
    fig, _ = event_figure(db, "m1", ids["trip"])
    assert "trip" in _annotations(fig) and fig.axes[0].get_xlabel() == "time since the trip (s)"
    text, at = _peak(fig)
    assert at == pytest.approx(-3.5) and text == "peak 1000.0 A (phase A) 3.50 s before the trip"
    assert_legend_covers_no_data(fig)


def test_event_plots_render_as_png(history: tuple[Path, dict[str, int]], tmp_path: Path) -> None:
    db, ids = history
    for name in ("start", "stop", "trip"):
        path = tmp_path / f"{name}.png"
        assert plot_event(db, "m1", ids[name], path) > 0
        check_png(path)
