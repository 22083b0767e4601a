"""Several brokers (``--mqtt`` repeated): the first that answers; the next one when the connection is lost or the
primary host goes offline there; births (new bdSeq, its own Will) on every new server. The reconnect delay is
set far beyond the wait, so births within the wait show that moving to the next server does not wait for it."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from starterbus.serve.embedded import Mosquitto, free_port, mosquitto_binary, start_mosquitto

if TYPE_CHECKING:
    from starterbus.tests.serve.conftest import Host, Message, Serve

DELAY = "60"  # --reconnect-delay: the waits below (15 s) end long before it


def is_(kind: str) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind


def bdseq(m: Message) -> int:
    return int(next(x.long_value for x in m.payload.metrics if x.name == "bdSeq"))


@pytest.fixture
def second_broker() -> Iterator[Mosquitto]:
    if mosquitto_binary() is None:
        pytest.skip("mosquitto is not installed (apt-get install mosquitto)")
    b = start_mosquitto()
    try:
        yield b
    finally:
        b.close()


def args(tmp_path: Path, *urls: str) -> list[str]:
    mqtt = [a for url in urls for a in ("--mqtt", url)]
    return [
        *mqtt,
        "--group",
        "g1",
        "--node",
        "n1",
        "--state-file",
        str(tmp_path / "s.json"),
        "--reconnect-delay",
        DELAY,
    ]


def test_the_first_broker_that_answers(
    second_broker: Mosquitto,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(second_broker.port)
    nobody = f"mqtt://127.0.0.1:{free_port()}"  # nothing listens there
    s = serve(str(fleet_toml), *args(tmp_path, nobody, second_broker.url))
    i, _ = host.wait(is_("NBIRTH"))
    host.wait(lambda m: m.kind == "DBIRTH" and m.device == "pump", after=i)
    assert f"{nobody.split('//')[1]} unreachable" in s.output()


def test_connection_lost_moves_to_the_next_broker(
    broker: Mosquitto,
    second_broker: Mosquitto,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    first_host, second_host = host_factory(broker.port), host_factory(second_broker.port)
    serve(str(fleet_toml), *args(tmp_path, broker.url, second_broker.url))
    _, first = first_host.wait(is_("NBIRTH"))
    assert not second_host.messages  # one server at a time

    broker.process.terminate()  # the first broker stops
    i, second = second_host.wait(is_("NBIRTH"))
    assert bdseq(second) > bdseq(first) and second.payload.seq == 0
    second_host.wait(lambda m: m.kind == "DBIRTH" and m.device == "pump", after=i)


def test_primary_host_offline_walks_to_the_next_broker(
    broker: Mosquitto,
    second_broker: Mosquitto,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    hosts = host_factory(broker.port), host_factory(second_broker.port)
    birth = int(time.time() * 1000)  # a host's STATE carries its birth's timestamp, on every server, also offline

    def state(host: Host, online: bool) -> None:
        payload = json.dumps({"online": online, "timestamp": birth})
        host.client.publish("spBv1.0/STATE/scada", payload, qos=1, retain=True).wait_for_publish(5)

    for host in hosts:  # the primary host is online on both servers (retained)
        state(host, True)
    serve(str(fleet_toml), *args(tmp_path, broker.url, second_broker.url), "--primary-host", "scada")
    i, first = hosts[0].wait(is_("NBIRTH"))

    state(hosts[0], False)  # ... then goes offline on the first
    _, death = hosts[0].wait(is_("NDEATH"), after=i)
    assert bdseq(death) == bdseq(first)  # serve's own NDEATH before it leaves
    _, second = hosts[1].wait(is_("NBIRTH"))
    assert bdseq(second) > bdseq(first)
