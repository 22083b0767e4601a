"""Default security (Basic256Sha256 Sign/SignAndEncrypt, user names, trusted clients); `starterbus opcua --demo`."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from starterbus.aio import AsyncFleet
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.server import OpcUaServer, OpcUaSettings
from starterbus.opcua.users import Role, UserEntry, hash_password
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

CLIENT_URI = "urn:starterbus:test-client"


def test_defaults_offer_only_signed_endpoints_and_refuse_anonymous(tmp_path: Path) -> None:
    sim = ModbusRtuSimulator({1: SimulatedStarter(get_profile("ssd1"))}, pty=True).start()
    port = sim.client_urls()[1].split("://", 1)[1].split("?", 1)[0]
    config = parse_fleet(
        f'[[bus]]\nname = "l"\nurl = "modbus-rtu://{port}"\n[[bus.device]]\nname = "d"\nmodel = "ssd1"\naddress = 1\n',
        "s.toml",
    )
    users = {"op": UserEntry("op", Role.OPERATOR, hash_password("op-secret", iterations=1000))}
    cert, key = ensure_certificate(tmp_path / "client", CLIENT_URI)
    stranger = ensure_certificate(tmp_path / "stranger", CLIENT_URI)
    (tmp_path / "trusted").mkdir()
    (tmp_path / "trusted" / "client.der").write_bytes(cert.read_bytes())
    settings = OpcUaSettings(
        "opc.tcp://127.0.0.1:0/sb", pki_dir=tmp_path / "pki", users=users, trusted_clients=tmp_path / "trusted"
    )
    url = ""

    async def secure(user: str | None, pair: tuple[Path, Path] = (cert, key)) -> Client:
        c = Client(url, timeout=10)
        c.application_uri = CLIENT_URI
        if user is not None:
            c.set_user(user)
            c.set_password("op-secret")
        await c.set_security(SecurityPolicyBasic256Sha256, str(pair[0]), str(pair[1]), mode=ua.MessageSecurityMode.Sign)
        return c

    async def scenario() -> None:
        nonlocal url
        async with AsyncFleet(config) as fleet, OpcUaServer(fleet, settings) as server:
            url = server.endpoint_url
            endpoints = await Client(url).connect_and_get_server_endpoints()
            offered = {(e.SecurityPolicyUri.rsplit("#", 1)[1], e.SecurityMode) for e in endpoints}
            assert offered == {
                (policy, mode)
                for policy in ("Basic256Sha256", "Aes256_Sha256_RsaPss", "Aes128_Sha256_RsaOaep")
                for mode in (ua.MessageSecurityMode.Sign, ua.MessageSecurityMode.SignAndEncrypt)
            }
            tokens = {t.TokenType for e in endpoints for t in e.UserIdentityTokens}
            assert tokens == {ua.UserTokenType.UserName}
            with pytest.raises(ua.UaError):  # no None endpoint
                async with Client(url, timeout=10):
                    pass
            with pytest.raises(ua.UaError):  # anonymous is off
                async with await secure(None):
                    pass
            with pytest.raises(ua.uaerrors.BadCertificateUntrusted):  # not in the trusted directory
                async with await secure("op", stranger):
                    pass
            async with await secure("op") as c:
                idx = await c.get_namespace_index("urn:starterbus:fleet")
                assert await c.get_node(ua.NodeId("d.Identification.Model", idx)).read_value() == ua.LocalizedText(
                    "SSD1", "en"
                )

    try:
        asyncio.run(scenario())
    finally:
        sim.close()


def test_cli_serves_the_demo_fleet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from starterbus.cli.main import main

    result: list[int] = []
    argv = ["opcua", "--demo", "--endpoint", "opc.tcp://127.0.0.1:0/sb", "--anonymous", "--pki", str(tmp_path)]
    thread = threading.Thread(target=lambda: result.append(main([*argv, "--duration", "0.1"])))
    thread.start()
    thread.join(60)
    assert result == [0]
    out = capsys.readouterr().out
    assert "OPC UA: 7 devices on opc.tcp://127.0.0.1:" in out and "anonymous read-only" in out
    assert (tmp_path / "server_cert.der").is_file()
