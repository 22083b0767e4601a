"""The CANopen master for one device: SDO for parameters and measurements, TPDO1 for the status, RPDO1 for
commands, a master heartbeat, NMT start on open (built on canopen's RemoteNode).

Status reads use the latest TPDO1 when it is fresh (no older than ``max_age``) and provably later than the last
command: after a command, the status comes over SDO (answered after the device processed the RPDO, frames being
in order on the bus) and only TPDOs received after that SDO answer count again. SDO transfers to one node are
serialised; after an SDO timeout the next transfer waits one timeout so that a late reply is flushed, never
paired with the next request (the library also sends abort 0x05040000 on timeout).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from typing import Any

import can
import canopen

from starterbus.core import (
    Capability,
    Command,
    ControlWordState,
    DecodeError,
    DeviceUrl,
    NotOpenError,
    PointDef,
    Profile,
    Reading,
    RemoteDeviceError,
    Status,
    TimeoutError,
    Transport,
    TransportError,
    Value,
    check_peer,
    decode_status_word,
)
from starterbus_canopen.bus import BUSES, CanBus, Member
from starterbus_canopen.codes import RPDO1_BASE, TPDO1_BASE, Tpdo1, abort_meaning, encode_rpdo1
from starterbus_canopen.od import PdoLayout, build_od
from starterbus_canopen.settings import PLUGIN_NAME
from starterbus_canopen.url import CanopenUrl

NMT_START = 0x01
#: what a master whose virtual channel has no peer in this process should use instead
VIRTUAL_HINT = (
    "across processes, use a bus every process can open, e.g. Linux virtual CAN (ip link add dev vcan0 type vcan; "
    "ip link set up vcan0): starterbus simulate ... --canopen socketcan:vcan0 and canopen://socketcan/vcan0?node=N"
)


class SdoGate:
    """SDO transfers to one node of one bus, from every transport of this process: one at a time, and after a
    timeout the next transfer waits one timeout (whichever transport makes it) so that a late reply is dropped."""

    __slots__ = ("lock", "quiet_until")

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.quiet_until = 0.0


_gates_guard = threading.Lock()
_gates: dict[tuple[str, str, int], SdoGate] = {}


def sdo_gate(interface: str, channel: str, node: int) -> SdoGate:
    with _gates_guard:
        return _gates.setdefault((interface, channel, node), SdoGate())


def sdo_download_frame(node: int, index: int, subindex: int, raw: int) -> str:
    data = bytes([0x2B, index & 0xFF, index >> 8, subindex]) + raw.to_bytes(2, "little") + b"\0\0"
    return f"{0x600 + node:03X}#{data.hex().upper()}"


class CanopenTransport(Transport):
    name = PLUGIN_NAME
    run_needs_connection = True  # the device drops the run command when the master's heartbeat stops

    def __init__(self, url: DeviceUrl, profile: Profile) -> None:
        super().__init__(url, profile)
        self.options = CanopenUrl.parse(url, profile)
        self.layout = PdoLayout.of(profile)
        self._od = build_od(profile, self.options.node)
        self._bus: CanBus | None = None
        self._member: Member | None = None
        self._node: canopen.RemoteNode | None = None
        self._tasks: list[Any] = []
        self._rpdo_task: Any = None
        self._control = ControlWordState()
        self._gate = sdo_gate(self.options.interface, self.options.channel, self.options.node)
        self._tpdo: tuple[Tpdo1, float] | None = None
        self._tpdo_valid_after = 0.0
        self.bad_tpdos = 0

    # -- lifecycle -------------------------------------------------------------------------------------------

    def describe(self) -> str:
        return f"{self.url.text} (node {self.options.node})"

    def _open(self) -> None:
        o = self.options
        check_peer(o.interface, o.channel, VIRTUAL_HINT)
        key = (o.interface, o.channel)
        try:
            bus = BUSES.acquire(key, lambda: CanBus(o.interface, o.channel, o.bitrate))
        except TransportError as exc:
            raise TransportError(f"{self.describe()}: {exc}") from exc
        step = "join the bus (master heartbeat)"
        try:
            bus.check_bitrate(o.bitrate, self.url.text)
            member = Member(o.node, o.master, o.heartbeat, ((TPDO1_BASE + o.node, self._on_tpdo),))
            node = bus.join(member, lambda: canopen.RemoteNode(o.node, self._od), self.url.text)
            try:
                step = "NMT start"
                node.nmt.send_command(NMT_START)
            except BaseException:
                bus.leave(member)
                raise
        except BaseException as exc:
            BUSES.release(key)
            if isinstance(exc, can.CanError):
                raise TransportError(f"{self.describe()}: {step}: {exc}") from exc
            raise
        self._bus, self._member, self._node = bus, member, node
        self._tpdo_valid_after = time.monotonic()

    def _close(self) -> None:
        bus, member, self._bus, self._member, self._node = self._bus, self._member, None, None, None
        for task in self._tasks:
            task.stop()
        self._tasks.clear()
        self._rpdo_task = None
        if bus is not None and member is not None:
            bus.leave(member)
            BUSES.release((self.options.interface, self.options.channel))

    @property
    def bus(self) -> CanBus:
        """The CAN bus this device shares with every other CANopen device of this process on it."""
        if self._bus is None:
            raise NotOpenError(f"{self.describe()}: the transport is not open")
        return self._bus

    def _require(self) -> tuple[canopen.Network, canopen.RemoteNode]:
        if self._bus is None or self._node is None:
            raise NotOpenError(f"{self.describe()}: the transport is not open")
        return self._bus.network, self._node

    @property
    def capabilities(self) -> frozenset[Capability]:
        return frozenset(Capability)

    # -- SDO -------------------------------------------------------------------------------------------------

    def _address(self, point: PointDef, what: str) -> tuple[int, int]:
        where = point.addresses.get(PLUGIN_NAME)
        if where is None:
            raise self.unsupported(what, f"{point.key} has no canopen address in {self.profile.display_name}")
        return int(where[0]), int(where[1])

    def _sdo(self, what: str, call: Any, *args: Any) -> Any:
        _, node = self._require()
        gate = self._gate
        with gate.lock:
            wait = gate.quiet_until - time.monotonic()
            if wait > 0:
                time.sleep(wait)  # let a late reply of a timed-out transfer arrive, then drop it
            if not node.sdo.responses.empty():
                node.sdo.responses = type(node.sdo.responses)()
            node.sdo.RESPONSE_TIMEOUT = self.options.timeout  # the node may be shared with another transport
            node.sdo.MAX_RETRIES = 1
            try:
                return call(*args)
            except canopen.SdoAbortedError as exc:
                code = int(exc.code)
                raise RemoteDeviceError("CANopen SDO", code, abort_meaning(code), detail=what) from None
            except canopen.SdoCommunicationError as exc:
                gate.quiet_until = time.monotonic() + self.options.timeout
                if "No SDO response" in str(exc):
                    raise TimeoutError(
                        f"{self.describe()}: {what}: no SDO answer in {self.options.timeout:g} s"
                    ) from None
                raise TransportError(f"{self.describe()}: {what}: {exc}") from None
            except can.CanError as exc:
                raise TransportError(f"{self.describe()}: {what}: {exc}") from None

    def _upload_u(self, index: int, subindex: int, size: int, what: str) -> int:
        _, node = self._require()
        data = self._sdo(f"read {what} at 0x{index:04X}:{subindex:02X}", node.sdo.upload, index, subindex)
        if len(data) != size:
            raise DecodeError(
                f"{what}: {len(data)} bytes, expected {size}", bytes(data), f"0x{index:04X}:{subindex:02X}"
            )
        return int.from_bytes(data, "little")

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        out = []
        for point in points:
            index, subindex = self._address(point, f"read {point.key}")
            out.append(Reading(point, self._upload_u(index, subindex, 2, point.key)))
        return out

    def _write_parameter(self, point: PointDef, raw: int) -> None:
        index, subindex = self._address(point, f"write {point.key}")
        _, node = self._require()
        what = f"write {point.key} = {raw} at 0x{index:04X}:{subindex:02X}"
        self._sdo(what, node.sdo.download, index, subindex, raw.to_bytes(2, "little"))

    def _identify(self) -> dict[str, object]:
        return {
            "device_type": f"0x{self._upload_u(0x1000, 0, 4, 'device type'):08X}",
            "vendor_id": f"0x{self._upload_u(0x1018, 1, 4, 'vendor-ID'):08X}",
            "product_code": self._upload_u(0x1018, 2, 4, "product code"),
            "revision": f"0x{self._upload_u(0x1018, 3, 4, 'revision number'):08X}",
            "serial_number": self._upload_u(0x1018, 4, 4, "serial number"),
            "node": self.options.node,
        }

    # -- PDO -------------------------------------------------------------------------------------------------

    def _on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        try:
            sample = Tpdo1.decode(bytes(data))
        except DecodeError:  # a malformed TPDO never yields a value
            self.bad_tpdos += 1
            return
        self._tpdo = (sample, time.monotonic())

    def _fresh_tpdo(self) -> Tpdo1 | None:
        latest = self._tpdo
        if latest is None:
            return None
        sample, at = latest
        if at <= self._tpdo_valid_after or time.monotonic() - at > self.options.max_age:
            return None
        return sample

    def _read_status(self) -> Status:
        self._require()
        layout = self.layout
        sample = self._fresh_tpdo()
        if sample is not None:
            word, current, source = sample.status_word, sample.current_raw, "canopen TPDO1"
        else:
            index, subindex = self._address(layout.status_word, "read the status")
            word = self._upload_u(index, subindex, 2, layout.status_word.key)
            current = None
            if layout.current is not None:
                index, subindex = self._address(layout.current, "read the status")
                current = self._upload_u(index, subindex, 2, layout.current.key)
            source = "canopen SDO"
            self._tpdo_valid_after = time.monotonic()
        currents = {}
        if layout.current is not None and current is not None:
            currents["a"] = Value.from_raw(layout.current, current, source=source)
        return decode_status_word(
            word,
            self.profile.faults,
            bit12_is_mains_voltage=self.profile.control.bit12_is_mains_voltage,
            currents=currents,
            source=source,
        )

    def _rpdo_frames(self, command: Command) -> list[int]:
        state = ControlWordState(self._control.bus_control, self._control.run)
        return state.apply(command)

    def _send_command(self, command: Command) -> None:
        network, _ = self._require()
        words = self._control.apply(command)
        cob = RPDO1_BASE + self.options.node
        self._tpdo_valid_after = math.inf
        try:
            for word in words:
                network.send_message(cob, encode_rpdo1(word))
            data = encode_rpdo1(words[-1])
            if self._rpdo_task is None:
                self._rpdo_task = network.send_periodic(cob, data, self.options.cycle)
                self._tasks.append(self._rpdo_task)
            else:
                self._rpdo_task.update(data)
        except can.CanError as exc:
            raise TransportError(f"{self.describe()}: send {command.value}: {exc}") from None

    # -- dry runs --------------------------------------------------------------------------------------------

    def _preview_write(self, point: PointDef, raw: int) -> list[str]:
        index, subindex = self._address(point, f"write {point.key}")
        frame = sdo_download_frame(self.options.node, index, subindex, raw)
        return [f"{frame}  SDO expedited download 0x{index:04X}:{subindex:02X} = {raw} ({point.key})"]

    def _preview_command(self, command: Command) -> list[str]:
        cob = RPDO1_BASE + self.options.node
        words = self._rpdo_frames(command)
        return [
            f"{cob:03X}#{encode_rpdo1(w).hex().upper()}  RPDO1 control word 0x{w:04X}"
            + (f", then repeated every {self.options.cycle:g} s while open" if i == len(words) - 1 else "")
            for i, w in enumerate(words)
        ]
