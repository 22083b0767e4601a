"""One CAN bus per process for every CANopen device on it: one ``canopen.Network``, one master heartbeat.

Devices on one bus (a fleet's ``[[bus]]``, or several ``open_device`` calls naming the same interface and
channel) share a :class:`CanBus` from :data:`BUSES`: one python-can bus and notifier thread, which interfaces
that cannot be opened twice (PCAN, slcan on a serial port) need; one heartbeat per master node id, not one per
device; one ``RemoteNode`` per node id, so that a second transport for a node does not take the node's SDO
answers away from the first. The last device to leave closes the bus.

What must be the same for every device on the bus (the bit rate; a master's heartbeat period) is checked when a
device joins: a difference is a :class:`~starterbus.core.ConfigurationError` naming both, and the device does
not join.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import canopen

from starterbus.core import ConfigurationError, SharedPool, TransportError, open_bus, shutdown_bus

HEARTBEAT_OPERATIONAL = 0x05

Listener = Callable[[int, bytearray, float], None]


@dataclass(frozen=True, slots=True)
class Member:
    """What one device asked of the bus when it joined (given back to :meth:`CanBus.leave`)."""

    node: int
    master: int
    heartbeat: float  # s; 0: the device asked for none
    listens: tuple[tuple[int, Listener], ...]  # (COB-ID, callback)


class CanBus:
    """One interface/channel opened once in this process, shared by every CANopen device on it. Thread-safe."""

    def __init__(self, interface: str, channel: str, bitrate: int | None) -> None:
        self.interface, self.channel, self.bitrate = interface, channel, bitrate
        bus = open_bus(interface, channel, bitrate)  # any failure: TransportError naming interface and channel
        network = canopen.Network(bus)
        network.NOTIFIER_CYCLE = 0.05  # the notifier thread ends promptly on close
        try:
            network.connect()
        except Exception as exc:
            shutdown_bus(bus)
            raise TransportError(f"cannot listen on CAN interface {interface!r} channel {channel!r}: {exc}") from exc
        self.network = network
        self._lock = threading.Lock()
        self._nodes: dict[int, tuple[canopen.RemoteNode, int]] = {}  # node id -> (node, devices using it)
        self._heartbeats: dict[int, tuple[float, Any, int]] = {}  # master id -> (period, task, devices)

    @property
    def name(self) -> str:
        return f"{self.interface}/{self.channel}"

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

    def join(self, member: Member, make_node: Callable[[], canopen.RemoteNode], who: str) -> canopen.RemoteNode:
        """Attach a device: its node (made with ``make_node`` unless another device already uses it), its
        listeners and its master's heartbeat. Nothing changes if this raises."""
        with self._lock:
            known = self._heartbeats.get(member.master)
            if member.heartbeat > 0 and known is not None and known[0] != member.heartbeat:
                raise ConfigurationError(
                    f"{who}: master {member.master} already sends its heartbeat every {known[0] * 1000:g} ms on "
                    f"CAN bus {self.name}; this device asks for {member.heartbeat * 1000:g} ms: one master has one "
                    "heartbeat period (give every device on the bus the same heartbeat=)"
                )
            entry = self._nodes.get(member.node)
            node = entry[0] if entry else make_node()
            if entry is None:
                self.network.add_node(node)
            self._nodes[member.node] = (node, entry[1] + 1 if entry else 1)
            try:
                if member.heartbeat > 0:
                    if known is None:
                        frame = bytes([HEARTBEAT_OPERATIONAL])
                        task = self.network.send_periodic(0x700 + member.master, frame, member.heartbeat)
                        self._heartbeats[member.master] = (member.heartbeat, task, 1)
                    else:
                        self._heartbeats[member.master] = (known[0], known[1], known[2] + 1)
                for cob, listener in member.listens:
                    self.network.subscribe(cob, listener)
            except BaseException:
                self._leave(member)
                raise
            return node

    def leave(self, member: Member) -> None:
        """Detach what :meth:`join` attached for ``member``."""
        with self._lock:
            self._leave(member)

    def _leave(self, member: Member) -> None:
        for cob, listener in member.listens:
            if listener in self.network.subscribers.get(cob, ()):
                self.network.unsubscribe(cob, listener)
        known = self._heartbeats.get(member.master)
        if member.heartbeat > 0 and known is not None:
            period, task, users = known
            if users > 1:
                self._heartbeats[member.master] = (period, task, users - 1)
            else:
                del self._heartbeats[member.master]
                task.stop()
        entry = self._nodes.get(member.node)
        if entry is not None:
            node, users = entry
            if users > 1:
                self._nodes[member.node] = (node, users - 1)
            else:
                del self._nodes[member.node]
                del self.network[member.node]

    def close(self) -> None:
        with self._lock:
            for _, task, _ in self._heartbeats.values():
                task.stop()
            self._heartbeats.clear()
            self._nodes.clear()
        try:
            self.network.disconnect()  # re-raises what stopped the notifier thread, if anything did
        except Exception as exc:
            raise TransportError(f"CAN bus {self.name}: closing: {exc}") from exc


#: every CAN bus a CANopen device of this process is on, by (interface, channel)
BUSES: SharedPool[CanBus] = SharedPool("CANopen buses")
