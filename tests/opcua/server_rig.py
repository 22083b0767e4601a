"""The OPC UA server's test rig: one server on a simulated Modbus fleet on two pseudo-terminals, run on an event
loop in a thread (asyncua takes about a second to start, so ``test_server.py`` shares one per module), and the
asyncua client helpers its tests use."""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import pytest
from asyncua import Client, Node, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from starterbus.aio import AsyncFleet
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.logins import LoginPolicy
from starterbus.opcua.server import OpcUaServer, OpcUaSettings
from starterbus.opcua.users import Role, UserEntry, hash_password
from starterbus.ops.throttle import ThrottlePolicy
from starterbus.testing import wait_until_async
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

T = TypeVar("T")
NS = "urn:starterbus:fleet"
CLIENT_URI = "urn:starterbus:test-client"
USERS = {
    "op": UserEntry("op", Role.OPERATOR, hash_password("op-secret", iterations=1000)),
    "viewer": UserEntry("viewer", Role.READ_ONLY, hash_password("view-secret", iterations=1000)),
}


def fleet_text(line1: str, line2: str) -> str:
    return f"""
[poll]
period = 0.1
max_backoff = 0.5

[[bus]]
name = "line-1"
url = "modbus-rtu://{line1}?timeout=0.3"

  [[bus.device]]
  name = "conveyor"
  model = "jjr5000"
  address = 1
  measurements = ["phase_a_current"]
  parameters = ["current_limit", "ramp_time", "start_mode"]
  remote = {{ commands = ["start", "stop", "reset"], write = ["current_limit"] }}

  [[bus.device]]
  name = "fan"
  model = "ssd1"
  address = 2
  measurements = ["phase_a_current"]
  parameters = ["current_limit"]

  [[bus.device]]
  name = "crusher"
  model = "jjr8000"
  address = 4
  measurements = ["phase_a_current"]
  parameters = ["ramp_time"]
  remote = {{ write = ["ramp_time"] }}

[[bus]]
name = "line-2"
url = "modbus-rtu://{line2}?timeout=0.05&retries=0"

  [[bus.device]]
  name = "pump"
  model = "jjr5000"
  address = 3
  measurements = ["phase_a_current"]

  [[bus.device]]
  name = "ghost"
  model = "jjr5000"
  address = 9
  measurements = ["phase_a_current"]
"""


@dataclass
class Rig:
    loop: asyncio.AbstractEventLoop
    server: OpcUaServer
    starters: dict[str, SimulatedStarter]
    audit: Path
    pki: Path
    url: str

    def run(self, make: Callable[[], Awaitable[T]], timeout: float = 60.0) -> T:  # outer: each step has its own
        async def wrapped() -> T:
            return await make()

        return asyncio.run_coroutine_threadsafe(wrapped(), self.loop).result(timeout)


@contextmanager
def running_rig(tmp: Path) -> Iterator[Rig]:
    """The server on a fleet of two simulated lines, in an event loop of its own thread, until the block ends."""
    starters = {
        "conveyor": SimulatedStarter(get_profile("jjr5000")),
        "fan": SimulatedStarter(get_profile("ssd1")),
        "pump": SimulatedStarter(get_profile("jjr5000")),  # only the subscription test moves it
        "crusher": SimulatedStarter(get_profile("jjr8000")),  # only the state-rule test moves it
    }
    line1 = ModbusRtuSimulator({1: starters["conveyor"], 2: starters["fan"], 4: starters["crusher"]}, pty=True).start()
    line2 = ModbusRtuSimulator({3: starters["pump"]}, pty=True).start()
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="opcua-test-loop", daemon=True)
    thread.start()
    stop = asyncio.Event()
    ready: asyncio.Future[OpcUaServer] = loop.create_future()
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("STARTERBUS_AUDIT_LOG", str(tmp / "audit.jsonl"))
        ports = [sim.client_urls()[unit].split("://", 1)[1].split("?", 1)[0] for sim, unit in ((line1, 1), (line2, 3))]
        config = parse_fleet(fleet_text(*ports), "opcua-test.toml")
        settings = OpcUaSettings(
            "opc.tcp://127.0.0.1:0/starterbus",
            pki_dir=tmp / "pki",
            users=USERS,
            anonymous=True,
            allow_insecure=True,
            # one server for the module: the wrong-password test must not throttle 127.0.0.1 for the tests after
            # it, in whatever order they run (throttling is tested in test_logins.py)
            logins=LoginPolicy(throttle=ThrottlePolicy(backoff_base=0.0), refusal_delay=0.0),
        )
        cert, _key = ensure_certificate(tmp / "pki" / "client", CLIENT_URI)  # the tests' client, trusted
        (tmp / "pki" / "trusted").mkdir()
        (tmp / "pki" / "trusted" / "client.der").write_bytes(cert.read_bytes())

        async def serve() -> None:
            try:
                async with AsyncFleet(config) as fleet, OpcUaServer(fleet, settings) as server:
                    ready.set_result(server)
                    await stop.wait()
            except BaseException as exc:
                if not ready.done():
                    ready.set_exception(exc)
                raise

        task = asyncio.run_coroutine_threadsafe(serve(), loop)
        try:
            server = asyncio.run_coroutine_threadsafe(asyncio.wait_for(asyncio.shield(ready), 30), loop).result()
            yield Rig(loop, server, starters, tmp / "audit.jsonl", tmp / "pki", server.endpoint_url)
        finally:
            loop.call_soon_threadsafe(stop.set)
            task.result(30)
            loop.call_soon_threadsafe(loop.stop)
            thread.join(10)
            loop.close()
            line2.close()
            line1.close()


def client(rig: Rig, user: str | None = None, password: str | None = None) -> Client:
    c = Client(rig.url, timeout=10)
    if user is not None:
        c.set_user(user)
        c.set_password(password or "")
    return c


async def secure_client(rig: Rig, mode: ua.MessageSecurityMode, user: str, password: str) -> Client:
    cert, key = ensure_certificate(rig.pki / "client", CLIENT_URI)
    c = client(rig, user, password)
    c.application_uri = CLIENT_URI
    await c.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), mode=mode)
    return c


async def ns_node(c: Client, text: str) -> Node:
    idx = await c.get_namespace_index(NS)
    return c.get_node(ua.NodeId(text, idx))


async def wait_value(node: Node, accept: Callable[[ua.DataValue], bool], timeout: float = 10.0) -> ua.DataValue:
    """Read until ``accept`` holds (values arrive with the polls); the value accepted."""
    last: list[ua.DataValue] = []

    async def accepted() -> bool:
        last[:] = [await node.read_data_value(raise_on_bad_status=False)]
        return accept(last[0])

    assert await wait_until_async(accepted, timeout), f"{node}: still {last}"
    return last[0]


def audit(rig: Rig) -> list[dict[str, Any]]:
    if not rig.audit.exists():
        return []
    return [json.loads(line) for line in rig.audit.read_text(encoding="utf-8").splitlines()]
