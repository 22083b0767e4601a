"""A device's event log in the web API on the demo fleet: what the history recorded (a fault with the currents
before the trip and its text in both languages), every guarded write and command with who did it (web:USER, or
the system account of an audit record without an actor), and ``?after=ID``: only what a page has not seen yet."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from starterbus.core.audit import AuditLog
from starterbus.ops.throttle import ThrottlePolicy
from starterbus.testing.conformance import wait_until
from starterbus.tests.web.harness import Client, WebDemo, web_demo
from starterbus.web.auth import AuthPolicy


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDemo]:
    logins = AuthPolicy(ThrottlePolicy(backoff_base=60.0), refusal_delay=0.1)
    with web_demo(tmp_path_factory.mktemp("events"), allow_plaintext_commands=True, logins=logins) as demo:
        yield demo


def _events(client: Client, device: str, after: int | None = None) -> list[dict[str, Any]]:
    status, body = client.call(
        "GET", f"/api/devices/{device}/events" + (f"?after={after}" if after is not None else "")
    )
    assert status == 200, body
    return list(body)


def _last_id(client: Client, device: str) -> int:
    return max((e["id"] for e in _events(client, device)), default=0)


def test_a_write_appears_with_its_actor_and_after_gives_only_what_is_new(site: WebDemo) -> None:
    operator = Client(site.url)
    assert operator.login("olga") == 200
    last = _last_id(operator, "conveyor")
    limit = site.demo.starters["conveyor"].params["current_limit"]
    target = limit - 10 if limit - 10 >= 150 else limit + 10
    status, body = operator.call("POST", "/api/devices/conveyor/write", {"values": {"current_limit": target}})
    assert status == 200 and body["ok"], body
    assert wait_until(lambda: any(e["kind"] == "write" for e in _events(operator, "conveyor", last)), 20)
    new = _events(operator, "conveyor", last)
    assert all(e["id"] > last for e in new)
    [write] = [e for e in new if e["kind"] == "write"]
    assert write["actor"] == "web:olga" and write["text"] == f"current_limit: {limit} % -> {target} %: ok"
    assert _events(operator, "conveyor", max(e["id"] for e in new)) == []  # nothing newer yet
    assert write in _events(operator, "conveyor")  # the whole list has it too


def test_an_audit_record_without_an_actor_names_the_system_account(site: WebDemo) -> None:
    client = Client(site.url)
    last = _last_id(client, "fan")
    url = site.fleet.config.devices_by_name["fan"].url
    record = AuditLog(site.audit).append(device=url, model="ssd1", action="command", command="stop", result="ok")
    assert wait_until(lambda: any(e["kind"] == "command" for e in _events(client, "fan", last)), 20)
    [event] = [e for e in _events(client, "fan", last) if e["kind"] == "command"]
    assert event["actor"] is None and event["user"] == record["user"]


def test_a_fault_has_the_currents_before_the_trip_and_its_text_in_chinese(site: WebDemo) -> None:
    client = Client(site.url)
    last = _last_id(client, "crusher")
    starter = site.demo.starters["crusher"]
    starter.start("test")
    assert wait_until(lambda: starter.current() > 0, 20)
    assert wait_until(lambda: any(e["kind"] == "state" for e in _events(client, "crusher", last)), 20)
    starter.inject_fault(6)
    try:
        assert wait_until(lambda: any(e["kind"] == "fault" for e in _events(client, "crusher", last)), 20)
    finally:
        starter.fault_reset()
    [fault] = [e for e in _events(client, "crusher", last) if e["kind"] == "fault"]
    assert fault["code"] == 6 and fault["text"].startswith("6: ") and fault["zh"].startswith("6: ")
    assert fault["zh"] != fault["text"]  # the profile's Chinese text
    assert fault["currents_before"] and all("time" in c for c in fault["currents_before"])


@pytest.mark.parametrize("after", ["x", "-1", "1.5", "%C2%B2"])  # the last: ², a digit to str.isdigit
def test_after_must_be_an_event_id(site: WebDemo, after: str) -> None:
    status, body = Client(site.url).call("GET", f"/api/devices/conveyor/events?after={after}")
    assert status == 400 and "not an event id" in body["error"]
