"""JJR8000 DeviceNet slave simulator: the shared simulated starter behind one or more slave nodes on a CAN bus.

Programmatic use (in-process, e.g. on python-can's ``virtual`` bus)::

    starter = SimulatedStarter(get_profile("jjr8000"))
    sim = DeviceNetSlaveSimulator(starter, ("virtual", "bus0"), mac=5, dup_mac_wait=0.05).start()
    ...   # devicenet://virtual/bus0?mac=5&dup_mac_wait=0.05
    sim.close()

Several nodes share one simulator (one python-can bus, one thread): ``DeviceNetSimulator(bus).add_node(...)``.
The node logic is :class:`~starterbus.transports.devicenet.slave.node.SlaveNode` (sans-IO); this module is its
driver; the JJR8000 application is ``slave/application.py`` (:class:`StarterApplication`): input assemblies
1/101 from the starter's state, output assemblies 2/102 written as the control word with bit 3 (bus control) set,
since DeviceNet is the network control path and the JJR8000 obeys commands only with bit 3 = 1. When the polled
connection times out (4 x expected packet rate), is released, or the master goes idle, the starter's
``command_lost()`` drops the run command: the motor soft-stops and stays stopped until the master sends a new
start edge (the documented safe state).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import TypeVar

import can

from starterbus.core import (
    CanFrame,
    ConfigurationError,
    RunningSimulator,
    SimulatedStarter,
    open_bus,
    shutdown_bus,
)
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.dupmac import DEFAULT_WAIT
from starterbus.transports.devicenet.codec.identity import Identity
from starterbus.transports.devicenet.codec.ids import MAX_MAC, poll_command_id, poll_response_id
from starterbus.transports.devicenet.settings import profile_identity
from starterbus.transports.devicenet.slave.application import IO_REFRESH, PRO_TYPE_KEY, StarterApplication
from starterbus.transports.devicenet.slave.node import SlaveNode
from starterbus.transports.devicenet.slave.state import NodeState

__all__ = [
    "IO_REFRESH",
    "PRO_TYPE_KEY",
    "BusSpec",
    "DeviceNetSimulator",
    "DeviceNetSlaveSimulator",
    "StarterApplication",
]

log = logging.getLogger(__name__)
SimulatorT = TypeVar("SimulatorT", bound="DeviceNetSimulator")

BusSpec = can.BusABC | tuple[str, str]
Handler = Callable[[bytes, float], list[CanFrame]]
Route = tuple[SlaveNode, Handler, int | None]  # node, handler, poll response id (the fast path) or None


class DeviceNetSimulator(RunningSimulator):
    """Slave nodes on one python-can bus, served by one background thread.

    ``bus`` is a python-can bus (not shut down on close) or ``(interface, channel)`` (opened and closed here).
    Nodes added before :meth:`start` start their duplicate MAC ID check when it starts; nodes added later
    start at once. ``dup_mac_wait`` is the wait of the check (1 s per the specification; tests use less).
    """

    def __init__(
        self,
        bus: BusSpec,
        *,
        bitrate: int = 500000,
        dup_mac_wait: float = DEFAULT_WAIT,
        tick_ms: int = 10,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if isinstance(bus, tuple):
            interface, channel = bus
            self.bus = open_bus(interface, channel, bitrate)
            self._owns_bus = True
            self.where = f"{interface}/{channel}"
        else:
            self.bus = bus
            self._owns_bus = False
            self.where = f"{getattr(bus, 'channel_info', 'bus')}"
        self.bitrate = bitrate
        self.dup_mac_wait = dup_mac_wait
        self.tick_ms = tick_ms
        self.clock = clock
        self.lock = threading.RLock()
        self.nodes: list[SlaveNode] = []
        self.applications: dict[int, StarterApplication] = {}
        self._routes: dict[int, list[Route]] = {}
        self._next_tick = float("inf")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._outbox: list[CanFrame] = []
        self.errors: list[str] = []
        #: tests (the conformance kit): called with a node's MAC id, the CAN id and the data of each frame it gets
        self.received: Callable[[int, int, bytes], None] | None = None

    # -- nodes ----------------------------------------------------------------------------------------------------

    def add_node(
        self,
        starter: SimulatedStarter,
        mac: int,
        *,
        identity: Identity | None = None,
        assemblies: AssemblySet | None = AssemblySet.EXTENDED,
        explicit_epr_ms: int | None = None,
    ) -> SlaveNode:
        if not 0 <= mac <= MAX_MAC:
            raise ConfigurationError(f"DeviceNet MAC id {mac} is outside 0..63 ({starter.profile.display_name}: 1..63)")
        if identity is None:
            identity = profile_identity(starter.profile, serial_number=0x20110100 + mac)
        app = StarterApplication(starter, assemblies)
        node = SlaveNode(mac, app, identity, dup_mac_wait=self.dup_mac_wait, tick_ms=self.tick_ms, bitrate=self.bitrate)
        if explicit_epr_ms is not None:
            node.explicit_epr_ms = explicit_epr_ms
        with self.lock:
            self.nodes.append(node)
            self.applications[id(node)] = app
            routes = {k: list(v) for k, v in self._routes.items()}
            for can_id, handler in node.routes().items():
                fast = poll_response_id(mac) if can_id == poll_command_id(mac) else None
                routes.setdefault(can_id, []).append((node, handler, fast))
            self._routes = routes
            if self._thread is not None:
                self._emit(node, node.start(self.clock()))
                self._next_tick = min(self._next_tick, node.next_deadline() or float("inf"))
                self._flush()
        return node

    def node(self, mac: int) -> SlaveNode:
        for node in self.nodes:
            if node.mac == mac:
                return node
        raise KeyError(f"no simulated DeviceNet node with MAC {mac}")

    def application(self, node: SlaveNode) -> StarterApplication:
        return self.applications[id(node)]

    # -- lifecycle --------------------------------------------------------------------------------------------

    def start(self: SimulatorT) -> SimulatorT:
        if self._thread is not None:
            return self
        with self.lock:
            now = self.clock()
            started = [(node, node.start(now)) for node in self.nodes]  # all checking before any frame is seen
            for node, frames in started:
                self._emit(node, frames)
            self._recompute_deadline()
            self._flush()
        self._thread = threading.Thread(target=self._run, name=f"devicenet-sim {self.where}", daemon=True)
        self._thread.start()
        return self

    def wait_online(self, timeout: float = 5.0) -> bool:
        """Wait until every node finished its duplicate MAC ID check (on line or faulted)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if all(n.state in (NodeState.ONLINE, NodeState.COMM_FAULT) for n in self.nodes):
                    return True
            time.sleep(0.005)
        return False

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._owns_bus:
            shutdown_bus(self.bus)

    def __enter__(self: SimulatorT) -> SimulatorT:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> list[str]:
        lines = []
        for node in self.nodes:
            app = self.application(node)
            assemblies = app.assembly_set()
            lines.append(
                f"devicenet: {self.where} MAC {node.mac} ({node.identity.product_name}, {assemblies.value} assemblies "
                f"{assemblies.input_instance}/{assemblies.output_instance}, {self.bitrate // 1000} kbit/s)"
            )
        return lines

    # -- the thread ---------------------------------------------------------------------------------------------

    def _recompute_deadline(self) -> None:
        deadlines = [d for d in (n.next_deadline() for n in self.nodes) if d is not None]
        self._next_tick = min(deadlines) if deadlines else float("inf")

    def _emit(self, sender: SlaveNode | None, frames: Iterable[CanFrame]) -> None:
        """Queue frames for the bus, and hand them to sibling nodes (a bus never echoes to its sender)."""
        for frame in frames:
            self._outbox.append(frame)
            for node, handler, _ in self._routes.get(frame.can_id, ()):
                if node is not sender:
                    self._emit(node, handler(frame.data, self.clock()))

    def _flush(self) -> None:
        outbox, self._outbox = self._outbox, []
        for frame in outbox:
            try:
                self.bus.send(can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=False))
            except can.CanError as exc:
                self.errors.append(f"send {frame.text()} failed: {exc}")

    def _run(self) -> None:
        bus = self.bus
        stop = self._stop
        clock = self.clock
        while not stop.is_set():
            now = clock()
            if now >= self._next_tick:
                with self.lock:
                    for node in self.nodes:
                        self._emit(node, node.tick(now))
                    self._recompute_deadline()
                    self._flush()
                continue
            try:
                message = bus.recv(max(0.0, min(self._next_tick - now, 0.05)))
            except Exception as exc:
                if stop.is_set():
                    break
                self.errors.append(f"receive failed: {exc}")
                time.sleep(0.05)
                continue
            if message is None or message.is_extended_id or message.is_remote_frame or message.is_error_frame:
                continue
            targets = self._routes.get(message.arbitration_id)
            if not targets:
                continue
            now = clock()
            data = bytes(message.data)
            with self.lock:
                for node, handler, response_id in targets:
                    if self.received is not None:
                        self.received(node.mac, message.arbitration_id, data)
                    try:
                        if response_id is not None:  # poll command: the hot path
                            response = node.poll(data, now)
                            if response is not None:
                                self._outbox.append(CanFrame(response_id, response))
                            continue
                        self._emit(node, handler(data, now))
                    except Exception as exc:  # a bug must not kill the bus thread
                        log.exception(
                            "DeviceNet node %s failed on %03X#%s", node.mac, message.arbitration_id, data.hex()
                        )
                        self.errors.append(f"MAC {node.mac}: {type(exc).__name__}: {exc}")
                    deadline = node.next_deadline()
                    if deadline is not None and deadline < self._next_tick:
                        self._next_tick = deadline
                outbox, self._outbox = self._outbox, []
            for frame in outbox:
                try:
                    bus.send(can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=False))
                except can.CanError as exc:
                    self.errors.append(f"send {frame.text()} failed: {exc}")


class DeviceNetSlaveSimulator(DeviceNetSimulator):
    """One simulated JJR8000 node: ``DeviceNetSlaveSimulator(starter, bus_or_(interface, channel), mac, ...)``."""

    def __init__(
        self,
        starter: SimulatedStarter,
        bus: BusSpec,
        mac: int,
        *,
        identity: Identity | None = None,
        assemblies: AssemblySet | None = AssemblySet.EXTENDED,
        bitrate: int = 500000,
        dup_mac_wait: float = DEFAULT_WAIT,
        tick_ms: int = 10,
        explicit_epr_ms: int | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(bus, bitrate=bitrate, dup_mac_wait=dup_mac_wait, tick_ms=tick_ms, clock=clock)
        self.slave = self.add_node(
            starter, mac, identity=identity, assemblies=assemblies, explicit_epr_ms=explicit_epr_ms
        )
