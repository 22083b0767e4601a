"""The objects a DeviceNet slave node serves over explicit messaging (Identity, Message Router, DeviceNet,
Assembly, Connection) and the allocation of the Predefined Master/Slave Connection Set, sans-IO. The decisions
where the specification leaves room are listed in ``slave.node``'s docstring."""

from __future__ import annotations

from collections.abc import Callable

from starterbus.transports.devicenet.codec import cip
from starterbus.transports.devicenet.codec.cip import CipStatus, GeneralStatus, ObjectClass, Service
from starterbus.transports.devicenet.codec.connection import (
    BAUD_CODES,
    SUPPORTED_CHOICE,
    AllocationChoice,
    ConnectionAttribute,
    ConnectionInstance,
    ConnectionState,
    DeviceNetAttribute,
    WatchdogAction,
    assembly_path,
    describe_choice,
    round_epr,
    uint,
)
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest
from starterbus.transports.devicenet.codec.ids import (
    explicit_request_id,
    explicit_response_id,
    poll_command_id,
    poll_response_id,
)
from starterbus.transports.devicenet.slave.state import EXPLICIT_CONNECTION_SIZE, Connection, RequestRefused, SlaveState


def _const(data: bytes) -> Callable[[], bytes]:
    return lambda: data


class SlaveObjects(SlaveState):
    """The explicit-message object model of :class:`~starterbus.transports.devicenet.slave.node.SlaveNode`."""

    __slots__ = ()

    # -- objects --------------------------------------------------------------------------------------------------

    def _dispatch(self, request: ExplicitRequest, now: float) -> bytes:
        handlers: dict[int, Callable[[ExplicitRequest, float], bytes]] = {
            ObjectClass.IDENTITY: self._identity,
            ObjectClass.MESSAGE_ROUTER: self._message_router,
            ObjectClass.DEVICENET: self._devicenet,
            ObjectClass.ASSEMBLY: self._assembly,
            ObjectClass.CONNECTION: self._connection,
        }
        handler = handlers.get(request.class_id)
        if handler is None:
            raise RequestRefused(
                CipStatus(GeneralStatus.PATH_DESTINATION_UNKNOWN), f"no object class 0x{request.class_id:02X}"
            )
        return handler(request, now)

    @staticmethod
    def _unsupported(request: ExplicitRequest) -> RequestRefused:
        return RequestRefused(
            CipStatus(GeneralStatus.SERVICE_NOT_SUPPORTED), f"{cip.service_name(request.service)} not supported here"
        )

    @staticmethod
    def _no_instance(request: ExplicitRequest) -> RequestRefused:
        return RequestRefused(
            CipStatus(GeneralStatus.OBJECT_DOES_NOT_EXIST),
            f"{cip.class_name(request.class_id)} has no instance {request.instance}",
        )

    @staticmethod
    def _no_attribute(request: ExplicitRequest) -> RequestRefused:
        return RequestRefused(
            CipStatus(GeneralStatus.ATTRIBUTE_NOT_SUPPORTED),
            f"{cip.class_name(request.class_id)} instance {request.instance} has no attribute {request.attribute}",
        )

    @staticmethod
    def _no_data(request: ExplicitRequest) -> None:
        if request.data:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), f"{request.describe()} carries extra data")

    def _get(self, request: ExplicitRequest, attributes: dict[int, Callable[[], bytes]]) -> bytes:
        """Get_Attribute_Single / Set_Attribute_Single against a table of readable attributes."""
        if request.service == Service.GET_ATTRIBUTE_SINGLE:
            self._no_data(request)
            getter = attributes.get(request.attribute or 0)
            if getter is None:
                raise self._no_attribute(request)
            return getter()
        if request.service == Service.SET_ATTRIBUTE_SINGLE:
            if (request.attribute or 0) in attributes:
                raise RequestRefused(
                    CipStatus(GeneralStatus.ATTRIBUTE_NOT_SETTABLE), f"attribute {request.attribute} is read-only"
                )
            raise self._no_attribute(request)
        raise self._unsupported(request)

    def _identity(self, request: ExplicitRequest, now: float) -> bytes:
        if request.instance == 0:
            return self._get(request, {1: lambda: uint(1), 2: lambda: uint(1)})
        if request.instance != 1:
            raise self._no_instance(request)
        identity = self.current_identity()
        if request.service == Service.GET_ATTRIBUTES_ALL:
            self._no_data(request)
            return identity.attributes_all()
        if request.service == Service.RESET:
            if len(request.data) > 1:
                raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "Reset takes at most one type byte")
            if request.data and request.data[0] != 0:
                raise RequestRefused(
                    CipStatus(GeneralStatus.INVALID_PARAMETER), f"reset type {request.data[0]} is not supported"
                )
            return b""
        table = {n: _const(encoded) for n in range(1, 8) if (encoded := identity.attribute(n)) is not None}
        return self._get(request, table)

    def _message_router(self, request: ExplicitRequest, now: float) -> bytes:
        if request.instance not in (0, 1):
            raise self._no_instance(request)
        return self._get(request, {})

    def _devicenet(self, request: ExplicitRequest, now: float) -> bytes:
        if request.service in (Service.ALLOCATE, Service.RELEASE):
            if request.instance != 1:
                raise self._no_instance(request)
            if request.service == Service.ALLOCATE:
                return self._allocate(request, now)
            return self._release_request(request, now)
        if request.instance == 0:
            return self._get(request, {1: lambda: uint(2)})
        if request.instance != 1:
            raise self._no_instance(request)
        return self._get(
            request,
            {
                DeviceNetAttribute.MAC_ID: lambda: bytes((self.mac,)),
                DeviceNetAttribute.BAUD_RATE: lambda: bytes((BAUD_CODES.get(self.bitrate, 2),)),
                DeviceNetAttribute.BUS_OFF_INTERRUPT: lambda: b"\x00",
                DeviceNetAttribute.BUS_OFF_COUNTER: lambda: b"\x00",
                DeviceNetAttribute.ALLOCATION_INFORMATION: lambda: bytes((self.allocation, self.master_mac)),
            },
        )

    def _assembly(self, request: ExplicitRequest, now: float) -> bytes:
        instance = request.instance
        if instance == 0:
            return self._get(request, {1: lambda: uint(2), 2: lambda: uint(102)})
        # the instances of the configured set (the PRO type), numbered as the model numbers them
        current = self.app.assembly_set()
        inputs, outputs = self.app.instance_numbers()
        if instance == inputs:
            return self._get(request, {3: lambda: self.app.produce(current.input_instance)})
        if instance == outputs:
            return self._get(request, {3: lambda: self.app.output_data(current.output_instance)})
        raise self._no_instance(request)

    # -- allocation ---------------------------------------------------------------------------------------------

    def _check_choice(self, request: ExplicitRequest, choice: int) -> None:
        if choice == 0 or choice & AllocationChoice.RESERVED:
            raise RequestRefused(cip.INVALID_CHOICE, f"choice 0x{choice:02X} ({describe_choice(choice)})")
        unsupported = choice & ~int(SUPPORTED_CHOICE) & 0xFF
        if unsupported:
            raise RequestRefused(
                cip.UNSUPPORTED_CONNECTION,
                f"{describe_choice(unsupported)} not supported (the JJR8000 offers polled and explicit only)",
            )

    def _allocate(self, request: ExplicitRequest, now: float) -> bytes:
        if len(request.data) < 2:
            raise RequestRefused(CipStatus(GeneralStatus.NOT_ENOUGH_DATA), "Allocate needs choice and allocator MAC")
        if len(request.data) > 2:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "Allocate takes choice and allocator MAC")
        choice, allocator = request.data[0], request.data[1]
        self._check_choice(request, choice)
        if allocator > 63:
            raise RequestRefused(CipStatus(GeneralStatus.INVALID_PARAMETER), f"allocator MAC {allocator} > 63")
        if self.allocation and self.master_mac != allocator:
            raise RequestRefused(
                cip.ALLOCATED_TO_ANOTHER_MASTER, f"allocated to master {self.master_mac}, requested by {allocator}"
            )
        if choice & self.allocation:
            raise RequestRefused(
                cip.ALREADY_ALLOCATED, f"{describe_choice(choice & self.allocation)} already allocated to {allocator}"
            )
        self.allocation |= choice
        self.master_mac = allocator
        if choice & AllocationChoice.EXPLICIT:
            self.explicit = Connection(
                ConnectionInstance.EXPLICIT,
                ConnectionState.ESTABLISHED,
                round_epr(self.explicit_epr_ms, self.tick_ms),
                WatchdogAction.AUTO_DELETE,
            )
            self.explicit.restart_timer(now)
        if choice & AllocationChoice.POLLED:
            self.polled = Connection(ConnectionInstance.POLLED, ConnectionState.CONFIGURING)
            self._idle = False
        self._log(now, f"allocated {describe_choice(choice)} to master {allocator}")
        return b"\x00"  # message body format 0: DeviceNet 8/8

    def _release_request(self, request: ExplicitRequest, now: float) -> bytes:
        if not request.data:
            raise RequestRefused(CipStatus(GeneralStatus.NOT_ENOUGH_DATA), "Release needs a choice byte")
        if len(request.data) > 1:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "Release takes one choice byte")
        choice = request.data[0]
        self._check_choice(request, choice)
        if self.allocation and request.mac != self.master_mac:
            raise RequestRefused(
                cip.ALLOCATED_TO_ANOTHER_MASTER, f"allocated to master {self.master_mac}, release from {request.mac}"
            )
        if choice & ~self.allocation & 0xFF:
            raise RequestRefused(cip.NOT_ALLOCATED, f"{describe_choice(choice & ~self.allocation)} not allocated")
        self._release(choice, now, f"released by master {request.mac}")
        return b""

    # -- connection objects -------------------------------------------------------------------------------------

    def _connection(self, request: ExplicitRequest, now: float) -> bytes:
        if request.instance == 0:
            return self._get(request, {1: lambda: uint(1)})
        if request.instance == ConnectionInstance.EXPLICIT:
            conn = self.explicit
        elif request.instance == ConnectionInstance.POLLED:
            conn = self.polled
        else:
            raise self._no_instance(request)
        if conn.state is ConnectionState.NON_EXISTENT:
            raise self._no_instance(request)
        attribute = request.attribute or 0
        if request.service == Service.SET_ATTRIBUTE_SINGLE and attribute == ConnectionAttribute.EXPECTED_PACKET_RATE:
            return self._set_epr(conn, request, now)
        if request.service == Service.SET_ATTRIBUTE_SINGLE and attribute == ConnectionAttribute.WATCHDOG_TIMEOUT_ACTION:
            if len(request.data) != 1:
                status = GeneralStatus.NOT_ENOUGH_DATA if not request.data else GeneralStatus.TOO_MUCH_DATA
                raise RequestRefused(CipStatus(status), "watchdog action is one USINT")
            if request.data[0] > WatchdogAction.DEFERRED_DELETE:
                raise RequestRefused(
                    CipStatus(GeneralStatus.INVALID_ATTRIBUTE_VALUE), f"watchdog action {request.data[0]} is not 0-3"
                )
            conn.watchdog_action = WatchdogAction(request.data[0])
            return b""
        return self._get(request, self._connection_attributes(conn))

    def _set_epr(self, conn: Connection, request: ExplicitRequest, now: float) -> bytes:
        if len(request.data) < 2:
            raise RequestRefused(CipStatus(GeneralStatus.NOT_ENOUGH_DATA), "expected packet rate is a UINT")
        if len(request.data) > 2:
            raise RequestRefused(CipStatus(GeneralStatus.TOO_MUCH_DATA), "expected packet rate is a UINT")
        if conn.state is ConnectionState.TIMED_OUT:
            raise RequestRefused(
                CipStatus(GeneralStatus.OBJECT_STATE_CONFLICT), "connection timed out: release and allocate again"
            )
        requested = int.from_bytes(request.data, "little")
        conn.epr_ms = round_epr(requested, self.tick_ms)
        if conn.state is ConnectionState.CONFIGURING:
            conn.state = ConnectionState.ESTABLISHED
            self._log(now, f"polled I/O connection established, expected packet rate {conn.epr_ms} ms")
        conn.restart_timer(now)
        return uint(conn.epr_ms)

    def _connection_attributes(self, conn: Connection) -> dict[int, Callable[[], bytes]]:
        explicit = conn.instance is ConnectionInstance.EXPLICIT
        assemblies = self.app.assembly_set()
        if explicit:
            produced_id, consumed_id = explicit_response_id(self.mac), explicit_request_id(self.mac)
            sizes = (EXPLICIT_CONNECTION_SIZE, EXPLICIT_CONNECTION_SIZE)
            paths = (b"", b"")
        else:
            produced_id, consumed_id = poll_response_id(self.mac), poll_command_id(self.mac)
            sizes = (assemblies.input_size, assemblies.output_size)
            paths = (assembly_path(assemblies.input_instance), assembly_path(assemblies.output_instance))
        return {
            ConnectionAttribute.STATE: lambda: bytes((int(conn.state),)),
            ConnectionAttribute.INSTANCE_TYPE: lambda: b"\x00" if explicit else b"\x01",
            ConnectionAttribute.TRANSPORT_CLASS_TRIGGER: lambda: b"\x83" if explicit else b"\x82",
            ConnectionAttribute.PRODUCED_CONNECTION_ID: lambda: uint(produced_id),
            ConnectionAttribute.CONSUMED_CONNECTION_ID: lambda: uint(consumed_id),
            ConnectionAttribute.INITIAL_COMM_CHARACTERISTICS: lambda: b"\x21" if explicit else b"\x01",
            ConnectionAttribute.PRODUCED_CONNECTION_SIZE: lambda: uint(sizes[0]),
            ConnectionAttribute.CONSUMED_CONNECTION_SIZE: lambda: uint(sizes[1]),
            ConnectionAttribute.EXPECTED_PACKET_RATE: lambda: uint(conn.epr_ms),
            ConnectionAttribute.WATCHDOG_TIMEOUT_ACTION: lambda: bytes((int(conn.watchdog_action),)),
            ConnectionAttribute.PRODUCED_CONNECTION_PATH_LENGTH: lambda: uint(len(paths[0])),
            ConnectionAttribute.PRODUCED_CONNECTION_PATH: lambda: paths[0],
            ConnectionAttribute.CONSUMED_CONNECTION_PATH_LENGTH: lambda: uint(len(paths[1])),
            ConnectionAttribute.CONSUMED_CONNECTION_PATH: lambda: paths[1],
            ConnectionAttribute.PRODUCTION_INHIBIT_TIME: lambda: uint(0),
        }
