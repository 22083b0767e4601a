"""The web dashboard in real headless Chromium (Debian's ``chromium``, driven by Playwright through its
``executable_path``): one browser for the module, the demo fleet served in this process.

``STARTERBUS_SCREENSHOTS=DIR`` saves the fleet page and a device page there (docs/web-*.png are made so).
"""

from __future__ import annotations

import os
import re
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from starterbus.core.simulator import Phase
from starterbus.core.status import Command
from starterbus.ops.backup import loads
from starterbus.ops.throttle import ThrottlePolicy
from starterbus.testing.conformance import wait_until
from starterbus.tests.web.chromium import WAIT_MS, needs_chromium, sync_api
from starterbus.tests.web.harness import PASSWORD, Client, WebDemo, web_demo
from starterbus.web.auth import AuthPolicy

pytestmark = needs_chromium


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDemo]:
    logins = AuthPolicy(ThrottlePolicy(backoff_base=60.0), refusal_delay=0.1)
    with web_demo(tmp_path_factory.mktemp("browser"), allow_plaintext_commands=True, logins=logins) as demo:
        yield demo


def _screenshot(page: Any, name: str) -> None:
    folder = os.environ.get("STARTERBUS_SCREENSHOTS")
    if folder:
        page.screenshot(path=str(Path(folder) / name), full_page=False)


def test_the_fleet_page_shows_every_device_and_a_trip_without_reload(site: WebDemo, page: Any) -> None:
    page.goto(site.url)
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    assert page.locator("tr[data-device]").count() == len(site.demo.starters)
    for name in site.demo.starters:
        assert page.locator(f"tr[data-device='{name}'] .state").count() == 1
    page.evaluate("window.notReloaded = true")
    site.demo.starters["crusher"].inject_fault(6)
    row = page.locator("tr[data-device='crusher']")
    sync_api.expect(row.locator(".state")).to_have_attribute("data-state", "fault", timeout=WAIT_MS)
    sync_api.expect(row.locator(".state")).to_have_text("fault")  # the state in words, not colour alone
    assert "6:" in row.locator("td.fault").inner_text()
    assert page.evaluate("window.notReloaded") is True
    page.select_option("#filter-state", "fault")
    assert page.locator("tr[data-device]:visible").count() == 1
    page.select_option("#filter-state", "")
    _screenshot(page, "web-fleet.png")
    page.click("#lang")
    sync_api.expect(row.locator(".state")).to_have_text("故障")
    page.click("#lang")
    site.demo.starters["crusher"].fault_reset()


def test_a_read_only_visitor_cannot_act(site: WebDemo, page: Any) -> None:
    page.goto(site.url + "device/fan")
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    for button in ("#cmd-start", "#cmd-stop", "#cmd-reset"):
        assert page.locator(button).is_disabled()
    assert page.locator("#action-hint").is_visible()
    _login(page, "rita")  # logged in, but read-only
    sync_api.expect(page.locator("#who")).to_contain_text("rita")
    assert page.locator("#cmd-stop").is_disabled()


def _login(page: Any, user: str) -> None:
    page.click("#login-button")
    page.fill("#login-user", user)
    page.fill("#login-password", PASSWORD)
    page.press("#login-password", "Enter")  # the keyboard alone
    sync_api.expect(page.locator("#who")).to_contain_text(user, timeout=WAIT_MS)


def test_an_operators_stop_reaches_the_starter_read_back_and_audited(site: WebDemo, page: Any) -> None:
    starter = site.demo.starters["conveyor"]
    assert site.fleet.poller is not None
    site.fleet.poller.submit("conveyor", lambda device: device.command(Command.START)).result(20)  # over the bus
    assert wait_until(lambda: starter.phase in (Phase.STARTING, Phase.RUNNING), 10)
    page.goto(site.url + "device/conveyor")
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    _login(page, "olga")
    sync_api.expect(page.locator("#cmd-stop")).to_be_enabled(timeout=WAIT_MS)
    page.click("#cmd-stop")
    sync_api.expect(page.locator("#confirm-dialog")).to_be_visible()
    page.click("#confirm-ok")
    result = page.locator("#action-result")
    sync_api.expect(result).to_contain_text(": ok", timeout=WAIT_MS)  # stop: running -> stopping: ok
    assert starter.phase in (Phase.STOPPING, Phase.STOPPED)
    last = site.audit_records()[-1]
    assert (last["actor"], last["command"], last["result"]) == ("web:olga", "stop", "ok")


def test_a_recorded_start_plots(site: WebDemo, page: Any) -> None:
    starter = site.demo.starters["mill"]
    starter.start("test")
    assert wait_until(lambda: starter.phase is Phase.RUNNING, 20)
    page.goto(site.url + "device/mill")
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    chart = page.locator("#start-chart")
    sync_api.expect(chart.locator("canvas")).to_have_count(1, timeout=WAIT_MS)
    assert int(chart.get_attribute("data-points") or 0) > 1
    sync_api.expect(page.locator("#start-note")).to_contain_text("peak")
    page.locator("#s-starts").evaluate("e => e.scrollIntoView()")  # the plot and the history chart below it
    _screenshot(page, "web-device.png")


def test_the_history_chart_plots_a_measured_point_over_a_time_range(site: WebDemo, page: Any) -> None:
    client = Client(site.url)
    recorded = "/api/devices/mill/history?key=current_a"
    assert wait_until(lambda: (r := client.call("GET", recorded))[0] == 200 and len(r[1]["t"]) > 2, 30)
    page.goto(site.url + "device/mill")
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    chart = page.locator("#history-chart")
    sync_api.expect(page.locator("#history-key option[value='current_a']")).to_have_count(1, timeout=WAIT_MS)
    page.select_option("#history-key", "current_a")
    page.select_option("#history-range", "600")  # the last 10 minutes
    sync_api.expect(chart).to_have_attribute("data-key", "current_a", timeout=WAIT_MS)
    sync_api.expect(chart.locator("canvas")).to_have_count(1)
    assert int(chart.get_attribute("data-points") or 0) > 2  # samples from the SQLite history, drawn
    # 10 min asked, not the default hour (the key's own plot, drawn first, may still be on screen a moment)
    assert wait_until(lambda: float(chart.get_attribute("data-since") or 0) > time.time() - 3000, 10)
    sync_api.expect(page.locator("#history-note")).to_contain_text("samples")


def test_the_diff_view_against_the_defaults_and_an_uploaded_file(site: WebDemo, page: Any) -> None:
    with urllib.request.urlopen(site.url + "api/devices/conveyor/backup", timeout=20) as r:
        text = r.read().decode()
    ramp = loads(text)[0].parameters["ramp_time"].raw
    edited = text.replace(f"raw = {ramp}\n", f"raw = {ramp + 1}\n", 1)
    edited = re.sub(r"(\[parameters\.ramp_time\]\n(?:.*\n)*?)value = .*\n", r"\1", edited, count=1)
    assert loads(edited)[0].parameters["ramp_time"].raw == ramp + 1
    page.goto(site.url + "device/conveyor")
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    diff = page.locator("#diff")
    page.click("#diff-button")  # against the defaults (a visitor may: it only reads)
    sync_api.expect(diff).to_have_attribute("data-rows", re.compile(r"\d+"), timeout=WAIT_MS)
    page.set_input_files("#diff-file", files=[_file("edited.toml", edited.encode())])
    row = diff.locator("tr[data-key='ramp_time']")
    sync_api.expect(row).to_have_count(1, timeout=WAIT_MS)
    assert diff.locator("tbody tr").count() == 1  # only what differs from the file
    cells = row.locator("td").all_inner_texts()
    assert str(ramp + 1) in cells[0] and str(ramp) in cells[1]  # the file's, then the device's
    sync_api.expect(diff.locator("caption")).to_contain_text("edited.toml")
    page.set_input_files("#diff-file", files=[_file("gbk.toml", "x = '工'".encode("gbk"))])  # not UTF-8
    sync_api.expect(diff.locator("[role='alert']")).to_contain_text("gbk.toml: line 1", timeout=WAIT_MS)


def _file(name: str, data: bytes) -> dict[str, object]:
    return {"name": name, "mimeType": "text/plain", "buffer": data}
