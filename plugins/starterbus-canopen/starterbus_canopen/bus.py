"""One CAN bus per process for every CANopen device on it: the process's CAN driver of the bus, one SDO engine per
node, one master heartbeat per master node id.

Devices on one bus (a fleet's ``[[bus]]``, or several ``open_device`` calls naming the same interface and
channel) share a :class:`CanBus` from :data:`BUSES`. It holds a lease of the process's
:class:`~starterbus.core.CanDriver` of that bus (one python-can bus per interface and channel, shared with any
other protocol on it: interfaces such as PCAN or slcan cannot be opened twice), run by the process's scheduler;
one :class:`~starterbus_canopen.sdo.SdoEngine` per node id, so that two devices for one node share its SDO
transfers (one at a time, one quiet period) and its TPDO1; one heartbeat per master node id, a periodic output of
the driver (the interface's own cyclic send where it has one, else the driver's deadlines), not one per device.
The last device to leave gives the driver back.

What must be the same for every device on the bus (the bit rate; a master's heartbeat period) is checked when a
device joins: a difference is a :class:`~starterbus.core.ConfigurationError` naming both, and the device does
not join.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import can

from starterbus.core import (
    CanDriver,
    CanFrame,
    ConfigurationError,
    Periodic,
    SharedPool,
    process_scheduler,
)
from starterbus_canopen.sdo import SdoEngine

HEARTBEAT_OPERATIONAL = 0x05
HEARTBEAT_BASE = 0x700

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Member:
    """What one device asked of the bus when it joined (given back to :meth:`CanBus.leave`)."""

    node: int
    master: int
    heartbeat: float  # s; 0: the device asked for none


def _filters(engine: SdoEngine) -> list[can.typechecking.CanFilter]:
    return [{"can_id": can_id, "can_mask": 0x7FF} for can_id in sorted(engine.wanted)]


class CanBus:
    """One interface/channel of this process, shared by every CANopen device on it. Thread-safe: the bookkeeping
    under a lock, everything touching the bus in the scheduler's loop."""

    def __init__(self, interface: str, channel: str, bitrate: int | None) -> None:
        self.interface, self.channel, self.bitrate = interface, channel, bitrate
        self.loop = process_scheduler()
        # any failure: TransportError naming interface and channel
        self.driver = CanDriver.acquire(interface, channel, self.loop, bitrate)
        self._lock = threading.Lock()
        self._nodes: dict[int, tuple[SdoEngine, int]] = {}  # node id -> (engine, devices using it)
        self._heartbeats: dict[int, tuple[float, Periodic, int]] = {}  # master id -> (period, task, devices)
        self.closed = False
        self.sdo_what = f"{self.name}: SDO"  #: a stalled SDO wait's error begins so

    @property
    def name(self) -> str:
        return f"{self.interface}/{self.channel}"

    def call(self, fn: Callable[[float], T], what: str) -> T:
        """Run ``fn(now)`` in the scheduler's loop and wait for it."""
        return self.driver.call(fn, what)

    def heartbeats(self) -> dict[int, float]:
        """Master node id -> the period of the heartbeat this process sends for it on the bus, s."""
        with self._lock:
            return {master: period for master, (period, _, _) in self._heartbeats.items()}

    def users(self, node: int) -> int:
        """How many devices of this process use ``node`` (0: the bus knows no such node)."""
        with self._lock:
            entry = self._nodes.get(node)
            return entry[1] if entry else 0

    def check_bitrate(self, bitrate: int | None, who: str) -> None:
        if bitrate != self.bitrate:

            def text(rate: int | None) -> str:
                return f"{rate} bit/s" if rate else "the interface's default bit rate"

            raise ConfigurationError(
                f"{who}: CAN bus {self.name} is already open in this process at {text(self.bitrate)}; this device "
                f"asks for {text(bitrate)}: one bus has one bit rate"
            )

    def join(self, member: Member, who: str) -> SdoEngine:
        """Attach a device: the SDO engine of its node (made unless another device already uses the node) and its
        master's heartbeat. Nothing changes if this raises."""
        with self._lock:
            known = self._heartbeats.get(member.master)
            if member.heartbeat > 0 and known is not None and known[0] != member.heartbeat:
                raise ConfigurationError(
                    f"{who}: master {member.master} already sends its heartbeat every {known[0] * 1000:g} ms on "
                    f"CAN bus {self.name}; this device asks for {member.heartbeat * 1000:g} ms: one master has one "
                    "heartbeat period (give every device on the bus the same heartbeat=)"
                )
            entry = self._nodes.get(member.node)
            driver = self.driver
            if entry is None:
                engine = SdoEngine(member.node, f"{self.name} node {member.node}")
                self.call(lambda now: driver.add(engine, _filters(engine)), "add an SDO client")
            else:
                engine = entry[0]
            self._nodes[member.node] = (engine, entry[1] + 1 if entry else 1)
            try:
                if member.heartbeat > 0:
                    if known is None:
                        frame = CanFrame(HEARTBEAT_BASE + member.master, bytes([HEARTBEAT_OPERATIONAL]))
                        period = member.heartbeat
                        task = self.call(lambda now: driver.periodic(frame, period, now), "start the heartbeat")
                        self._heartbeats[member.master] = (member.heartbeat, task, 1)
                    else:
                        self._heartbeats[member.master] = (known[0], known[1], known[2] + 1)
            except BaseException:
                self._leave(member)
                raise
            return engine

    def leave(self, member: Member) -> None:
        """Detach what :meth:`join` attached for ``member``."""
        with self._lock:
            self._leave(member)

    def _leave(self, member: Member) -> None:
        known = self._heartbeats.get(member.master)
        if member.heartbeat > 0 and known is not None:
            period, task, users = known
            if users > 1:
                self._heartbeats[member.master] = (period, task, users - 1)
            else:
                del self._heartbeats[member.master]
                self.call(lambda now: task.stop(), "stop the heartbeat")
        entry = self._nodes.get(member.node)
        if entry is not None:
            engine, users = entry
            if users > 1:
                self._nodes[member.node] = (engine, users - 1)
            else:
                del self._nodes[member.node]
                driver = self.driver
                self.call(lambda now: driver.remove(engine, now), "remove an SDO client")

    def send(self, frames: Sequence[CanFrame], what: str) -> None:
        """Write ``frames`` now, in this order (NMT, RPDO): a frame refused is a TransportError saying ``what``
        and naming the frame (``CanDriver.send``); those after it are not sent."""
        self.driver.send(frames, what)

    def periodic(self, frame: CanFrame, period: float, what: str) -> Periodic:
        """Send ``frame`` every ``period`` s from now on (the driver's periodic output: ``modify``, ``stop``)."""
        driver = self.driver
        return self.call(lambda now: driver.periodic(frame, period, now), what)

    def close(self) -> None:
        with self._lock:
            tasks = [task for _, task, _ in self._heartbeats.values()]
            self._heartbeats.clear()
            self._nodes.clear()

        def stop(now: float) -> None:
            for task in tasks:
                task.stop()

        try:
            if tasks and not self.driver.closed:
                self.call(stop, "stop the heartbeats")
        finally:
            self.closed = True
            self.driver.release()


#: every CAN bus a CANopen device of this process is on, by (interface, channel)
BUSES: SharedPool[CanBus] = SharedPool("CANopen buses")
