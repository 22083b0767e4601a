"""A CANopen front end serving shared simulated starters, built on canopen's LocalNode.

Per node: SDO read/write callbacks map the OD's application objects to the starter's points (a refusal becomes
the matching SDO abort); RPDO1 -> ``write_control_word(cyclic=True)``; TPDO1 (status word, phase A current) sent
on change and by its event timer, only in OPERATIONAL; heartbeat producer (0x1017); a heartbeat consumer
watchdog for the master (0x1016:01, which the library lacks): once the master's heartbeat has been seen, its
loss drops the run command it held (soft stop), sends EMCY 0x8130 with error register bit 4 and applies 0x1029
(0: pre-operational, 1: no change, 2: stopped). A heartbeat seen again resets the EMCY.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import can
import canopen

from starterbus.core import (
    ConfigurationError,
    DecodeError,
    PointDef,
    RunningSimulator,
    SimulatedStarter,
    SimulatorRefusal,
)
from starterbus_canopen.codes import (
    EMCY_HEARTBEAT,
    ER_COMMUNICATION,
    ER_GENERIC,
    REFUSAL_ABORTS,
    RPDO1_BASE,
    TPDO1_BASE,
    Tpdo1,
    decode_rpdo1,
)
from starterbus_canopen.od import MASTER_NODE_DEFAULT, PdoLayout, address, build_od
from starterbus_canopen.settings import PLUGIN_NAME

ABORT_GENERAL = 0x08000000
ABORT_LENGTH = 0x06070010


@dataclass
class _Served:
    starter: SimulatedStarter
    node_id: int
    local: Any  # canopen.LocalNode
    points: dict[tuple[int, int], PointDef]
    layout: PdoLayout
    last_tpdo: bytes = b""
    last_tpdo_at: float = 0.0
    master_seen_at: float | None = None
    master_lost: bool = False
    error_register: int = 0
    emcys: list[int] = field(default_factory=list)


class CanopenSimulator(RunningSimulator):
    """Serve starters as CANopen nodes on one python-can bus: ``add_node`` each, then ``start``."""

    def __init__(
        self,
        bus: tuple[str, str],
        *,
        bitrate: int | None = None,
        heartbeat_ms: int = 1000,
        consumer_ms: int = 1000,
        master: int = MASTER_NODE_DEFAULT,
        event_timer: float = 0.1,
        tick: float = 0.005,
    ) -> None:
        self.interface, self.channel = bus
        self.bitrate = bitrate
        self.heartbeat_ms, self.consumer_ms, self.master = heartbeat_ms, consumer_ms, master
        self.event_timer, self.tick = event_timer, tick
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05
        self.nodes: dict[int, _Served] = {}
        self.lock = threading.RLock()  # held while a TPDO is built and sent, and while an RPDO is applied
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def add_node(self, starter: SimulatedStarter, node_id: int) -> None:
        if not 1 <= node_id <= 127 or node_id == self.master or node_id in self.nodes:
            raise ConfigurationError(f"CANopen node id {node_id} is not 1..127, is the master's, or is taken")
        profile = starter.profile
        if not profile.supports(PLUGIN_NAME):
            raise ConfigurationError(f"{profile.display_name} has no CANopen interface")
        od = build_od(profile, node_id, self.master, self.consumer_ms, self.heartbeat_ms)
        points = {address(p): p for p in profile.points.values() if PLUGIN_NAME in p.addresses}
        served = _Served(starter, node_id, canopen.LocalNode(node_id, od), points, PdoLayout.of(profile))
        self.nodes[node_id] = served
        if self._thread is not None:  # already serving: wire the node at once
            self._wire(served)

    def start(self) -> CanopenSimulator:
        kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate:
            kwargs["bitrate"] = self.bitrate
        self.network.connect(**kwargs)
        for served in self.nodes.values():
            self._wire(served)
        self.network.subscribe(0x700 + self.master, self._on_master_heartbeat)
        self._thread = threading.Thread(target=self._run, name="canopen-simulator", daemon=True)
        self._thread.start()
        return self

    def __enter__(self) -> CanopenSimulator:
        return self.start()

    def __exit__(self, *_: object) -> None:
        self.close()

    def _wire(self, served: _Served) -> None:
        local = served.local
        self.network.add_node(local)

        def on_read(index: int, subindex: int, od: object) -> int | None:
            return self._read(served, index, subindex)

        def on_write(index: int, subindex: int, od: object, data: bytes) -> None:
            self._write(served, index, subindex, bytes(data))

        local.add_read_callback(on_read)
        local.add_write_callback(on_write)
        self.network.subscribe(RPDO1_BASE + served.node_id, lambda _id, data, _ts: self._on_rpdo(served, data))
        local.nmt.send_command(0x81)  # reset node: boot-up message
        local.nmt.send_command(0x80)  # pre-operational: heartbeat from 0x1017 starts

    # -- SDO ---------------------------------------------------------------------------------------------------

    def _read(self, served: _Served, index: int, subindex: int) -> int | None:
        if index == 0x1001 and subindex == 0:
            return served.error_register
        point = served.points.get((index, subindex))
        if point is None:
            return None
        with self.lock:
            try:
                return served.starter.read(point)
            except SimulatorRefusal as exc:
                raise canopen.SdoAbortedError(REFUSAL_ABORTS.get(exc.reason, ABORT_GENERAL)) from None

    def _write(self, served: _Served, index: int, subindex: int, data: bytes) -> None:
        point = served.points.get((index, subindex))
        if point is None:
            return  # communication objects: the library stores them (0x1017 restarts the heartbeat)
        if len(data) != 2:
            raise canopen.SdoAbortedError(ABORT_LENGTH)
        try:
            served.starter.write(point, int.from_bytes(data, "little"))
        except SimulatorRefusal as exc:
            raise canopen.SdoAbortedError(REFUSAL_ABORTS.get(exc.reason, ABORT_GENERAL)) from None

    # -- PDO, heartbeat consumer -------------------------------------------------------------------------------

    def _on_rpdo(self, served: _Served, data: bytearray) -> None:
        if served.local.nmt.state != "OPERATIONAL":
            return
        try:
            word = decode_rpdo1(bytes(data))
        except DecodeError:  # wrong length: CiA 301 says EMCY 0x8210, the word is not applied
            served.local.emcy.send(0x8210, served.error_register | ER_GENERIC)
            return
        with self.lock:
            served.starter.write_control_word(word, cyclic=True, source=f"CANopen RPDO1 node {served.node_id}")

    def _on_master_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = time.monotonic()
        for served in self.nodes.values():
            served.master_seen_at = now

    def _consumer(self, served: _Served) -> tuple[int, float]:
        raw = int.from_bytes(served.local.get_data(0x1016, 1), "little")
        return (raw >> 16) & 0x7F, (raw & 0xFFFF) / 1000.0

    def _watch(self, served: _Served, now: float) -> None:
        master, limit = self._consumer(served)
        seen = served.master_seen_at
        if master != self.master or limit <= 0 or seen is None:
            return
        if now - seen <= limit:
            if served.master_lost:
                served.master_lost = False
                served.error_register &= ~(ER_COMMUNICATION | ER_GENERIC)
                served.local.emcy.reset(served.error_register)
                served.emcys.append(0)
            return
        if served.master_lost:
            return
        served.master_lost = True
        served.error_register |= ER_COMMUNICATION | ER_GENERIC
        with self.lock:
            served.starter.command_lost("CANopen master heartbeat lost")
        served.local.emcy.send(EMCY_HEARTBEAT, served.error_register)
        served.emcys.append(EMCY_HEARTBEAT)
        behaviour = int.from_bytes(served.local.get_data(0x1029, 0), "little")
        if behaviour == 0 and served.local.nmt.state == "OPERATIONAL":
            served.local.nmt.state = "PRE-OPERATIONAL"
        elif behaviour == 2:
            served.local.nmt.state = "STOPPED"

    def _tpdo(self, served: _Served, now: float) -> None:
        if served.local.nmt.state != "OPERATIONAL":
            served.last_tpdo = b""
            return
        starter, layout = served.starter, served.layout
        with self.lock:
            current = starter.read(layout.current) if layout.current is not None else 0
            data = Tpdo1(starter.status_word(), current).encode()
            if data != served.last_tpdo or now - served.last_tpdo_at >= self.event_timer:
                self.network.send_message(TPDO1_BASE + served.node_id, data)
                served.last_tpdo, served.last_tpdo_at = data, now

    def _run(self) -> None:
        while not self._stop.wait(self.tick):
            now = time.monotonic()
            for served in list(self.nodes.values()):
                try:
                    self._watch(served, now)
                    self._tpdo(served, now)
                except (can.CanError, OSError, canopen.SdoAbortedError):  # a bus error: the next tick retries
                    continue

    # -- RunningSimulator --------------------------------------------------------------------------------------

    def describe(self) -> list[str]:
        return [
            f"canopen: {self.interface}/{self.channel} node {n} (connect with {url})"
            for n, url in self.client_urls().items()
        ]

    def client_urls(self) -> dict[int, str]:
        return {n: f"canopen://{self.interface}/{self.channel}?node={n}" for n in self.nodes}

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        for served in self.nodes.values():
            served.local.nmt.stop_heartbeat()
        self.network.disconnect()
