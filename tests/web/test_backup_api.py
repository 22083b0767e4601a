"""The backup part of the web API on the demo fleet: the diff against an uploaded file (and its refusals: too
large, not UTF-8, not TOML, empty), a restore's refusals (too large among them), each with nothing written and
nothing audited, and an operator's restore: written, read back, audited and in the device's event log."""

from __future__ import annotations

import re
import urllib.request
from collections.abc import Iterator

import pytest

from starterbus.ops.backup import loads
from starterbus.ops.throttle import ThrottlePolicy
from starterbus.testing.conformance import wait_until
from starterbus.tests.web.harness import Client, WebDemo, web_demo
from starterbus.web.auth import AuthPolicy
from starterbus.web.backup_api import MAX_UPLOAD


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDemo]:
    logins = AuthPolicy(ThrottlePolicy(backoff_base=60.0), refusal_delay=0.1)
    with web_demo(tmp_path_factory.mktemp("backup"), allow_plaintext_commands=True, logins=logins) as demo:
        yield demo


def _backup(site: WebDemo, device: str) -> str:
    with urllib.request.urlopen(site.url + f"api/devices/{device}/backup", timeout=20) as r:
        text: str = r.read().decode()
    return text


def _with_raw(text: str, key: str, raw: int) -> str:
    """The backup with parameter ``key`` changed to ``raw`` (its ``value`` line dropped, as the file says)."""
    head, _, rest = text.partition(f"[parameters.{key}]\n")
    table, sep, tail = rest.partition("\n\n")
    table = re.sub(r"(?m)^value = .*\n", "", table)
    table = re.sub(r"(?m)^raw = \d+$", f"raw = {raw}", table)
    return f"{head}[parameters.{key}]\n{table}{sep}{tail}"


def _raw(text: str, key: str) -> int:
    return loads(text)[0].parameters[key].raw


def test_a_diff_against_an_uploaded_backup_file(site: WebDemo) -> None:
    text = _backup(site, "conveyor")
    client = Client(site.url)
    status, body = client.call("POST", "/api/devices/conveyor/diff?file=conveyor.toml", text.encode())
    assert status == 200, body
    assert body["diff"] == [] and body["file"]["name"] == "conveyor.toml" and body["model"] == "jjr5000"
    ramp = _raw(text, "ramp_time")
    edited = _with_raw(text, "ramp_time", ramp + 1 if ramp < 120 else ramp - 1)
    status, body = client.call("POST", "/api/devices/conveyor/diff?file=edited.toml", edited.encode())
    assert status == 200, body
    rows = [(r["key"], r["raw_a"], r["raw_b"]) for r in body["diff"]]
    assert rows == [("ramp_time", _raw(edited, "ramp_time"), ramp)]  # a: the file, b: the device
    bom = b"\xef\xbb\xbf" + edited.encode()  # as a Windows editor saves it
    assert client.call("POST", "/api/devices/conveyor/diff", bom)[1]["diff"] == body["diff"]


@pytest.mark.parametrize(
    ("upload", "status", "words"),
    [
        (b"x" * (MAX_UPLOAD + 1), 413, "larger than 256 kB"),
        (b'format = "x"\nmodel = "jjr5000" # caf\xe9\n', 422, "line 2, column 24 (byte offset 36): byte 0xE9 is not"),
        (b"format = [not toml", 422, "not TOML"),
        (b"  \n", 422, "empty"),
        (b'format = "something else"\n', 422, "not a starterbus backup"),
    ],
)
def test_an_upload_that_is_no_backup_is_refused_in_one_line(
    site: WebDemo, upload: bytes, status: int, words: str
) -> None:
    got, body = Client(site.url).call("POST", "/api/devices/conveyor/diff?file=bad.toml", upload)
    assert got == status and words in body["error"] and body["error"].startswith("bad.toml: "), body
    assert "\n" not in body["error"] and body["error"].endswith("nothing read")


def test_a_restore_is_refused_without_an_operator_or_outside_remote_write(site: WebDemo) -> None:
    text = _backup(site, "conveyor")
    ramp = _raw(text, "ramp_time")
    edited = _with_raw(text, "ramp_time", ramp + 1 if ramp < 120 else ramp - 1)
    before = len(site.audit_records())
    assert Client(site.url).call("POST", "/api/devices/conveyor/restore", {"backup": edited})[0] == 401
    reader = Client(site.url)
    assert reader.login("rita") == 200
    status, body = reader.call("POST", "/api/devices/conveyor/restore", {"backup": edited})
    assert status == 403 and "only operators" in body["error"]
    operator = Client(site.url)
    assert operator.login("olga") == 200
    status, body = operator.call("POST", "/api/devices/conveyor/restore", {"backup": edited})
    assert status == 403 and "ramp_time" in body["error"] and "nothing sent" in body["error"]  # not in remote.write
    status, body = operator.call("POST", "/api/devices/conveyor/restore", {"backup": _backup(site, "fan")})
    assert status == 422 and "a backup of a ssd1" in body["error"]  # another model
    status, body = operator.call("POST", "/api/devices/conveyor/restore", {"backup": "format = [not toml"})
    assert status == 422 and "not TOML" in body["error"] and "nothing sent" in body["error"]
    status, body = operator.call("POST", "/api/devices/conveyor/restore", {"text": edited})
    assert status == 422 and "backup" in body["error"]
    assert len(site.audit_records()) == before  # nothing written, nothing audited
    assert _raw(_backup(site, "conveyor"), "ramp_time") == ramp


def test_an_operators_restore_is_written_read_back_audited_and_in_the_event_log(site: WebDemo) -> None:
    text = _backup(site, "crusher")
    limit = _raw(text, "current_limit")
    target = limit - 20 if limit - 20 >= 150 else limit + 20
    operator = Client(site.url)
    assert operator.login("olga") == 200
    _, seen = operator.call("GET", "/api/devices/crusher/events")
    last = max((e["id"] for e in seen), default=0)
    status, body = operator.call(
        "POST", "/api/devices/crusher/restore", {"backup": _with_raw(text, "current_limit", target)}
    )
    assert status == 200 and body["ok"], body
    [outcome] = body["outcomes"]  # only what differs is written
    assert (outcome["key"], outcome["raw"], outcome["result"]) == ("current_limit", target, "ok")
    assert outcome["read_back"] == outcome["new"]
    assert site.demo.starters["crusher"].params["current_limit"] == target
    record = site.audit_records()[-1]
    assert (record["actor"], record["action"], record["key"]) == ("web:olga", "write", "current_limit")

    def written() -> list[dict[str, object]]:
        found = operator.call("GET", f"/api/devices/crusher/events?after={last}")[1]
        return [e for e in found if e["kind"] == "write"]

    assert wait_until(lambda: len(written()) == 1, 20)  # recorded from the audit log at the next poll
    [event] = written()
    assert event["actor"] == "web:olga" and str(event["text"]).startswith("current_limit: ")
    assert str(event["text"]).endswith(": ok")
    site.demo.starters["crusher"].params["current_limit"] = limit


def test_a_restore_over_256_kb_is_refused_with_413_and_nothing_sent(site: WebDemo) -> None:
    text = _backup(site, "crusher")
    padded = text + "#" * (MAX_UPLOAD - len(text.encode()) + 1)  # a comment: still a valid backup, but too large
    before = len(site.audit_records())
    assert Client(site.url).call("POST", "/api/devices/crusher/restore", {"backup": padded})[0] == 401  # who first
    operator = Client(site.url)
    assert operator.login("olga") == 200
    status, body = operator.call("POST", "/api/devices/crusher/restore", {"backup": padded})
    assert status == 413 and body["error"] == "the backup: larger than 256 kB, not a backup file; nothing sent"
    status, body = operator.call("POST", "/api/devices/crusher/restore", {"backup": "#" * (1024 * 1024)})
    assert status == 413 and "larger than 1024 kB" in body["error"]  # beyond the server's body limit: JSON too
    assert len(site.audit_records()) == before
