"""The fleet page's view: snapshots joined from rows encoded once, and event streams that continue from an event
id with only the rows changed since (a page loaded from ``/api/fleet``, or reconnecting), else a snapshot."""

from __future__ import annotations

import asyncio
import json
from typing import Any

from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.fleet.config import BusConfig, DeviceConfig, FleetConfig
from starterbus.fleet.sample import Sample
from starterbus.web.view import FleetView

PROFILE = get_profile("jjr5000")
NAMES = ("a1", "a2", "b1")


def _view(history: int = 32) -> FleetView:
    buses = tuple(
        BusConfig(
            bus,
            "synthetic",
            "modbus-rtu",
            0.0,
            tuple(DeviceConfig(n, bus, "jjr5000", "x", i, 1.0, (), ()) for i, n in enumerate(names)),
        )
        for bus, names in (("line-a", NAMES[:2]), ("line-b", NAMES[2:]))
    )
    config = FleetConfig(buses, source="<test>", devices_by_name={d.name: d for b in buses for d in b.devices})
    return FleetView(config, clock=lambda: 1000.0, history=history)


def _sample(name: str, word: int = 0x2200, online: bool = True) -> Sample:
    bus = "line-b" if name.startswith("b") else "line-a"
    status = decode_status_word(word, PROFILE.faults) if online else None
    return Sample(name, bus, "jjr5000", 999.0, online, status, {}, None if online else "timeout", 0)


def _events(queue: asyncio.Queue[bytes | None]) -> list[tuple[str, str, dict[str, Any]]]:
    out = []
    while not queue.empty():
        message = queue.get_nowait()
        assert message is not None
        fields = dict(line.split(": ", 1) for line in message.decode().strip().split("\n"))
        out.append((fields["id"], fields["event"], json.loads(fields["data"])))
    return out


def test_the_snapshot_text_is_the_snapshot() -> None:
    view = _view()
    view.observe(_sample("a1"))
    text = json.loads(view.snapshot_json())
    assert text == view.snapshot()
    assert {d["name"] for d in text["devices"]} == set(NAMES)
    assert [d["state"] for d in text["devices"] if d["name"] == "a1"] != ["unknown"]
    assert text["id"] == view.event_id and [line["name"] for line in text["lines"]] == ["line-a", "line-b"]


def test_a_stream_without_an_id_starts_with_a_snapshot_then_updates_carry_ids() -> None:
    view = _view()
    queue = view.subscribe()
    [(first_id, event, data)] = _events(queue)
    assert event == "snapshot" and data["id"] == first_id and len(data["devices"]) == 3
    view.observe(_sample("b1"))
    view.flush()
    [(second_id, event, data)] = _events(queue)
    assert event == "update" and second_id != first_id
    assert [d["name"] for d in data["devices"]] == ["b1"]


def test_a_page_with_the_rows_of_an_id_gets_only_what_changed_since() -> None:
    view = _view()
    loaded = view.snapshot()["id"]  # the page's /api/fleet
    assert _events(view.subscribe(loaded)) == []  # nothing changed: nothing to send, not the snapshot again
    view.observe(_sample("a1"))
    view.flush()  # no page connected: the change is kept as names, nothing encoded for nobody
    view.observe(_sample("b1", 0x0008))
    view.flush()
    [(event_id, event, data)] = _events(view.subscribe(loaded))
    assert event == "update" and event_id == view.event_id
    assert sorted(d["name"] for d in data["devices"]) == ["a1", "b1"]
    b1 = next(d for d in data["devices"] if d["name"] == "b1")
    assert b1 == view.rows["b1"]


def test_an_id_the_view_cannot_continue_from_gets_a_snapshot() -> None:
    view = _view(history=2)
    loaded = view.event_id
    other = _view().event_id  # another process's (a restarted server)
    for _ in range(3):  # more refreshes than the view keeps
        view.observe(_sample("a2"))
        view.flush()
    ahead = f"{view.epoch}-{view.seq + 1}"
    for after in (loaded, other, ahead, "garbage", f"{view.epoch}-x"):
        [(_, event, data)] = _events(view.subscribe(after))
        assert event == "snapshot", after
        assert len(data["devices"]) == 3
    recent = f"{view.epoch}-{view.seq - 1}"
    [(_, event, data)] = _events(view.subscribe(recent))
    assert event == "update" and [d["name"] for d in data["devices"]] == ["a2"]


def test_a_device_pages_stream_carries_its_device_only() -> None:
    """A device page's stream (``?device=NAME``): the snapshot and every update hold that device's row only (an
    update without it when it did not change); a fleet page beside it still gets every changed row."""
    view = _view()
    fleet = view.subscribe()
    page = view.subscribe(device="a2")
    (_, kind, snap), *_ = _events(page)
    assert kind == "snapshot" and [d["name"] for d in snap["devices"]] == ["a2"]
    _events(fleet)
    view.observe(_sample("a1"))
    view.observe(_sample("a2", word=0x2201))
    view.flush()
    assert [[d["name"] for d in data["devices"]] for _, _, data in _events(page)] == [["a2"]]
    assert [sorted(d["name"] for d in data["devices"]) for _, _, data in _events(fleet)] == [["a1", "a2"]]
    view.observe(_sample("b1"))
    view.flush()
    ((_, kind, data),) = _events(page)
    assert (
        kind == "update" and data["devices"] == [] and [line["name"] for line in data["lines"]] == ["line-a", "line-b"]
    )
    (last_id, _, _), *_ = [(view.event_id, "", {})]
    view.observe(_sample("a1", word=0x2201))
    view.flush()
    again = view.subscribe(after=last_id, device="a2")  # reconnecting: a2 did not change since
    assert _events(again) == []
    view.unsubscribe(page)
    view.unsubscribe(again)
    assert view.clients == 1
