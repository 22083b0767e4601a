"""The web dashboard's JSON API on the demo fleet: reads for everybody, actions only for an operator over
TLS (or explicitly allowed plaintext), with CSRF token, the guarded path, read-back and the audit record."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from starterbus.core.simulator import Phase
from starterbus.core.status import MotorState
from starterbus.ops.throttle import ThrottlePolicy
from starterbus.serve.embedded import mosquitto_binary
from starterbus.testing.conformance import wait_until
from starterbus.tests.web.harness import PASSWORD, Client, WebDemo, web_demo
from starterbus.web.auth import AuthPolicy

DEMO_DEVICES = {"conveyor", "fan", "crusher", "mill", "mixer", "pump-a", "pump-b"}


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDemo]:
    logins = AuthPolicy(ThrottlePolicy(backoff_base=60.0), refusal_delay=0.1)  # a backoff that outlasts the test
    with web_demo(tmp_path_factory.mktemp("web"), allow_plaintext_commands=True, logins=logins) as demo:
        yield demo


def test_the_fleet_lists_every_device_by_line_with_utilisation(site: WebDemo) -> None:
    client = Client(site.url)
    assert wait_until(lambda: all(d["online"] for d in client.call("GET", "/api/fleet")[1]["devices"]), 30)
    _, fleet = client.call("GET", "/api/fleet")
    assert {d["name"] for d in fleet["devices"]} == DEMO_DEVICES
    assert {d["state"] for d in fleet["devices"]} <= {s.value for s in MotorState}
    lines = {line["name"]: line for line in fleet["lines"]}
    assert lines["rtu-line-1"]["devices"] == 2 and 0 < lines["rtu-line-1"]["utilisation"] < 1


def test_the_event_stream_starts_with_a_snapshot_then_updates(site: WebDemo) -> None:
    with urllib.request.urlopen(site.url + "api/stream", timeout=20) as stream:
        events: list[str] = []
        while len(events) < 2:
            line = stream.readline().decode()
            if line.startswith("event: "):
                events.append(line.split(": ", 1)[1].strip())
    assert events == ["snapshot", "update"]


def _first_event(url: str, headers: dict[str, str] | None = None) -> tuple[str, str]:
    """The id and name of a stream's first event."""
    request = urllib.request.Request(url, headers=headers or {})
    with urllib.request.urlopen(request, timeout=20) as stream:
        fields: dict[str, str] = {}
        while "event" not in fields or "id" not in fields:
            line = stream.readline().decode()
            if ": " in line and line.split(": ", 1)[0] in ("id", "event"):
                key, value = line.rstrip("\n").split(": ", 1)
                fields[key] = value
    return fields["id"], fields["event"]


def test_a_page_loaded_from_the_snapshot_continues_the_stream_from_its_id(site: WebDemo) -> None:
    _, fleet = Client(site.url).call("GET", "/api/fleet")
    event_id, event = _first_event(site.url + "api/stream?after=" + fleet["id"])
    assert event == "update" and event_id.split("-")[0] == fleet["id"].split("-")[0]  # not the snapshot again
    assert _first_event(site.url + "api/stream", {"Last-Event-ID": event_id})[1] == "update"  # a reconnection
    assert _first_event(site.url + "api/stream", {"Last-Event-ID": "another-process-1"})[1] == "snapshot"


def test_a_device_pages_stream_carries_that_device_only(site: WebDemo) -> None:
    with urllib.request.urlopen(site.url + "api/stream?device=mill", timeout=20) as stream:
        while not (line := stream.readline().decode()).startswith("data: "):
            pass
    assert [d["name"] for d in json.loads(line[6:])["devices"]] == ["mill"]
    status, body = Client(site.url).call("GET", "/api/stream?device=nothing")
    assert status == 404 and "no device 'nothing'" in body["error"]


def test_the_pages_assets_are_revalidated(site: WebDemo) -> None:
    """After an upgrade a browser never runs an old script: every asset is revalidated (its ETag: a 304)."""
    with urllib.request.urlopen(site.url + "assets/fleet.js", timeout=20) as response:
        assert response.headers["Cache-Control"] == "no-cache" and response.headers["ETag"]


def test_a_visitor_reads_a_device_with_every_parameter(site: WebDemo) -> None:
    def current_limit() -> dict[str, Any]:
        status, detail = Client(site.url).call("GET", "/api/devices/conveyor")
        assert status == 200
        found: dict[str, Any] = next(p for p in detail["points"] if p["key"] == "current_limit")
        return found

    limit = current_limit()
    assert limit["unit"] and limit["zh"] and limit["en"] and limit["certainty"]["certainty"] == "printed"
    # the demo fleet polls it (its first parameter poll may not have come yet on a loaded machine)
    assert wait_until(lambda: current_limit()["now"] is not None, 30)
    detail = Client(site.url).call("GET", "/api/devices/conveyor")[1]
    assert detail["remote"]["write"] == ["current_limit"]
    assert Client(site.url).call("GET", "/api/devices/nobody")[0] == 404


def test_nobody_but_a_logged_in_operator_with_the_csrf_token_acts(site: WebDemo) -> None:
    starter = site.demo.starters["fan"]
    before = len(site.audit_records())
    anonymous = Client(site.url)
    assert anonymous.call("POST", "/api/devices/fan/command", {"command": "start"})[0] == 401
    reader = Client(site.url)
    assert reader.login("rita") == 200
    assert reader.call("POST", "/api/devices/fan/command", {"command": "start"})[0] == 403
    operator = Client(site.url)
    assert operator.login("olga") == 200
    token, operator.csrf = operator.csrf, "forged"
    assert operator.call("POST", "/api/devices/fan/command", {"command": "start"})[0] == 403
    operator.csrf = token
    cross = operator.call("POST", "/api/devices/fan/command", {"command": "start"}, {"Origin": "http://evil.example"})
    assert cross[0] == 403
    assert starter.phase is Phase.STOPPED and len(site.audit_records()) == before  # nothing sent


def test_a_wrong_password_is_refused_then_the_address_backs_off(site: WebDemo) -> None:
    assert Client(site.url).login("olga", "not the password") == 401
    assert Client(site.url).login("olga") == 401  # refused unchecked: the address backs off
    site.forget_failed_logins()
    assert Client(site.url).login("olga") == 200


def test_an_operator_write_is_validated_read_back_and_audited(site: WebDemo) -> None:
    operator = Client(site.url)
    assert operator.login("olga") == 200
    status, body = operator.call("POST", "/api/devices/conveyor/write", {"values": {"current_limit": 99999}})
    assert status == 422 and "nothing sent" in body["error"]
    status, body = operator.call("POST", "/api/devices/conveyor/write", {"values": {"ramp_time": 10}})
    assert status == 403 and "remote writes" in body["error"]  # not in the fleet file's remote.write
    status, body = operator.call("POST", "/api/devices/conveyor/write", {"values": {"current_limit": 350}})
    assert status == 200 and body["ok"], body
    assert body["outcomes"][0]["read_back"].startswith("350")
    last = site.audit_records()[-1]
    assert last["actor"] == "web:olga" and last["key"] == "current_limit" and last["result"] == "ok"


def test_the_history_of_a_device(site: WebDemo) -> None:
    client = Client(site.url)
    assert wait_until(lambda: client.call("GET", "/api/devices/conveyor/history")[0] == 200, 20)
    _, keys = client.call("GET", "/api/devices/conveyor/history")
    assert "current_a" in keys["keys"]
    assert wait_until(lambda: len(client.call("GET", "/api/devices/conveyor/history?key=current_a")[1]["t"]) > 1, 20)


def test_a_backup_and_its_diff_against_the_defaults(site: WebDemo) -> None:
    status, body = Client(site.url).call("GET", "/api/devices/conveyor/backup?format=json")
    assert status == 200 and "current_limit" in body["values"]
    assert isinstance(body["diff_defaults"], list)
    with urllib.request.urlopen(site.url + "api/devices/conveyor/backup", timeout=20) as r:
        assert "attachment" in r.headers["Content-Disposition"] and b"[parameters" in r.read()


def test_without_tls_logins_and_actions_are_refused(tmp_path: Path) -> None:
    with web_demo(tmp_path) as demo:
        client = Client(demo.url)
        status, body = client.call("POST", "/api/login", {"user": "olga", "password": PASSWORD})
        assert status == 403 and "TLS" in body["error"]
        assert client.call("GET", "/api/session")[1]["actions_allowed"] is False


@pytest.mark.skipif(mosquitto_binary() is None, reason="mosquitto is not installed (serve --demo starts one)")
def test_serve_demo_http_says_where_the_pages_are(tmp_path: Path) -> None:
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path), "STARTERBUS_AUDIT_LOG": str(tmp_path / "audit.jsonl")}
    command = [sys.executable, "-m", "starterbus.cli.main", "serve", "--demo", "--http", "127.0.0.1:0", "--json",
               "--node", "web-test", "--duration", "30"]  # fmt: skip
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) as proc:
        try:
            assert proc.stdout is not None
            ready = json.loads(proc.stdout.readline())
            assert ready["http"].startswith("http://127.0.0.1:")
            with urllib.request.urlopen(ready["http"], timeout=10) as page:
                assert b"fleet.js" in page.read()
            _, fleet = Client(ready["http"]).call("GET", "/api/fleet")
            assert {d["name"] for d in fleet["devices"]} == DEMO_DEVICES
        finally:
            proc.terminate()
            proc.wait(30)
