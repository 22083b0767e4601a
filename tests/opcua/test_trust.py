"""Client certificates trusted on purpose: unknown ones refused and saved to rejected/, trusted by a move or the CLI;
the server certificate's names; the Aes policies."""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import socket
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import (
    SecurityPolicyAes128Sha256RsaOaep,
    SecurityPolicyAes256Sha256RsaPss,
    SecurityPolicyBasic256Sha256,
)
from cryptography import x509

from starterbus.aio import AsyncFleet
from starterbus.cli.main import main
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import FleetConfig, parse_fleet
from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.server import OpcUaServer, OpcUaSettings
from starterbus.opcua.trust import thumbprint
from starterbus.opcua.users import Role, UserEntry, hash_password
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

CLIENT_URI = "urn:starterbus:test-client"
USERS = {"op": UserEntry("op", Role.OPERATOR, hash_password("op-secret", iterations=1000))}


@pytest.fixture
def config() -> object:
    sim = ModbusRtuSimulator({1: SimulatedStarter(get_profile("ssd1"))}, pty=True).start()
    port = sim.client_urls()[1].split("://", 1)[1].split("?", 1)[0]
    yield parse_fleet(
        f'[[bus]]\nname = "l"\nurl = "modbus-rtu://{port}"\n[[bus.device]]\nname = "d"\nmodel = "ssd1"\naddress = 1\n',
        "s.toml",
    )
    sim.close()


async def connect(url: str, pair: tuple[Path, Path], policy: type = SecurityPolicyBasic256Sha256) -> str:
    c = Client(url, timeout=10)
    c.application_uri = CLIENT_URI
    c.set_user("op")
    c.set_password("op-secret")
    await c.set_security(policy, str(pair[0]), str(pair[1]), mode=ua.MessageSecurityMode.SignAndEncrypt)
    async with c:
        idx = await c.get_namespace_index("urn:starterbus:fleet")
        return str(await c.get_node(ua.NodeId("d.Identification.ProductCode", idx)).read_value())


def test_unknown_clients_are_refused_saved_and_trusted_by_a_move_or_the_cli(
    tmp_path: Path, config: FleetConfig, capsys: pytest.CaptureFixture[str]
) -> None:
    pki = tmp_path / "pki"
    first = ensure_certificate(tmp_path / "first", CLIENT_URI)
    second = ensure_certificate(tmp_path / "second", CLIENT_URI)
    settings = OpcUaSettings("opc.tcp://127.0.0.1:0/sb", pki_dir=pki, users=USERS)

    async def scenario() -> None:
        async with AsyncFleet(config) as fleet, OpcUaServer(fleet, settings) as server:
            url = server.endpoint_url
            with pytest.raises(ua.uaerrors.BadCertificateUntrusted):
                await connect(url, first)
            cert = x509.load_der_x509_certificate(first[0].read_bytes())
            saved = pki / "rejected" / f"starterbus-OPC-UA-server_{thumbprint(cert)}.der"
            assert saved.read_bytes() == first[0].read_bytes()
            saved.rename(pki / "trusted" / saved.name)  # what an administrator does; no restart
            assert await connect(url, first, SecurityPolicyAes256Sha256RsaPss) == "ssd1"

            with pytest.raises(ua.uaerrors.BadCertificateUntrusted):
                await connect(url, second)
            capsys.readouterr()
            assert main(["opcua-trust", "--pki", str(pki), "--json"]) == 0
            listing = json.loads(capsys.readouterr().out)
            (refused,) = listing["rejected"]
            assert refused["uri"] == CLIENT_URI and [c["file"] for c in listing["trusted"]] == [saved.name]
            assert main(["opcua-trust", "--pki", str(pki), refused["thumbprint"][:12]]) == 0
            assert "trusted " in capsys.readouterr().out
            assert not any((pki / "rejected").iterdir())
            assert await connect(url, second, SecurityPolicyAes128Sha256RsaOaep) == "ssd1"

    asyncio.run(scenario())
    server_cert = x509.load_der_x509_certificate((pki / "server_cert.der").read_bytes())
    names = server_cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert {socket.gethostname(), socket.getfqdn(), "localhost"} <= set(names.get_values_for_type(x509.DNSName))
    assert ipaddress.ip_address("127.0.0.1") in names.get_values_for_type(x509.IPAddress)  # the endpoint's


def test_trust_any_client_is_an_explicit_logged_opt_in(
    tmp_path: Path, config: FleetConfig, caplog: pytest.LogCaptureFixture
) -> None:
    stranger = ensure_certificate(tmp_path / "stranger", CLIENT_URI)
    settings = OpcUaSettings("opc.tcp://127.0.0.1:0/sb", pki_dir=tmp_path / "pki", users=USERS, trust_any_client=True)
    caplog.set_level(logging.WARNING, logger="starterbus.opcua")

    async def scenario() -> None:
        async with AsyncFleet(config) as fleet, OpcUaServer(fleet, settings) as server:
            assert await connect(server.endpoint_url, stranger) == "ssd1"

    asyncio.run(scenario())
    assert any("any client certificate is accepted" in r.getMessage() for r in caplog.records)
    assert not (tmp_path / "pki" / "rejected").exists()


def test_opcua_trust_names_what_it_cannot_find(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "rejected").mkdir()
    assert main(["opcua-trust", "--pki", str(tmp_path), "nothing.der"]) == 1
    assert "no rejected certificate 'nothing.der' (rejected: none)" in capsys.readouterr().err
    assert main(["opcua-trust", "--pki", str(tmp_path)]) == 0
    assert "rejected: 0 certificates" in capsys.readouterr().out
