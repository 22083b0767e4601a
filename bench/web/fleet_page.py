"""Benchmark: the fleet page for 1,000 simulated devices at 1 Hz, in headless Chromium.

Run: ``python bench/web/fleet_page.py [--devices 1000] [--lines 16] [--seconds 20] [--loads 5]``

A synthetic source on the event loop makes the poller's ``Sample`` objects (every device once a second, spread
evenly, the currents changing every time) and hands them to asyncio as :class:`AsyncFleet` does. Two runs:

* baseline: the source alone, its samples consumed and dropped;
* web: the same source feeding :class:`WebServer`, with the fleet page open in Chromium (Debian's, through
  Playwright), its event stream connected.

Extra CPU is the event loop thread's CPU time (``time.thread_time``: the source, aiohttp and the view all run on
it; the browser is another process) per second of wall time, web minus baseline, as a fraction of one core
(goal < 0.05). Keeping up: at the end, the oldest "last poll" among the rows the page shows (goal < 2 s at 1 Hz:
no row falls behind).

Load time (goal < 1 s): the page is loaded ``--loads`` times, each in a fresh browser context (empty cache, as a
first visit), Chromium itself started once before and warmed up by one small page (its start,
``browser_start_s``, is not the page's). ``load_s`` is from ``page.goto`` until Playwright sees every row built
(``body[data-ready]``; it waits for the layout; its own polling included); ``breakdown_ms`` are the page's own
timings from navigation start (the median over the loads): ``html`` (the response's end), ``snapshot`` (the
snapshot's arrival: the ``/api/fleet`` response, or the stream's first event for a page that has no such
request), ``scripts`` (DOMContentLoaded), ``built`` (every row in the DOM), ``painted`` (the first frame after,
laid out and painted). ``reload_s`` is a reload of the last page (scripts cached).

The page's own work at 1 Hz: ``page_main_thread_core``, the renderer's main thread busy (Chrome's
``Performance.getMetrics``: all tasks, script, layout) per second while the CPU is measured, in cores.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import statistics
import threading
import time
from collections.abc import AsyncIterator
from typing import Any

from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.core.supervision import Supervisor
from starterbus.fleet.config import BusConfig, DeviceConfig, FleetConfig
from starterbus.fleet.sample import Sample
from starterbus.web.server import WebServer
from starterbus.web.settings import WebSettings

PROFILE = get_profile("jjr5000")
CURRENTS = PROFILE.phase_currents()


class SyntheticFleet:
    """What :class:`WebServer` uses of an :class:`AsyncFleet`: config, supervisor, poller, samples()."""

    def __init__(self, devices: int, lines: int) -> None:
        buses = []
        for line in range(lines):
            devs = tuple(
                DeviceConfig(f"d{i:04d}", f"line-{line:02d}", "jjr5000", "synthetic", i, 1.0, (), ())
                for i in range(line, devices, lines)
            )
            buses.append(BusConfig(f"line-{line:02d}", "synthetic", "modbus-rtu", 0.0, devs))
        names = {d.name: d for b in buses for d in b.devices}
        self.config = FleetConfig(tuple(buses), source="<bench>", devices_by_name=names)
        self.supervisor = Supervisor()
        self.poller = None
        self._queues: list[asyncio.Queue[Sample]] = []
        self.produced = 0

    async def samples(self) -> AsyncIterator[Sample]:
        queue: asyncio.Queue[Sample] = asyncio.Queue(100_000)
        self._queues.append(queue)
        while True:
            yield await queue.get()

    async def produce(self, stop: asyncio.Event) -> None:
        devices = self.config.devices
        slices = 100  # every 10 ms a hundredth of the fleet
        per = max(1, len(devices) // slices)
        tick = 0
        start = time.monotonic()
        while not stop.is_set():
            chunk = devices[(tick % slices) * per : (tick % slices + 1) * per]
            now = time.time()
            for d in chunk:
                raw = 1000 + (tick * 7 + int(d.name[1:])) % 300
                currents = {n: Value.from_raw(p, raw) for n, p in zip("abc", CURRENTS, strict=False)}
                status = decode_status_word(0x2200, PROFILE.faults, currents=currents)
                sample = Sample(d.name, d.bus, d.model, now, True, status, {}, None, 0)
                self.produced += 1
                for q in self._queues:
                    q.put_nowait(sample)
            tick += 1
            await asyncio.sleep(max(0.0, start + tick * 0.01 - time.monotonic()))


async def _drain(fleet: SyntheticFleet) -> None:
    async for _sample in fleet.samples():
        pass


async def run(
    fleet: SyntheticFleet, seconds: float, web: bool, url_box: dict[str, Any], done: threading.Event
) -> float:
    stop = asyncio.Event()
    producer = asyncio.create_task(fleet.produce(stop))
    try:
        if web:
            async with WebServer(fleet, WebSettings("127.0.0.1", 0)) as server:  # type: ignore[arg-type]
                url_box["url"] = server.url
                await asyncio.to_thread(url_box["ready"].wait)
                cpu0, wall0 = time.thread_time(), time.monotonic()
                await asyncio.sleep(seconds)
                cpu = (time.thread_time() - cpu0) / (time.monotonic() - wall0)
                url_box["clients"] = server.view.clients
                await asyncio.to_thread(done.wait)
                return cpu
        drain = asyncio.create_task(_drain(fleet))
        await asyncio.sleep(2.0)
        cpu0, wall0 = time.thread_time(), time.monotonic()
        await asyncio.sleep(seconds)
        cpu = (time.thread_time() - cpu0) / (time.monotonic() - wall0)
        drain.cancel()
        return cpu
    finally:
        stop.set()
        await producer


#: the page's own timings, from navigation start: added before any of the page's scripts runs
TIMINGS = """(() => {
  const P = performance;
  const oadd = EventTarget.prototype.addEventListener;
  EventTarget.prototype.addEventListener = function (type, fn, opt) {
    if (typeof EventSource !== "undefined" && this instanceof EventSource && type === "snapshot") {
      const inner = fn;
      fn = function (e) { if (!P.getEntriesByName("bench-stream-snapshot").length) P.mark("bench-stream-snapshot");
        return inner.call(this, e); };
    }
    return oadd.call(this, type, fn, opt);
  };
  new MutationObserver((_, observer) => {
    if (!document.body || !document.body.dataset.ready) return;
    observer.disconnect();
    P.mark("bench-built");
    requestAnimationFrame(() => setTimeout(() => P.mark("bench-painted"), 0));
  }).observe(document, { attributes: true, subtree: true, attributeFilter: ["data-ready"] });
})();"""

BREAKDOWN = """() => {
  const mark = (name) => { const e = performance.getEntriesByName(name); return e.length ? e[0].startTime : null; };
  const nav = performance.getEntriesByType("navigation")[0];
  const fleet = performance.getEntriesByType("resource").find((e) => new URL(e.name).pathname === "/api/fleet");
  return { html: nav.responseEnd, snapshot: fleet ? fleet.responseEnd : mark("bench-stream-snapshot"),
    scripts: nav.domContentLoadedEventStart, built: mark("bench-built"), painted: mark("bench-painted") };
}"""


def _load(browser: Any, url: str) -> tuple[Any, Any, float, dict[str, float]]:
    context = browser.new_context(viewport={"width": 1366, "height": 768})
    context.add_init_script(TIMINGS)
    page = context.new_page()
    t0 = time.monotonic()
    page.goto(url, wait_until="commit")
    page.wait_for_selector("body[data-ready='1']", timeout=30_000)
    load = time.monotonic() - t0
    page.wait_for_function("performance.getEntriesByName('bench-painted').length > 0", timeout=30_000)
    return context, page, load, page.evaluate(BREAKDOWN)


def browse(box: dict[str, Any], done: threading.Event, seconds: float, loads: int) -> dict[str, Any]:
    from playwright.sync_api import sync_playwright

    while "url" not in box:
        time.sleep(0.05)
    chromium = shutil.which("chromium")
    with sync_playwright() as p:
        t0 = time.monotonic()
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        started = time.monotonic() - t0
        warm_up = browser.new_context()  # Chromium's first page starts its network service: not the fleet page's
        warm_up.new_page().goto(box["url"] + "api/session")
        warm_up.close()
        times, parts = [], []
        for i in range(loads):
            context, page, load, breakdown = _load(browser, box["url"])
            times.append(load)
            parts.append(breakdown)
            if i < loads - 1:
                context.close()
        t1 = time.monotonic()
        page.reload()
        page.wait_for_selector("body[data-ready='1']", timeout=30_000)
        box["reload_s"] = time.monotonic() - t1
        box["ready"].set()
        cdp = page.context.new_cdp_session(page)
        cdp.send("Performance.enable")
        m0, w0 = _metrics(cdp), time.monotonic()
        time.sleep(seconds + 1.0)
        m1, wall = _metrics(cdp), time.monotonic() - w0
        busy = {k: round((m1[k] - m0[k]) / wall, 4) for k in ("TaskDuration", "ScriptDuration", "LayoutDuration")}
        oldest = page.evaluate(
            """() => { let worst = 0;
                for (const td of document.querySelectorAll('tr[data-device] td.num:last-child')) {
                  const m = td.textContent.match(/([0-9.]+) s/); if (m) worst = Math.max(worst, Number(m[1])); }
                return worst; }"""
        )
        rows = page.locator("tr[data-device]").count()
        browser.close()
    done.set()
    breakdown = {k: round(statistics.median(p[k] for p in parts if p[k] is not None), 1) for k in parts[0]}
    return {
        "start": started,
        "loads": times,
        "breakdown": breakdown,
        "oldest_row_s": oldest,
        "rows": rows,
        "page": busy,
    }


def _metrics(cdp: Any) -> dict[str, float]:
    return {m["name"]: float(m["value"]) for m in cdp.send("Performance.getMetrics")["metrics"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", type=int, default=1000)
    ap.add_argument("--lines", type=int, default=16)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--loads", type=int, default=5, help="page loads in fresh browser contexts (median, worst)")
    args = ap.parse_args()
    base = asyncio.run(run(SyntheticFleet(args.devices, args.lines), args.seconds, False, {}, threading.Event()))
    box: dict[str, Any] = {"ready": threading.Event()}
    done = threading.Event()
    result: dict[str, Any] = {}
    browser = threading.Thread(target=lambda: result.update(browse(box, done, args.seconds, args.loads)))
    browser.start()
    fleet = SyntheticFleet(args.devices, args.lines)
    with_web = asyncio.run(run(fleet, args.seconds, True, box, done))
    browser.join()
    print(
        json.dumps(
            {
                "devices": args.devices,
                "load_average_1min": round(os.getloadavg()[0], 2),
                "baseline_core": round(base, 4),
                "with_web_core": round(with_web, 4),
                "extra_core": round(with_web - base, 4),
                "browser_start_s": round(result["start"], 3),
                "load_s_median": round(statistics.median(result["loads"]), 3),
                "load_s_worst": round(max(result["loads"]), 3),
                "load_s": [round(t, 3) for t in result["loads"]],
                "breakdown_ms": result["breakdown"],
                "reload_s": round(box["reload_s"], 3),
                "rows": result["rows"],
                "oldest_row_s": result["oldest_row_s"],
                "page_main_thread_core": result["page"],
                "event_streams": box.get("clients"),
            }
        )
    )


if __name__ == "__main__":
    main()
