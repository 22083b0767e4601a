"""OPC UA logins: verified off the event loop, the same work for unknown users, throttled, locked out, counted."""

from __future__ import annotations

import asyncio
import logging
import threading
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from prometheus_client import CollectorRegistry, generate_latest

from starterbus.aio import AsyncFleet
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.logins import LoginCollector, LoginPolicy
from starterbus.opcua.server import OpcUaServer, OpcUaSettings
from starterbus.opcua.users import Role, UserEntry, hash_password
from starterbus.ops import users as users_module
from starterbus.ops.throttle import Throttle, ThrottlePolicy
from starterbus.ops.users import verify_password
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

CLIENT_URI = "urn:starterbus:test-client"


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_throttle_backs_off_exponentially_then_locks_and_forgets() -> None:
    clock = Clock()
    throttle = Throttle(ThrottlePolicy(backoff_base=1, backoff_max=3, lockout_after=4, lockout_seconds=100), clock)
    keys = ("address 10.0.0.1", "user 'op'")
    assert throttle.blocked(keys) is None
    assert [f.seconds for f in throttle.failed(keys)] == [1, 1]
    block = throttle.blocked(["user 'op'"])
    assert block is not None and not block.locked and block.seconds == 1
    clock.now += 1
    assert throttle.blocked(keys) is None
    assert [f.seconds for f in throttle.failed(keys[:1])] == [2]
    assert [f.seconds for f in throttle.failed(keys[:1])] == [3]  # capped at backoff_max
    (locked,) = throttle.failed(keys[:1])
    assert locked.locked and locked.seconds == 100 and locked.failures == 4
    assert throttle.locked_keys() == 1
    assert throttle.blocked(keys) == throttle.blocked(keys[:1])  # the lockout is the longest block
    clock.now += 100
    assert throttle.blocked(keys) is None and throttle.locked_keys() == 0
    assert throttle.failed(keys[:1])[0].failures == 1  # the lockout served: counting starts again
    throttle.succeeded(keys)
    assert throttle.blocked(keys) is None


def test_throttle_remembers_a_bounded_number_of_keys() -> None:
    clock = Clock()
    throttle = Throttle(ThrottlePolicy(max_keys=3, forget_after=10), clock)
    for n in range(5):
        throttle.failed([f"user {n}"])
    assert throttle.blocked(["user 0"]) is None  # the oldest were forgotten first
    assert throttle.blocked(["user 4"]) is not None


def test_logins_are_checked_off_the_loop_throttled_and_locked_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    sim = ModbusRtuSimulator({1: SimulatedStarter(get_profile("ssd1"))}, pty=True).start()
    port = sim.client_urls()[1].split("://", 1)[1].split("?", 1)[0]
    config = parse_fleet(
        f'[[bus]]\nname = "l"\nurl = "modbus-rtu://{port}"\n[[bus.device]]\nname = "d"\nmodel = "ssd1"\naddress = 1\n',
        "s.toml",
    )
    users = {"op": UserEntry("op", Role.OPERATOR, hash_password("op-secret", iterations=1234))}
    cert, key = ensure_certificate(tmp_path / "client", CLIENT_URI)
    (tmp_path / "pki" / "trusted").mkdir(parents=True)
    (tmp_path / "pki" / "trusted" / "client.der").write_bytes(cert.read_bytes())
    clock = Clock()
    policy = LoginPolicy(ThrottlePolicy(backoff_base=1, lockout_after=3, lockout_seconds=600), refusal_delay=0)
    settings = OpcUaSettings("opc.tcp://127.0.0.1:0/sb", pki_dir=tmp_path / "pki", users=users, logins=policy)
    verified: list[tuple[str, int]] = []  # (thread, iterations) of every PBKDF2 the server ran
    real_verify = verify_password  # the one PasswordCheck calls for logins.py, spied on below

    def spy(password: str, encoded: str) -> bool:
        verified.append((threading.current_thread().name, int(encoded.split("$")[1])))
        return real_verify(password, encoded)

    monkeypatch.setattr(users_module, "verify_password", spy)
    caplog.set_level(logging.INFO, logger="starterbus.opcua.security")
    url = ""

    async def login(user: str, password: str) -> str:
        c = Client(url, timeout=10)
        c.application_uri = CLIENT_URI
        c.set_user(user)
        c.set_password(password)
        await c.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.Sign)
        try:
            async with c:
                return "ok"
        except ua.uaerrors.BadUserAccessDenied:
            return "refused"

    async def scenario() -> None:
        nonlocal url
        async with AsyncFleet(config) as fleet, OpcUaServer(fleet, settings) as server:
            clock_guard = server.logins
            clock_guard.clock = clock_guard.throttle.clock = clock
            url = server.endpoint_url
            assert await login("op", "op-secret") == "ok"
            assert await login("op", "wrong-one") == "refused"
            assert await login("op", "op-secret") == "refused"  # backing off: not even checked
            clock.now += 1
            assert await login("op", "op-secret") == "ok"  # after the backoff; the success clears the keys
            assert await login("nobody", "whatever") == "refused"
            for _ in range(2):  # with the unknown user's failure above: 3 in a row from 127.0.0.1
                clock.now += 10
                assert await login("op", "wrong-one") == "refused"
            assert clock_guard.lockouts == 1  # the address (the user name has 2 failures since its success)
            clock.now += 500
            assert await login("op", "op-secret") == "refused"  # locked: 600 s
            clock.now += 100
            assert await login("op", "op-secret") == "ok"
            guard = server.logins
            assert dict(guard.outcomes) == {
                "accepted": 3, "wrong_password": 3, "unknown_user": 1, "backoff": 1, "locked": 1,
            }  # fmt: skip
            assert guard.checked_on_loop == 0 and guard.checked_off_loop == 7
            registry = CollectorRegistry()
            registry.register(LoginCollector(lambda: guard))
            scrape = generate_latest(registry).decode()
            assert 'starterbus_opcua_logins_total{outcome="wrong_password"} 3.0' in scrape
            assert "starterbus_opcua_login_lockouts_total 1.0" in scrape

    try:
        asyncio.run(scenario())
    finally:
        sim.close()
    assert len(verified) == 7 and all(thread.startswith("opcua-login") for thread, _ in verified)
    assert {iterations for _, iterations in verified} == {1234}  # the unknown user cost the same PBKDF2
    messages = [r.getMessage() for r in caplog.records if r.name == "starterbus.opcua.security"]
    assert any("refused: user 'nobody' from 127.0.0.1: unknown user" in m for m in messages)
    assert any("locked out for address 127.0.0.1: 3 failures in a row; locked for 600 s" in m for m in messages)
