"""Alarms & Conditions: a simulated fault raises an alarm seen by an asyncua event subscription; operators
acknowledge and confirm it, a read-only user cannot; the reset clears it; a device that stops answering is an alarm."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

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
USERS = {
    "op": UserEntry("op", Role.OPERATOR, hash_password("op-secret", iterations=1000)),
    "viewer": UserEntry("viewer", Role.READ_ONLY, hash_password("view-secret", iterations=1000)),
}
ACKNOWLEDGE = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)


class Events:
    def __init__(self) -> None:
        self.queue: asyncio.Queue[Any] = asyncio.Queue()

    def event_notification(self, event: Any) -> None:
        self.queue.put_nowait(event)

    async def next(self, **want: object) -> Any:
        """The next event whose fields (``ActiveState_Id`` for ``ActiveState/Id``) have the wanted values."""
        while True:
            event = await asyncio.wait_for(self.queue.get(), 15)
            fields = {k.replace("/", "_"): v for k, v in vars(event).items()}
            if all(fields.get(k) == v for k, v in want.items()):
                return event


def test_a_fault_is_an_alarm_acknowledged_and_confirmed_by_an_operator(tmp_path: Path) -> None:
    starter = SimulatedStarter(get_profile("jjr5000"))
    sim = ModbusRtuSimulator({1: starter}, pty=True).start()
    port = sim.client_urls()[1].split("://", 1)[1].split("?", 1)[0]
    config = parse_fleet(
        f'[poll]\nperiod = 0.1\nmax_backoff = 0.3\n[[bus]]\nname = "l"\nurl = "modbus-rtu://{port}?timeout=0.2"\n'
        '[[bus.device]]\nname = "conveyor"\nmodel = "jjr5000"\naddress = 1\nmeasurements = ["phase_a_current"]\n',
        "a.toml",
    )
    cert, key = ensure_certificate(tmp_path / "client", CLIENT_URI)
    (tmp_path / "pki" / "trusted").mkdir(parents=True)
    (tmp_path / "pki" / "trusted" / "client.der").write_bytes(cert.read_bytes())
    settings = OpcUaSettings("opc.tcp://127.0.0.1:0/sb", pki_dir=tmp_path / "pki", users=USERS)

    async def client(url: str, user: str, password: str) -> Client:
        c = Client(url, timeout=10)
        c.application_uri = CLIENT_URI
        c.set_user(user)
        c.set_password(password)
        await c.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.Sign)
        return c

    async def scenario() -> None:
        async with AsyncFleet(config) as fleet, OpcUaServer(fleet, settings) as server:
            url = server.endpoint_url
            async with await client(url, "op", "op-secret") as op, await client(url, "viewer", "view-secret") as viewer:
                idx = await op.get_namespace_index("urn:starterbus:fleet")
                fault_type = await op.nodes.base_event_type.get_child(
                    ["0:ConditionType", "0:AcknowledgeableConditionType", "0:AlarmConditionType",
                     f"{idx}:StarterFaultAlarmType"]
                )  # fmt: skip
                events = Events()
                sub = await op.create_subscription(50, events)
                await sub.subscribe_events(op.nodes.server, fault_type)
                offline_events = Events()
                offline_sub = await op.create_subscription(50, offline_events)
                await offline_sub.subscribe_events(op.nodes.server, ua.ObjectIds.AlarmConditionType)

                starter.start()
                while server.samples_served < 3 or starter.current() < 1:  # running, polled with its current
                    await asyncio.sleep(0.05)
                served = server.samples_served
                while server.samples_served < served + 2:
                    await asyncio.sleep(0.05)
                starter.inject_fault(6)
                raised = await events.next(ConditionName="FaultAlarm", ActiveState_Id=True)
                assert raised.FaultCode == 6 and raised.FaultText.Text == "motor overload"
                assert raised.Severity == 800 and raised.Retain is True and raised.SourceName == "conveyor"
                assert raised.CurrentKeys == "phase_a_current" and raised.CurrentsBeforeTrip[0] > 0
                assert getattr(raised, "AckedState/Id") is False and getattr(raised, "ConfirmedState/Id") is False

                condition = ua.NodeId("conveyor.FaultAlarm", idx)
                with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                    await viewer.get_node(condition).call_method(ACKNOWLEDGE, raised.EventId, ua.LocalizedText("no"))
                with pytest.raises(ua.uaerrors.BadEventIdUnknown):
                    await op.get_node(condition).call_method(ACKNOWLEDGE, b"stale", ua.LocalizedText("seen"))
                await op.get_node(condition).call_method(ACKNOWLEDGE, raised.EventId, ua.LocalizedText("seen"))
                acked = await events.next(AckedState_Id=True)
                assert acked.ClientUserId == "opcua:op" and acked.Comment.Text == "seen" and acked.Retain is True
                with pytest.raises(ua.uaerrors.BadConditionBranchAlreadyAcked):
                    await op.get_node(condition).call_method(ACKNOWLEDGE, acked.EventId, ua.LocalizedText("again"))
                with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                    await viewer.get_node(condition).call_method(CONFIRM, acked.EventId, ua.LocalizedText("no"))
                await op.get_node(condition).call_method(CONFIRM, acked.EventId, ua.LocalizedText("checked"))
                confirmed = await events.next(ConfirmedState_Id=True)
                assert getattr(confirmed, "ActiveState/Id") is True and confirmed.Retain is True  # still active

                starter.fault_reset()
                cleared = await events.next(ActiveState_Id=False)
                assert cleared.Retain is False  # inactive, acknowledged, confirmed: gone

                sim.close()  # the device stops answering
                offline = await offline_events.next(ConditionName="OfflineAlarm", ActiveState_Id=True)
                assert offline.SourceName == "conveyor" and offline.Severity == 600 and offline.Retain is True

    try:
        asyncio.run(scenario())
    finally:
        sim.close()
