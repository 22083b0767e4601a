"""The device page's event log and restore in real headless Chromium (as test_browser.py: Debian's ``chromium``
driven by Playwright through ``executable_path``; one browser and one demo fleet for the module).

What an operator does through the page (a stop with the keyboard alone, a write, a restore of a backup file)
and what a technician does with the CLI on the same audit file appear in the open page's event log with who did
it, without reloading. A read-only visitor cannot restore; a file over 256 kB is refused in one line, unsent.
``STARTERBUS_SCREENSHOTS=DIR`` saves the device page after the stop and the write there
(docs/web-device-events.png).
"""

from __future__ import annotations

import getpass
import os
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from starterbus.core.simulator import Phase
from starterbus.core.status import Command
from starterbus.ops.throttle import ThrottlePolicy
from starterbus.testing.conformance import wait_until
from starterbus.tests.web.chromium import WAIT_MS, needs_chromium, sync_api
from starterbus.tests.web.harness import PASSWORD, WebDemo, web_demo
from starterbus.tests.web.test_backup_api import _raw, _with_raw
from starterbus.web.auth import AuthPolicy
from starterbus.web.backup_api import MAX_UPLOAD

pytestmark = needs_chromium


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDemo]:
    logins = AuthPolicy(ThrottlePolicy(backoff_base=60.0), refusal_delay=0.1)
    with web_demo(
        tmp_path_factory.mktemp("events"), modbus_tcp="mill", allow_plaintext_commands=True, logins=logins
    ) as demo:
        yield demo


def _open(site: WebDemo, page: Any, device: str, user: str | None = None) -> None:
    page.goto(site.url + "device/" + device)
    page.wait_for_selector("body[data-ready='1']", timeout=WAIT_MS)
    if user is not None:
        page.click("#login-button")
        page.fill("#login-user", user)
        page.fill("#login-password", PASSWORD)
        page.press("#login-password", "Enter")
        sync_api.expect(page.locator("#who")).to_contain_text(user, timeout=WAIT_MS)
    page.evaluate("window.notReloaded = true")


def _event(page: Any, kind: str, actor: str, words: str) -> Any:
    """The event log's row of this kind by this actor with these words, once it is there."""
    row = page.locator(f"#events tr[data-kind='{kind}'][data-actor='{actor}']", has_text=words)
    sync_api.expect(row).to_have_count(1, timeout=WAIT_MS)
    return row


def _backup(site: WebDemo, device: str) -> str:
    with urllib.request.urlopen(site.url + f"api/devices/{device}/backup", timeout=20) as r:
        text: str = r.read().decode()
    return text


def _file(name: str, data: bytes) -> dict[str, object]:
    return {"name": name, "mimeType": "text/plain", "buffer": data}


def test_an_operators_stop_by_keyboard_and_write_appear_in_the_event_log_with_who(site: WebDemo, page: Any) -> None:
    starter = site.demo.starters["conveyor"]
    assert site.fleet.poller is not None
    site.fleet.poller.submit("conveyor", lambda device: device.command(Command.START)).result(20)
    assert wait_until(lambda: starter.phase in (Phase.STARTING, Phase.RUNNING), 10)
    _open(site, page, "conveyor", "olga")
    stop = page.locator("#cmd-stop")
    sync_api.expect(stop).to_be_enabled(timeout=WAIT_MS)
    stop.focus()
    page.keyboard.press("Enter")  # the keyboard alone: the dialog opens on Cancel, Tab goes to Confirm
    sync_api.expect(page.locator("#confirm-dialog")).to_be_visible()
    assert page.evaluate("document.activeElement.id") == "confirm-cancel"
    page.keyboard.press("Tab")
    page.keyboard.press("Enter")
    sync_api.expect(page.locator("#action-result")).to_contain_text(": ok", timeout=WAIT_MS)
    assert page.evaluate("document.activeElement.id") == "cmd-stop"  # the focus is back where it was
    assert starter.phase in (Phase.STOPPING, Phase.STOPPED)
    row = _event(page, "command", "web:olga", "stop:")
    assert row.locator("td.text").inner_text().endswith(": ok")
    assert row.locator("td.who").inner_text() == "web:olga"

    limit = starter.params["current_limit"]
    target = limit - 10 if limit - 10 >= 150 else limit + 10
    field = page.locator("#points input[data-key='current_limit']")
    field.fill(str(target))
    field.press("Enter")  # Enter in the field writes, after the confirmation
    page.click("#confirm-ok")
    sync_api.expect(page.locator("#action-result")).to_contain_text(f"read back {target} %: ok", timeout=WAIT_MS)
    assert starter.params["current_limit"] == target
    _event(page, "write", "web:olga", f"current_limit: {limit} % -> {target} %: ok")
    assert page.evaluate("window.notReloaded") is True
    folder = os.environ.get("STARTERBUS_SCREENSHOTS")
    if folder:
        page.evaluate("window.scrollTo(0, 0)")
        page.screenshot(path=str(Path(folder) / "web-device-events.png"), full_page=False)


def test_a_cli_command_on_the_same_audit_log_appears_in_the_open_page(site: WebDemo, page: Any, tmp_path: Path) -> None:
    # A technician's CLI on serve's machine, with serve's fleet file, commands a Modbus TCP starter that serve
    # polls: a Modbus TCP server takes several masters (a PKW gateway station, an RTU line or a DeviceNet
    # slave serves one, and the CLI would be refused).
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(site.demo.fleet_toml, encoding="utf-8")
    _open(site, page, "mill-tcp")
    page.wait_for_selector("#events[data-loaded='1']", timeout=WAIT_MS)  # the log as it was before
    cli = [sys.executable, "-m", "starterbus.cli.main", "stop", "mill-tcp", "--fleet", str(fleet), "--yes", "--json"]
    done = subprocess.run(
        [*cli, "--audit-log", str(site.audit)], check=False, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    actor = f"cli:{getpass.getuser()}"
    assert site.audit_records()[-1]["actor"] == actor
    row = _event(page, "command", actor, "stop:")
    assert row.locator("td.who").inner_text() == actor
    assert page.evaluate("window.notReloaded") is True


def test_an_operator_restores_a_backup_file_through_the_page(site: WebDemo, page: Any) -> None:
    text = _backup(site, "crusher")
    limit = _raw(text, "current_limit")
    target = limit - 20 if limit - 20 >= 150 else limit + 20
    edited = _with_raw(text, "current_limit", target)
    _open(site, page, "crusher", "olga")
    page.set_input_files("#restore-file", files=[_file("crusher-edited.toml", edited.encode())])
    sync_api.expect(page.locator("#confirm-text")).to_contain_text("crusher-edited.toml")
    page.click("#confirm-ok")
    result = page.locator("#action-result")
    sync_api.expect(result).to_contain_text("current_limit: ", timeout=WAIT_MS)
    assert "read back" in result.inner_text() and result.inner_text().endswith(": ok")  # the units are the model's
    assert site.demo.starters["crusher"].params["current_limit"] == target  # reached the simulator
    last = site.audit_records()[-1]
    assert (last["actor"], last["action"], last["key"], last["result"]) == ("web:olga", "write", "current_limit", "ok")
    _event(page, "write", "web:olga", "current_limit: ")
    page.set_input_files("#restore-file", files=[_file("crusher-edited.toml", edited.encode())])  # once more
    page.click("#confirm-ok")
    sync_api.expect(result).to_contain_text("already has every value", timeout=WAIT_MS)  # nothing to write
    assert page.evaluate("window.notReloaded") is True


def test_a_read_only_visitor_cannot_restore(site: WebDemo, page: Any) -> None:
    text = _backup(site, "crusher")
    edited = _with_raw(text, "current_limit", _raw(text, "current_limit") + 10)
    before = len(site.audit_records())
    _open(site, page, "crusher")
    restore = page.locator("#restore-file")
    assert restore.is_disabled()
    _open(site, page, "crusher", "rita")  # logged in, read-only
    assert restore.is_disabled()
    page.evaluate("document.getElementById('restore-file').disabled = false")  # forced: the server refuses
    page.set_input_files("#restore-file", files=[_file("edited.toml", edited.encode())])
    page.click("#confirm-ok")
    sync_api.expect(page.locator("#action-result")).to_contain_text("only operators act", timeout=WAIT_MS)
    assert len(site.audit_records()) == before
    assert site.demo.starters["crusher"].params["current_limit"] == _raw(text, "current_limit")


def test_a_file_over_256_kb_is_refused_in_the_page_in_one_line(site: WebDemo, page: Any) -> None:
    big = _file("big.toml", b"# " + b"x" * MAX_UPLOAD)
    before = len(site.audit_records())
    _open(site, page, "conveyor", "olga")
    page.set_input_files("#restore-file", files=[big])
    result = page.locator("#action-result")
    sync_api.expect(result).to_have_text("big.toml: larger than 256 kB, not a backup file; nothing sent")
    assert page.locator("#confirm-dialog").count() == 0  # not even asked
    page.set_input_files("#diff-file", files=[big])
    sync_api.expect(page.locator("#diff [role='alert']")).to_have_text(
        "big.toml: larger than 256 kB, not a backup file; nothing sent"
    )
    assert len(site.audit_records()) == before


def test_the_device_page_at_1366x768_shows_the_event_log_on_the_first_screen(site: WebDemo, page: Any) -> None:
    _open(site, page, "crusher")
    log = page.locator("#s-events")
    box = log.bounding_box()
    assert box is not None and box["y"] < 768  # no scrolling past a hundred parameters to find it
    width = page.evaluate("document.documentElement.scrollWidth")
    assert width <= 1366  # nothing sideways at 1366 px
    page.wait_for_selector("#events[data-loaded='1']", timeout=WAIT_MS)
    page.keyboard.press("Tab")  # the first stop of the keyboard: the link back to the fleet
    assert page.evaluate("document.activeElement.getAttribute('href')") == "/"
    page.click("nav.jump a[href='#s-params']")  # the jump links reach the parameters
    assert page.evaluate("location.hash") == "#s-params"


def test_a_device_without_a_recorded_start_shows_no_empty_chart(site: WebDemo, page: Any) -> None:
    _open(site, page, "pump-b")  # never started in this module
    sync_api.expect(page.locator("#start-note")).to_have_text("No start recorded yet.", timeout=WAIT_MS)
    assert not page.locator("#start-select").is_visible() and not page.locator("#start-chart").is_visible()
