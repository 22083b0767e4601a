"""The fleet's address space: Objects/StarterBus/<line>/<device>, with status, measurements, parameters, methods.

Node ids are strings in the fleet namespace, stable across restarts: ``s=conveyor``, ``s=conveyor.Status.State``,
``s=conveyor.Measurements.phase_a_current``, ``s=conveyor.Parameters.current_limit``, ``s=conveyor.Start``.
Building happens once before the server starts; :mod:`starterbus.opcua.values` fills the variables.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from asyncua import Node, Server, ua
from asyncua.common.structures104 import new_enum

from starterbus.core.model import PointDef
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.status import Command, MotorState
from starterbus.fleet.config import DeviceConfig, FleetConfig
from starterbus.opcua.units import eu_information

#: StarterStateEnum values (the enumeration's order is part of the interface: do not reorder)
STATES: tuple[MotorState, ...] = (
    MotorState.UNKNOWN,
    MotorState.STOPPED,
    MotorState.READY,
    MotorState.STARTING,
    MotorState.RUNNING,
    MotorState.STOPPING,
    MotorState.FAULT,
)
#: the EnumStrings of StarterStateEnum: each state's one name (MotorState), capitalised as OPC UA enum fields are
STATE_ENUM_STRINGS: tuple[str, ...] = tuple(s.value.capitalize() for s in STATES)


class DeviceHealth(enum.IntEnum):
    """OPC 10000-100 (DI) DeviceHealthEnumeration, mirrored in our namespace."""

    NORMAL = 0
    FAILURE = 1
    CHECK_FUNCTION = 2
    OFF_SPEC = 3
    MAINTENANCE_REQUIRED = 4


METHODS: dict[str, Command] = {"Start": Command.START, "Stop": Command.SOFT_STOP, "Reset": Command.FAULT_RESET}
STATUS_VARIABLES = ("State", "Fault", "FaultCode", "FaultText", "Ready", "BusControl")

ANALOG_ITEM_TYPE = ua.NodeId(ua.ObjectIds.AnalogItemType)
MULTISTATE_VALUE_DISCRETE_TYPE = ua.NodeId(ua.ObjectIds.MultiStateValueDiscreteType)
BASE_DATA_VARIABLE_TYPE = ua.NodeId(ua.ObjectIds.BaseDataVariableType)
PROPERTY_TYPE = ua.NodeId(ua.ObjectIds.PropertyType)


def texts(en: str, zh: str, locale: str) -> tuple[ua.LocalizedText, ua.LocalizedText]:
    """(DisplayName, Description): the chosen language as display name, the other as description."""
    english = ua.LocalizedText(en, "en")
    chinese = ua.LocalizedText(zh or en, "zh-CN" if zh else "en")
    return (chinese, english) if locale == "zh" else (english, chinese)


@dataclass(slots=True)
class PointNode:
    point: PointDef
    node: ua.NodeId
    value_as_text: ua.NodeId | None = None  # enums: the label of the current value


@dataclass(slots=True)
class DeviceNodes:
    config: DeviceConfig
    profile: Profile
    node: ua.NodeId
    status: dict[str, ua.NodeId]  # State, Fault, ..., Online, LastError, DeviceHealth, LastOperation
    points: dict[str, PointNode] = field(default_factory=dict)
    methods: dict[ua.NodeId, Command] = field(default_factory=dict)


@dataclass(slots=True)
class FleetNodes:
    namespace_index: int
    root: ua.NodeId
    devices: dict[str, DeviceNodes]
    parameters: dict[ua.NodeId, tuple[DeviceNodes, PointNode]]  # writable parameter node -> device, point


MethodHandler = Callable[[DeviceNodes, Command], Any]


class _Builder:
    def __init__(self, server: Server, idx: int, locale: str) -> None:
        self.server = server
        self.idx = idx
        self.locale = locale
        self.session = server.iserver.isession

    def nid(self, text: str) -> ua.NodeId:
        return ua.NodeId(text, self.idx)

    async def variable(
        self,
        parent: ua.NodeId,
        nodeid: ua.NodeId,
        name: str,
        value: ua.Variant,
        datatype: ua.NodeId,
        *,
        display: tuple[ua.LocalizedText, ua.LocalizedText] | None = None,
        typedef: ua.NodeId = BASE_DATA_VARIABLE_TYPE,
        writable: bool = False,
        prop: bool = False,
    ) -> ua.NodeId:
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = nodeid
        item.BrowseName = ua.QualifiedName(name, 0 if prop else self.idx)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasProperty if prop else ua.ObjectIds.HasComponent)
        item.TypeDefinition = PROPERTY_TYPE if prop else typedef
        attrs = ua.VariableAttributes()
        attrs.DisplayName, attrs.Description = display or (ua.LocalizedText(name), ua.LocalizedText(name))
        attrs.DataType = datatype
        attrs.Value = value
        if isinstance(value.Value, list):
            attrs.ValueRank = ua.ValueRank.OneDimension
            attrs.ArrayDimensions = [0]
        else:
            attrs.ValueRank = ua.ValueRank.Scalar
        level = ua.AccessLevel.CurrentRead.mask | (ua.AccessLevel.CurrentWrite.mask if writable else 0)
        attrs.AccessLevel = attrs.UserAccessLevel = level
        attrs.WriteMask = attrs.UserWriteMask = 0
        item.NodeAttributes = attrs
        (result,) = await self.session.add_nodes([item])
        result.StatusCode.check()
        return result.AddedNodeId

    async def enum_type(self, name: str, labels: Sequence[str]) -> ua.NodeId:
        node = await new_enum(self.server, self.idx, name, list(labels))
        strings = [ua.LocalizedText(label, "en") for label in labels]
        await self.variable(
            node.nodeid,
            self.nid(f"{name}.EnumStrings"),
            "EnumStrings",
            ua.Variant(strings, ua.VariantType.LocalizedText),
            ua.NodeId(ua.ObjectIds.LocalizedText),
            prop=True,
        )
        return node.nodeid

    async def point(self, parent: ua.NodeId, device: str, group: str, point: PointDef, writable: bool) -> PointNode:
        nodeid = self.nid(f"{device}.{group}.{point.key}")
        display = texts(point.name_en, point.name_zh, self.locale)
        if point.enum is not None:
            node = await self.variable(
                parent, nodeid, point.key, ua.Variant(0, ua.VariantType.UInt16), ua.NodeId(ua.ObjectIds.UInt16),
                display=display, typedef=MULTISTATE_VALUE_DISCRETE_TYPE, writable=writable,
            )  # fmt: skip
            values = []
            for raw, label in sorted(point.enum.labels.items()):
                name, description = texts(label.en, label.zh, self.locale)
                values.append(ua.EnumValueType(Value=raw, DisplayName=name, Description=description))
            await self.variable(
                node, self.nid(f"{nodeid.Identifier}.EnumValues"), "EnumValues",
                ua.Variant(values, ua.VariantType.ExtensionObject), ua.NodeId(ua.ObjectIds.EnumValueType), prop=True,
            )  # fmt: skip
            text = await self.variable(
                node, self.nid(f"{nodeid.Identifier}.ValueAsText"), "ValueAsText",
                ua.Variant(ua.LocalizedText(""), ua.VariantType.LocalizedText), ua.NodeId(ua.ObjectIds.LocalizedText),
                prop=True,
            )  # fmt: skip
            return PointNode(point, node, text)
        if point.bits:
            node = await self.variable(
                parent, nodeid, point.key, ua.Variant(0, ua.VariantType.UInt16), ua.NodeId(ua.ObjectIds.UInt16),
                display=display, writable=writable,
            )  # fmt: skip
            return PointNode(point, node)
        node = await self.variable(
            parent, nodeid, point.key, ua.Variant(0.0, ua.VariantType.Double), ua.NodeId(ua.ObjectIds.Double),
            display=display, typedef=ANALOG_ITEM_TYPE, writable=writable,
        )  # fmt: skip
        low, high = sorted((float(point.to_engineering(point.raw_min)), float(point.to_engineering(point.raw_max))))
        await self.variable(
            node, self.nid(f"{nodeid.Identifier}.EURange"), "EURange",
            ua.Variant(ua.Range(Low=low, High=high), ua.VariantType.ExtensionObject), ua.NodeId(ua.ObjectIds.Range),
            prop=True,
        )  # fmt: skip
        units = eu_information(point.unit)
        if units is not None:
            await self.variable(
                node, self.nid(f"{nodeid.Identifier}.EngineeringUnits"), "EngineeringUnits",
                ua.Variant(units, ua.VariantType.ExtensionObject), ua.NodeId(ua.ObjectIds.EUInformation), prop=True,
            )  # fmt: skip
        return PointNode(point, node)


async def build_fleet(
    server: Server, idx: int, fleet: FleetConfig, on_method: MethodHandler, *, locale: str = "en"
) -> FleetNodes:
    """Add the types and one object per device; ``on_method(device, command)`` serves Start/Stop/Reset."""
    b = _Builder(server, idx, locale)
    state_type = await b.enum_type("StarterStateEnum", list(STATE_ENUM_STRINGS))
    health_type = await b.enum_type("DeviceHealthEnumeration", [h.name for h in DeviceHealth])
    starter_type = await server.nodes.base_object_type.add_object_type(b.nid("SoftStarterType"), "SoftStarterType")
    objects: Node = server.nodes.objects
    root = await objects.add_folder(b.nid("StarterBus"), ua.QualifiedName("StarterBus", idx))
    devices: dict[str, DeviceNodes] = {}
    parameters: dict[ua.NodeId, tuple[DeviceNodes, PointNode]] = {}
    for bus in fleet.buses:
        line = await root.add_folder(b.nid(f"bus:{bus.name}"), ua.QualifiedName(bus.name, idx))
        for config in bus.devices:
            nodes = await _build_device(b, line, config, starter_type.nodeid, state_type, health_type)
            for command_name, command in METHODS.items():
                method = await _add_method(b, nodes, command_name, command, on_method)
                nodes.methods[method] = command
            devices[config.name] = nodes
            for point_node in nodes.points.values():
                if config.remote.allows_write(point_node.point.key):
                    parameters[point_node.node] = (nodes, point_node)
    return FleetNodes(idx, root.nodeid, devices, parameters)


async def _build_device(
    b: _Builder, line: Node, config: DeviceConfig, starter_type: ua.NodeId, state: ua.NodeId, health: ua.NodeId
) -> DeviceNodes:
    name = config.name
    profile = get_profile(config.model)
    obj = await line.add_object(b.nid(name), ua.QualifiedName(name, b.idx), starter_type)
    device = DeviceNodes(config, profile, obj.nodeid, {})
    ident = await obj.add_object(b.nid(f"{name}.Identification"), ua.QualifiedName("Identification", b.idx))
    for key, value, vtype in (
        ("Manufacturer", ua.LocalizedText(profile.vendor, "en"), ua.VariantType.LocalizedText),
        ("Model", ua.LocalizedText(profile.display_name, "en"), ua.VariantType.LocalizedText),
        ("ProductCode", profile.name, ua.VariantType.String),
        ("Line", config.bus, ua.VariantType.String),
        ("Address", -1 if config.address is None else config.address, ua.VariantType.Int32),
    ):
        await b.variable(
            ident.nodeid, b.nid(f"{name}.Identification.{key}"), key, ua.Variant(value, vtype),
            ua.NodeId(vtype.value), prop=True,
        )  # fmt: skip
    # OPC 40400-1 PtSoftStarterAttributesType, mirrored: only what the profile proves (see docs/opcua.md)
    attributes = await obj.add_object(
        b.nid(f"{name}.PtSoftStarterAttributes"), ua.QualifiedName("PtSoftStarterAttributes", b.idx)
    )
    overload = any(label.en == "motor overload" for label in profile.faults.labels.values())
    await b.variable(
        attributes.nodeid, b.nid(f"{name}.PtSoftStarterAttributes.MotorOverloadProtectionIntegrated"),
        "MotorOverloadProtectionIntegrated", ua.Variant(overload, ua.VariantType.Boolean),
        _dt(ua.VariantType.Boolean), prop=True,
    )  # fmt: skip
    device.status["DeviceHealth"] = await b.variable(
        obj.nodeid, b.nid(f"{name}.DeviceHealth"), "DeviceHealth", ua.Variant(0, ua.VariantType.Int32), health
    )
    status = await obj.add_object(b.nid(f"{name}.Status"), ua.QualifiedName("Status", b.idx))
    boolean, string = _dt(ua.VariantType.Boolean), _dt(ua.VariantType.String)
    specs: list[tuple[str, ua.Variant, ua.NodeId, str]] = [
        ("State", ua.Variant(0, ua.VariantType.Int32), state, "电机状态"),
        ("Fault", ua.Variant(False, ua.VariantType.Boolean), boolean, "故障"),
        ("FaultCode", ua.Variant(0, ua.VariantType.UInt16), _dt(ua.VariantType.UInt16), "故障代码"),
        ("FaultText", ua.Variant(ua.LocalizedText(""), ua.VariantType.LocalizedText),
         _dt(ua.VariantType.LocalizedText), "故障说明"),
        ("Ready", ua.Variant(False, ua.VariantType.Boolean), boolean, "起动准备好"),
        ("BusControl", ua.Variant(False, ua.VariantType.Boolean), boolean, "总线控制"),
        ("Online", ua.Variant(False, ua.VariantType.Boolean), boolean, "在线"),
        ("LastError", ua.Variant("", ua.VariantType.String), string, "最近一次轮询的错误"),
        ("LastOperation", ua.Variant("", ua.VariantType.String), string, "最近一次远程操作的结果"),
    ]  # fmt: skip
    for key, value, datatype, zh in specs:
        device.status[key] = await b.variable(
            status.nodeid, b.nid(f"{name}.Status.{key}"), key, value, datatype, display=texts(key, zh, b.locale)
        )
    for group, keys in (("Measurements", config.measurements), ("Parameters", config.parameters)):
        folder = await obj.add_object(b.nid(f"{name}.{group}"), ua.QualifiedName(group, b.idx))
        for key in keys:
            point = profile.point(key)
            writable = group == "Parameters" and config.remote.allows_write(point.key)
            device.points[point.key] = await b.point(folder.nodeid, name, group, point, writable)
    return device


def _dt(vtype: ua.VariantType) -> ua.NodeId:
    return ua.NodeId(vtype.value)


async def _add_method(
    b: _Builder, device: DeviceNodes, name: str, command: Command, on_method: MethodHandler
) -> ua.NodeId:
    async def call(parent: ua.NodeId) -> Any:
        return await on_method(device, command)

    out = ua.Argument(
        Name="StateReached",
        DataType=ua.NodeId(ua.ObjectIds.String),
        ValueRank=ua.ValueRank.Scalar,
        Description=ua.LocalizedText("the state the device reached, read back from it", "en"),
    )
    allowed = device.config.remote.allows_command(command)
    node = await Node(b.session, device.node).add_method(
        b.nid(f"{device.config.name}.{name}"), ua.QualifiedName(name, b.idx), call, [], [out]
    )
    # Executable tells clients up front what the fleet file enables; asyncua does not enforce it, we do
    for attr in (ua.AttributeIds.Executable, ua.AttributeIds.UserExecutable):
        await b.server.write_attribute_value(node.nodeid, ua.DataValue(ua.Variant(allowed)), attr)
    return node.nodeid
