"""The OPC UA server against asyncua's own client: browse, read, subscribe, methods, writes, roles, security.

One server (and one simulated Modbus fleet on two pseudo-terminals) is shared by the module: asyncua takes
about a second to start. It runs on an event loop in a thread; each test submits its client coroutine there.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import Any

import pytest
from asyncua import Node, ua

from starterbus.core.registry import get_profile
from starterbus.opcua.address_space import STATES
from starterbus.tests.opcua.server_rig import NS, Rig, audit, client, ns_node, running_rig, secure_client, wait_value


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("opcua")) as running:
        yield running


# -- browse and read ----------------------------------------------------------------------------------------


def test_browse_lines_devices_and_read_measurements_with_units(rig: Rig) -> None:
    async def scenario() -> None:
        async with client(rig) as c:  # anonymous, read-only: allowed in this rig
            idx = await c.get_namespace_index(NS)
            root = await c.nodes.objects.get_child([f"{idx}:StarterBus"])
            lines = {(await n.read_browse_name()).Name: n for n in await root.get_children()}
            assert sorted(lines) == ["line-1", "line-2"]
            devices = [(await n.read_browse_name()).Name for n in await lines["line-1"].get_children()]
            assert devices == ["conveyor", "fan", "crusher"]
            conveyor = await ns_node(c, "conveyor")
            children = {(await n.read_browse_name()).Name for n in await conveyor.get_children()}
            assert {"Status", "Measurements", "Parameters", "Identification", "Start", "Stop", "Reset"} <= children
            protection = await ns_node(c, "conveyor.PtSoftStarterAttributes.MotorOverloadProtectionIntegrated")
            assert await protection.read_value() is True

            current = await ns_node(c, "conveyor.Measurements.phase_a_current")
            value = await wait_value(current, lambda v: v.StatusCode is not None and v.StatusCode.is_good())
            assert value.Value is not None and value.Value.VariantType is ua.VariantType.Double
            assert value.SourceTimestamp is not None
            assert abs((datetime.now(timezone.utc) - value.SourceTimestamp).total_seconds()) < 60
            assert (await current.read_display_name()).Text == "phase A current"
            assert (await current.read_description()).Locale == "zh-CN"
            assert await current.read_type_definition() == ua.NodeId(ua.ObjectIds.AnalogItemType)
            units = await (await current.get_child("0:EngineeringUnits")).read_value()
            assert (units.UnitId, units.DisplayName.Text) == (4279632, "A")  # UNECE AMP

            limit = await ns_node(c, "conveyor.Parameters.current_limit")
            eu_range = await (await limit.get_child("0:EURange")).read_value()
            point = get_profile("jjr5000").point("current_limit")
            assert (eu_range.Low, eu_range.High) == (
                point.to_engineering(point.raw_min),
                point.to_engineering(point.raw_max),
            )
            limit_value = await wait_value(limit, lambda v: v.StatusCode is not None and v.StatusCode.is_good())
            assert limit_value.Value is not None
            assert limit_value.Value.Value == point.to_engineering(rig.starters["conveyor"].params["current_limit"])

            analog = await ns_node(c, "conveyor.Parameters.start_mode")
            labels = await (await analog.get_child("0:EnumValues")).read_value()
            enum = get_profile("jjr5000").point("start_mode").enum
            assert enum is not None
            assert [(e.Value, e.DisplayName.Text) for e in labels] == [
                (k, v.en) for k, v in sorted(enum.labels.items())
            ]
            shown = await wait_value(
                await analog.get_child("0:ValueAsText"),
                lambda v: v.Value is not None and v.Value.Value is not None and bool(v.Value.Value.Text),
            )
            assert shown.Value is not None and shown.Value.Value.Text in {v.en for v in enum.labels.values()}

            state = await ns_node(c, "fan.Status.State")
            state_value = await wait_value(state, lambda v: v.StatusCode is not None and v.StatusCode.is_good())
            assert state_value.Value is not None
            assert STATES[state_value.Value.Value].value == "ready"
            enum_type = c.get_node(await state.read_data_type())
            assert (await enum_type.read_browse_name()).Name == "StarterStateEnum"
            assert await (await ns_node(c, "fan.Status.Online")).read_value() is True

    rig.run(scenario)


def test_offline_device_reads_bad_communication_not_a_stale_value(rig: Rig) -> None:
    async def scenario() -> None:
        async with client(rig) as c:
            online = await ns_node(c, "ghost.Status.Online")
            await wait_value(
                online, lambda v: v.Value is not None and v.Value.Value is False and v.StatusCode.is_good()
            )
            for text in ("ghost.Status.State", "ghost.Status.FaultCode", "ghost.Measurements.phase_a_current"):
                value = await (await ns_node(c, text)).read_data_value(raise_on_bad_status=False)
                assert value.StatusCode is not None
                assert value.StatusCode.value == ua.StatusCodes.BadCommunicationError, text
                assert value.Value is None or value.Value.Value is None
            assert await (await ns_node(c, "ghost.Status.LastError")).read_value() != ""

    rig.run(scenario)


# -- subscriptions ------------------------------------------------------------------------------------------


class Changes:
    def __init__(self) -> None:
        self.queue: asyncio.Queue[ua.DataValue] = asyncio.Queue()

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        self.queue.put_nowait(data.monitored_item.Value)


def test_subscription_sees_the_current_change_poll_by_poll(rig: Rig) -> None:
    pump = rig.starters["pump"]

    async def scenario() -> None:
        async with client(rig, "viewer", "view-secret") as c:
            handler = Changes()
            sub = await c.create_subscription(50, handler)
            await sub.subscribe_data_change(await ns_node(c, "pump.Measurements.phase_a_current"))
            first = await asyncio.wait_for(handler.queue.get(), 10)  # the current value, at once
            assert first.Value is not None
            pump.params["ramp_time"] = 60  # the current rises over 0.75 s: several polls, on a loaded machine too
            pump.start()  # on the simulator itself: the ramp makes the current rise poll after poll
            seen: list[ua.DataValue] = []

            def good(v: ua.DataValue) -> bool:
                return v.StatusCode is None or v.StatusCode.is_good()

            while len({v.Value.Value for v in seen if good(v) and v.Value is not None}) < 3:
                seen.append(await asyncio.wait_for(handler.queue.get(), 10))
            stamps = [v.SourceTimestamp for v in seen]
            assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
            # a poll that failed (line-2's 0.05 s timeout on a loaded machine) is a Bad value with none given
            assert all(good(v) or v.Value is None or v.Value.Value is None for v in seen), seen
            await sub.delete()

    rig.run(scenario)


# -- methods and writes -------------------------------------------------------------------------------------


def test_operator_starts_and_stops_over_sign_and_encrypt_audited_as_opcua_user(rig: Rig) -> None:
    conveyor = rig.starters["conveyor"]

    async def scenario() -> None:
        c = await secure_client(rig, ua.MessageSecurityMode.SignAndEncrypt, "op", "op-secret")
        async with c:
            device = await ns_node(c, "conveyor")
            idx = device.nodeid.NamespaceIndex
            reached = await device.call_method(f"{idx}:Start")
            assert reached in {"starting", "running"}
            assert conveyor.phase.value in {"starting", "running"}
            assert await device.call_method(f"{idx}:Stop") in {"stopping", "ready", "stopped"}
            last = await (await ns_node(c, "conveyor.Status.LastOperation")).read_value()
            assert last.startswith("opcua:op stop: ok")

            fan = await ns_node(c, "fan")  # the fleet file enables nothing for the fan
            with pytest.raises(ua.uaerrors.BadNotExecutable):
                await fan.call_method(f"{idx}:Start")
            reason = await (await ns_node(c, "fan.Status.LastOperation")).read_value()
            assert "does not allow the command 'start'" in reason
            executable = await (await fan.get_child(f"{idx}:Start")).read_attribute(ua.AttributeIds.Executable)
            assert executable.Value is not None and executable.Value.Value is False

    rig.run(scenario)
    assert rig.starters["fan"].phase.value != "starting"
    entries = [(e["actor"], e["command"], e["result"]) for e in audit(rig) if e.get("command")]
    assert ("opcua:op", "start", "ok") in entries and ("opcua:op", "stop", "ok") in entries


def test_writes_only_after_read_back_and_refusals_as_status_codes(rig: Rig) -> None:
    conveyor = rig.starters["conveyor"]
    point = get_profile("jjr5000").point("current_limit")
    target = next(
        point.to_engineering(raw)
        for raw in range(point.raw_min, point.raw_max + 1)
        if raw != conveyor.params["current_limit"]
    )

    async def scenario() -> None:
        c = await secure_client(rig, ua.MessageSecurityMode.Sign, "op", "op-secret")
        async with c:
            limit = await ns_node(c, "conveyor.Parameters.current_limit")
            await limit.write_value(ua.DataValue(ua.Variant(float(target), ua.VariantType.Double)))
            assert await limit.read_value() == target  # the read-back, at once
            with pytest.raises(ua.uaerrors.BadOutOfRange):
                await limit.write_value(ua.DataValue(ua.Variant(99999.0, ua.VariantType.Double)))
            assert await limit.read_value() == target
            reason = await (await ns_node(c, "conveyor.Status.LastOperation")).read_value()
            assert "out of range" in reason
            for text in ("conveyor.Parameters.ramp_time", "conveyor.Measurements.phase_a_current"):
                with pytest.raises(ua.uaerrors.BadNotWritable):
                    await (await ns_node(c, text)).write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))

    rig.run(scenario)
    assert point.to_engineering(conveyor.params["current_limit"]) == target
    writes = [(e["actor"], e["key"], e["result"]) for e in audit(rig) if e.get("key")]
    assert writes[-1] == ("opcua:op", "current_limit", "ok")


def test_parameter_locked_while_running_is_refused_with_bad_invalid_state(rig: Rig) -> None:
    crusher = rig.starters["crusher"]
    before = dict(crusher.params)
    crusher.start()  # on the simulator: JJR8000 locks ramp_time while the motor runs

    async def scenario() -> None:
        c = await secure_client(rig, ua.MessageSecurityMode.SignAndEncrypt, "op", "op-secret")
        async with c:
            state = await ns_node(c, "crusher.Status.State")
            running = {"starting", "running"}

            def is_running(v: ua.DataValue) -> bool:  # Null until the first poll of the crusher gave a status
                return v.Value is not None and v.Value.Value is not None and STATES[v.Value.Value].value in running

            await wait_value(state, is_running)
            ramp = await ns_node(c, "crusher.Parameters.ramp_time")
            with pytest.raises(ua.uaerrors.BadInvalidState):
                await ramp.write_value(ua.DataValue(ua.Variant(20.0, ua.VariantType.Double)))
            reason = await (await ns_node(c, "crusher.Status.LastOperation")).read_value()
            assert "stop the motor first; nothing sent" in reason

    try:
        rig.run(scenario)
    finally:
        crusher.soft_stop()
    assert crusher.params == before


@pytest.mark.parametrize("who", ["anonymous", "viewer"])
def test_anonymous_and_read_only_users_cannot_call_or_write(rig: Rig, who: str) -> None:
    conveyor = rig.starters["conveyor"]
    before = dict(conveyor.params), conveyor.phase
    entries = len(audit(rig))

    async def scenario() -> None:
        c = client(rig) if who == "anonymous" else client(rig, "viewer", "view-secret")
        async with c:
            device = await ns_node(c, "conveyor")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await device.call_method(f"{device.nodeid.NamespaceIndex}:Start")
            limit = await ns_node(c, "conveyor.Parameters.current_limit")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await limit.write_value(ua.DataValue(ua.Variant(400.0, ua.VariantType.Double)))

    rig.run(scenario)
    assert (dict(conveyor.params), conveyor.phase) == before
    assert len(audit(rig)) == entries


def test_wrong_password_is_refused(rig: Rig) -> None:
    async def scenario() -> None:
        with pytest.raises(ua.uaerrors.BadUserAccessDenied):
            async with client(rig, "op", "wrong"):
                pass

    rig.run(scenario)
