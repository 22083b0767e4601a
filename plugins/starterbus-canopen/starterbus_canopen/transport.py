"""The CANopen master for one device: SDO for parameters and measurements, TPDO1 for the status, RPDO1 for
commands, a master heartbeat, NMT start on open.

The device's node is an :class:`~starterbus_canopen.sdo.SdoEngine` on the process's CAN driver of its bus
(:mod:`starterbus_canopen.bus`), run by the process's scheduler: no thread of its own. Every SDO transfer is a
ticket; the heartbeat and the RPDO1 cycle are periodic outputs of the driver. While the device is open the
scheduler's own thread runs (``keep_running``): the heartbeat and the cycle go on, and each TPDO1 is stamped when
it arrives, whether or not a caller waits. A fleet's poll is an :class:`~starterbus_canopen.poll.SdoPoll`.

Status reads use the latest TPDO1 when it is fresh (no older than ``max_age``) and provably later than the last
command: after a command, the status comes over SDO (answered after the device processed the RPDO, frames being
in order on the bus) and only TPDOs received after that SDO answer count again. SDO transfers to one node are
serialised by its engine; after an SDO timeout the engine aborts the transfer (0x05040000) and sends the node
nothing for one timeout, dropping what it answers meanwhile, so a late reply is never paired with the next request.
"""

from __future__ import annotations

import math
import time
from collections.abc import Generator, Sequence
from typing import Any

from starterbus.core import (
    CanFrame,
    Capability,
    Command,
    ControlWordState,
    DecodeError,
    DeviceUrl,
    NotOpenError,
    PointDef,
    PollResult,
    PollTask,
    Profile,
    Reading,
    Status,
    Transport,
    TransportError,
    Value,
    check_peer,
    decode_status_word,
    keep_running,
    let_go,
)
from starterbus_canopen.bus import BUSES, CanBus, Member
from starterbus_canopen.codes import RPDO1_BASE, Tpdo1, encode_rpdo1
from starterbus_canopen.od import PdoLayout
from starterbus_canopen.poll import SdoPoll, Steps, drive
from starterbus_canopen.sdo import Download, SdoEngine, SdoRequest, Upload
from starterbus_canopen.settings import PLUGIN_NAME
from starterbus_canopen.url import CanopenUrl

NMT_START = 0x01
CAPABILITIES = frozenset(Capability)  # every one (made once: the template asks on every call)
#: what a master whose virtual channel has no peer in this process should use instead
VIRTUAL_HINT = (
    "across processes, use a bus every process can open, e.g. Linux virtual CAN (ip link add dev vcan0 type vcan; "
    "ip link set up vcan0): starterbus simulate ... --canopen socketcan:vcan0 and canopen://socketcan/vcan0?node=N"
)


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
        self._bus: CanBus | None = None
        self._member: Member | None = None
        self._engine: SdoEngine | None = None
        self._rpdo: Any = None  # the RPDO1 cycle (a periodic output of the bus's driver), once a command was sent
        self._control = ControlWordState()
        self._tpdo_valid_after = 0.0
        self._uploads: dict[tuple[int, int, str], Upload] = {}  # the requests made so far (immutable: sent again)

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
        try:
            bus.check_bitrate(o.bitrate, self.url.text)
            member = Member(o.node, o.master, o.heartbeat)
            engine = bus.join(member, self.url.text)
            try:
                bus.send([CanFrame(0x000, bytes([NMT_START, o.node]))], f"{self.describe()}: NMT start")
            except BaseException:
                bus.leave(member)
                raise
        except BaseException:
            BUSES.release(key)
            raise
        keep_running(bus.loop)  # the heartbeat, the RPDO1 cycle and TPDO1 times, whether or not a caller waits
        self._bus, self._member, self._engine = bus, member, engine
        self._tpdo_valid_after = time.monotonic()

    def _close(self) -> None:
        bus, member, rpdo = self._bus, self._member, self._rpdo
        self._bus, self._member, self._engine, self._rpdo = None, None, None, None
        if bus is None or member is None:
            return
        try:
            if rpdo is not None:
                bus.call(lambda now: rpdo.stop(), "stop the RPDO1 cycle")
            bus.leave(member)
        finally:
            BUSES.release((self.options.interface, self.options.channel))
            let_go(bus.loop)

    @property
    def bus(self) -> CanBus:
        """The CAN bus this device shares with every other CANopen device of this process on it."""
        if self._bus is None:
            raise NotOpenError(f"{self.describe()}: the transport is not open")
        return self._bus

    @property
    def engine(self) -> SdoEngine:
        """The SDO client of the device's node (shared with every device of this process for that node)."""
        return self._require()[1]

    @property
    def bad_tpdos(self) -> int:
        """Malformed TPDO1s of the node dropped so far."""
        return self.engine.bad_tpdos

    def _require(self) -> tuple[CanBus, SdoEngine]:
        if self._bus is None or self._engine is None:
            raise NotOpenError(f"{self.describe()}: the transport is not open")
        return self._bus, self._engine

    def _drive(self, steps: Steps[Any]) -> Any:
        bus, engine = self._require()
        return drive(bus, engine, steps)

    @property
    def capabilities(self) -> frozenset[Capability]:
        return CAPABILITIES

    # -- SDO -------------------------------------------------------------------------------------------------

    def _address(self, point: PointDef, what: str) -> tuple[int, int]:
        where = point.addresses.get(PLUGIN_NAME)
        if where is None:
            raise self.unsupported(what, f"{point.key} has no canopen address in {self.profile.display_name}")
        return int(where[0]), int(where[1])

    def _upload_u(self, index: int, subindex: int, size: int, what: str) -> Generator[SdoRequest, bytes, int]:
        request = self._uploads.get((index, subindex, what))
        if request is None:
            text = f"{self.describe()}: read {what} at 0x{index:04X}:{subindex:02X}"
            request = self._uploads[(index, subindex, what)] = Upload(index, subindex, self.options.timeout, text)
        data = yield request
        if len(data) != size:
            where = f"0x{index:04X}:{subindex:02X}"
            raise DecodeError(f"{what}: {len(data)} bytes, expected {size}", bytes(data), where)
        return int.from_bytes(data, "little")

    def _points_steps(self, points: Sequence[PointDef]) -> Generator[SdoRequest, bytes, list[Reading]]:
        out = []
        for point in points:
            index, subindex = self._address(point, f"read {point.key}")
            out.append(Reading(point, (yield from self._upload_u(index, subindex, 2, point.key))))
        return out

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        result: list[Reading] = self._drive(self._points_steps(points))
        return result

    def _write_parameter(self, point: PointDef, raw: int) -> None:
        index, subindex = self._address(point, f"write {point.key}")
        what = f"{self.describe()}: write {point.key} = {raw} at 0x{index:04X}:{subindex:02X}"
        request = Download(index, subindex, raw.to_bytes(2, "little"), self.options.timeout, what)

        def steps() -> Generator[SdoRequest, bytes, None]:
            yield request

        self._drive(steps())

    def _identify_steps(self) -> Generator[SdoRequest, bytes, dict[str, object]]:
        device_type = yield from self._upload_u(0x1000, 0, 4, "device type")
        vendor = yield from self._upload_u(0x1018, 1, 4, "vendor-ID")
        product = yield from self._upload_u(0x1018, 2, 4, "product code")
        revision = yield from self._upload_u(0x1018, 3, 4, "revision number")
        serial = yield from self._upload_u(0x1018, 4, 4, "serial number")
        return {
            "device_type": f"0x{device_type:08X}",
            "vendor_id": f"0x{vendor:08X}",
            "product_code": product,
            "revision": f"0x{revision:08X}",
            "serial_number": serial,
            "node": self.options.node,
        }

    def _identify(self) -> dict[str, object]:
        result: dict[str, object] = self._drive(self._identify_steps())
        return result

    # -- PDO -------------------------------------------------------------------------------------------------

    def _fresh_tpdo(self) -> Tpdo1 | None:
        latest = self.engine.tpdo
        if latest is None:
            return None
        sample, at = latest
        if at <= self._tpdo_valid_after or time.monotonic() - at > self.options.max_age:
            return None
        return sample

    def _status_steps(self) -> Generator[SdoRequest, bytes, Status]:
        layout = self.layout
        sample = self._fresh_tpdo()
        if sample is not None:
            word, current, source = sample.status_word, sample.current_raw, "canopen TPDO1"
        else:
            index, subindex = self._address(layout.status_word, "read the status")
            word = yield from self._upload_u(index, subindex, 2, layout.status_word.key)
            current = None
            if layout.current is not None:
                index, subindex = self._address(layout.current, "read the status")
                current = yield from self._upload_u(index, subindex, 2, layout.current.key)
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

    def _read_status(self) -> Status:
        status: Status = self._drive(self._status_steps())
        return status

    # -- the fleet's poll without blocking -------------------------------------------------------------------

    def _poll_steps(self, points: Sequence[PointDef], status: bool) -> Generator[SdoRequest, bytes, PollResult]:
        value = (yield from self._status_steps()) if status else None
        readings = (yield from self._points_steps(points)) if points else []
        return PollResult(value, readings)

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        result: PollResult = self._drive(self._poll_steps(points, status))
        return result

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        bus, engine = self._require()
        return SdoPoll(bus, engine, self._poll_steps(points, status))

    # -- commands --------------------------------------------------------------------------------------------

    def _rpdo_frames(self, command: Command) -> list[int]:
        state = ControlWordState(self._control.bus_control, self._control.run)
        return state.apply(command)

    def _send_command(self, command: Command) -> None:
        bus, _ = self._require()
        words = self._control.apply(command)
        cob = RPDO1_BASE + self.options.node
        self._tpdo_valid_after = math.inf
        what = f"{self.describe()}: send {command.value}"
        bus.send([CanFrame(cob, encode_rpdo1(word)) for word in words], what)
        frame = CanFrame(cob, encode_rpdo1(words[-1]))
        rpdo = self._rpdo
        if rpdo is None:
            self._rpdo = bus.periodic(frame, self.options.cycle, f"{what}: start the RPDO1 cycle")
        else:
            bus.call(lambda now: rpdo.modify(frame), f"{what}: the RPDO1 cycle")

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
