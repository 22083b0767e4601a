"""The object dictionary of a device, built from its profile: one OD for the client (RemoteNode) and the
simulator (LocalNode), so the two cannot disagree about the device.

Communication objects follow CiA 301 (certain). Application objects are the profile's points, each at its
``canopen = [index, subindex]`` address as UNSIGNED16 (the design of this plugin; CiA 442's indices are not
public). PDO set 1 (design, in the spirit of CiA 442): TPDO1 = status word + phase A current, RPDO1 = control word.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen import objectdictionary as odm

from starterbus.core import ConfigurationError, PointDef, Profile
from starterbus_canopen.codes import RPDO1_BASE, TPDO1_BASE
from starterbus_canopen.settings import PLUGIN_NAME, CanopenSettings

MASTER_NODE_DEFAULT = 0x7F


@dataclass(frozen=True, slots=True)
class PdoLayout:
    """Which points PDO set 1 carries (from the profile's roles)."""

    control_word: PointDef
    status_word: PointDef
    current: PointDef | None

    @classmethod
    def of(cls, profile: Profile) -> PdoLayout:
        control, status = profile.role("control_word"), profile.role("status_word")
        if (
            control is None
            or status is None
            or PLUGIN_NAME not in control.addresses
            or (PLUGIN_NAME not in status.addresses)
        ):
            raise ConfigurationError(
                f"{profile.display_name}: the canopen transport needs the roles control_word and status_word "
                "with canopen addresses (RPDO1 and TPDO1 carry them)"
            )
        currents = [profile.point(k) for k in profile.roles.get("phase_currents", ())]
        current = next((p for p in currents if PLUGIN_NAME in p.addresses), None)
        return cls(control, status, current)


def address(point: PointDef) -> tuple[int, int]:
    where = point.addresses.get(PLUGIN_NAME)
    if where is None:
        raise ConfigurationError(f"{point.key} has no canopen address")
    index, subindex = where
    return int(index), int(subindex)


def _var(name: str, index: int, subindex: int, data_type: int, access: str, default: int) -> odm.ODVariable:
    var = odm.ODVariable(name, index, subindex)
    var.data_type = data_type
    var.access_type = access
    var.default = default
    return var


def _record(name: str, index: int, members: list[tuple[str, int, str, int]]) -> odm.ODRecord:
    record = odm.ODRecord(name, index)
    record.add_member(_var("highest sub-index supported", index, 0, odm.UNSIGNED8, "const", len(members)))
    for sub, (member, data_type, access, default) in enumerate(members, start=1):
        record.add_member(_var(member, index, sub, data_type, access, default))
    return record


def build_od(
    profile: Profile,
    node_id: int,
    master_node: int = MASTER_NODE_DEFAULT,
    consumer_ms: int = 1000,
    producer_ms: int = 0,
) -> odm.ObjectDictionary:
    """The device's object dictionary (heartbeat times as the simulator serves them by default)."""
    settings = CanopenSettings.of(profile)
    layout = PdoLayout.of(profile)
    od = odm.ObjectDictionary()  # type: ignore[no-untyped-call]
    od.node_id = node_id
    od.add_object(_var("device type", 0x1000, 0, odm.UNSIGNED32, "ro", settings.device_type))
    od.add_object(_var("error register", 0x1001, 0, odm.UNSIGNED8, "ro", 0))
    consumer = odm.ODArray("consumer heartbeat time", 0x1016)
    consumer.add_member(_var("highest sub-index supported", 0x1016, 0, odm.UNSIGNED8, "const", 1))
    consumer.add_member(
        _var("consumer heartbeat time 1", 0x1016, 1, odm.UNSIGNED32, "rw", (master_node << 16) | consumer_ms)
    )
    od.add_object(consumer)
    od.add_object(_var("producer heartbeat time", 0x1017, 0, odm.UNSIGNED16, "rw", producer_ms))
    ident = settings.identity
    od.add_object(
        _record(
            "identity object",
            0x1018,
            [
                ("vendor-ID", odm.UNSIGNED32, "ro", ident.vendor_id),
                ("product code", odm.UNSIGNED32, "ro", ident.product_code),
                ("revision number", odm.UNSIGNED32, "ro", ident.revision),
                ("serial number", odm.UNSIGNED32, "ro", ident.serial_number),
            ],
        )
    )
    od.add_object(_var("error behaviour: communication error", 0x1029, 0, odm.UNSIGNED8, "rw", 0))
    od.add_object(
        _record(
            "RPDO1 communication parameter",
            0x1400,
            [("COB-ID", odm.UNSIGNED32, "ro", RPDO1_BASE + node_id), ("transmission type", odm.UNSIGNED8, "ro", 254)],
        )
    )
    od.add_object(
        _record("RPDO1 mapping", 0x1600, [("mapped object 1", odm.UNSIGNED32, "ro", _mapping(layout.control_word))])
    )
    tpdo = [("mapped object 1", odm.UNSIGNED32, "ro", _mapping(layout.status_word))]
    if layout.current is not None:
        tpdo.append(("mapped object 2", odm.UNSIGNED32, "ro", _mapping(layout.current)))
    od.add_object(
        _record(
            "TPDO1 communication parameter",
            0x1800,
            [("COB-ID", odm.UNSIGNED32, "ro", TPDO1_BASE + node_id), ("transmission type", odm.UNSIGNED8, "ro", 254)],
        )
    )
    od.add_object(_record("TPDO1 mapping", 0x1A00, tpdo))
    _add_points(od, profile)
    return od


def _mapping(point: PointDef) -> int:
    index, subindex = address(point)
    return (index << 16) | (subindex << 8) | 16


def _add_points(od: odm.ObjectDictionary, profile: Profile) -> None:
    by_index: dict[int, list[tuple[int, PointDef]]] = {}
    for point in profile.points.values():
        if PLUGIN_NAME in point.addresses:
            index, subindex = address(point)
            by_index.setdefault(index, []).append((subindex, point))
    for index, members in sorted(by_index.items()):
        if len(members) == 1 and members[0][0] == 0:
            point = members[0][1]
            od.add_object(_var(point.key, index, 0, odm.UNSIGNED16, "rw" if point.writable else "ro", 0))
            continue
        record = odm.ODRecord(f"object 0x{index:04X}", index)
        highest = max(sub for sub, _ in members)
        record.add_member(_var("highest sub-index supported", index, 0, odm.UNSIGNED8, "const", highest))
        for sub, point in members:
            if sub == 0:
                raise ConfigurationError(f"{point.key}: canopen subindex 0 of 0x{index:04X} is taken by the record")
            record.add_member(_var(point.key, index, sub, odm.UNSIGNED16, "rw" if point.writable else "ro", 0))
        od.add_object(record)
