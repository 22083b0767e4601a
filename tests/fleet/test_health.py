"""Health for supervisors (issue 26, item 5): systemd's notifications received by a unix datagram socket the test
listens on, READY=1 only after the first round, WATCHDOG=1 only while the polls progress; readiness reasons."""

from __future__ import annotations

import socket
import tempfile
import threading
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from starterbus.core.device import Device
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.transport import PollResult
from starterbus.core.url import DeviceUrl
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.health import PollHealth, Watchdog, default_stall_after, notify_systemd
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.sdnotify import SystemdNotifier
from starterbus.testing.conformance import wait_until
from starterbus.tests.stub_transport import StubTransport

WAIT = 20.0
FLEET = (
    "[poll]\nperiod = 0.02\nmax_backoff = 0.05\n"
    '[[bus]]\nname = "a"\nurl = "modbus-rtu:///dev/null?baudrate=19200"\n'
    '[[bus.device]]\nname = "da"\nmodel = "jjr5000"\naddress = 1\n'
    '[[bus]]\nname = "b"\nurl = "modbus-rtu:///dev/zero?baudrate=19200"\n'
    '[[bus.device]]\nname = "db"\nmodel = "jjr5000"\naddress = 1\n'
)


class GatedTransport(StubTransport):
    """Answers at once while its gate is open; a poll that finds it closed blocks until it opens (a hung line)."""

    name = "gated"

    def __init__(self, profile: Profile) -> None:
        super().__init__(DeviceUrl.parse("gated://line"), profile)
        self.gate = threading.Event()
        self.gate.set()
        self.blocked = threading.Event()

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        if not self.gate.is_set():
            self.blocked.set()
            self.gate.wait(60)
        return PollResult(None, [Reading(p, 7) for p in points])


@dataclass
class Rig:
    poller: FleetPoller
    gates: dict[str, GatedTransport]


@pytest.fixture
def rig() -> Iterator[Rig]:
    """Two buses of one device each, every poll through a gated stub transport (no I/O); not started."""
    poller = FleetPoller(parse_fleet(FLEET), multiplex=False)
    profile = get_profile("jjr5000")
    gates = {}
    for worker in poller.workers:
        transport = GatedTransport(profile)
        worker.devices[0].device = Device(transport, profile).open()
        gates[worker.bus.name] = transport
    try:
        yield Rig(poller, gates)
    finally:
        for transport in gates.values():
            transport.gate.set()
        poller.stop()


class Listener:
    """What systemd does with $NOTIFY_SOCKET: a unix datagram socket; each datagram is one message."""

    def __init__(self, address: str) -> None:
        self.address = address
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind("\0" + address[1:] if address.startswith("@") else address)
        self.messages: list[list[str]] = []

    def next(self, timeout: float = WAIT) -> list[str]:
        self.sock.settimeout(timeout)
        lines = self.sock.recv(4096).decode().split("\n")
        self.messages.append(lines)
        return lines

    def until(self, line: str, timeout: float = WAIT) -> list[str]:
        """The first message holding ``line`` (or a line starting with it, for ``STATUS=...``)."""
        while True:
            lines = self.next(timeout)
            if any(x.startswith(line) for x in lines):
                return lines

    def drain(self) -> list[list[str]]:
        """Every message waiting now (the socket's queue), without waiting for more."""
        got = []
        self.sock.setblocking(False)
        try:
            while True:
                got.append(self.sock.recv(4096).decode().split("\n"))
        except BlockingIOError:
            pass
        self.messages += got
        return got

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def listener() -> Iterator[Listener]:
    sock = Listener(f"@starterbus-test-{uuid.uuid4().hex}")  # the abstract namespace, as systemd uses
    try:
        yield sock
    finally:
        sock.close()


def test_ready_after_the_first_round_and_watchdog_only_while_polls_progress(rig: Rig, listener: Listener) -> None:
    health = PollHealth(rig.poller, stall_after=1.0)
    watchdog = Watchdog(health, SystemdNotifier(listener.address, watchdog_usec=200_000))
    assert watchdog.ping_every == pytest.approx(0.1), "WATCHDOG=1 at half of $WATCHDOG_USEC"
    rig.gates["b"].gate.clear()  # bus b's first poll hangs: the first round is not done
    rig.poller.start()
    with watchdog:
        assert rig.gates["b"].blocked.wait(WAIT)
        assert watchdog.wait_ticks(3, WAIT)
        assert not any("READY=1" in m for m in listener.drain()), "no READY before every device was polled"
        assert not health.check().ready and "waiting for the first poll" in health.check().reason

        rig.gates["b"].gate.set()
        listener.until("READY=1")
        assert all(r.polls >= 1 for r in rig.poller.runtimes())
        listener.until("WATCHDOG=1")
        listener.until("WATCHDOG=1")

        rig.gates["a"].blocked.clear()
        rig.gates["a"].gate.clear()  # bus a hangs in its next poll: no progress there
        assert rig.gates["a"].blocked.wait(WAIT)
        stalled = listener.until("STATUS=stalled")
        assert "WATCHDOG=1" not in stalled and "bus a" in next(x for x in stalled if x.startswith("STATUS="))
        assert watchdog.wait_ticks(5, WAIT)  # five more looks at the poller, each after more than a ping's time
        assert not any("WATCHDOG=1" in m for m in listener.drain()), "no ping while a bus is stalled"
        assert health.check().stalled == ("a",) and not health.check().ready

        rig.gates["a"].gate.set()  # it comes back: pings again
        listener.until("WATCHDOG=1")
    assert listener.until("STOPPING=1")


def test_a_finished_poller_is_not_stalled_and_extra_checks_give_the_reason(rig: Rig) -> None:
    connected = threading.Event()
    health = PollHealth(
        rig.poller, stall_after=0.0, checks=[lambda: None if connected.is_set() else "not connected to a broker"]
    )
    rig.poller.rounds = 1
    for worker in rig.poller.workers:
        worker.rounds_left = 1
    rig.poller.start()
    rig.poller.join(WAIT)
    assert not rig.poller.running
    health.check()
    report = health.check()
    assert report.first_round and report.progressing, "the rounds asked for are done: not a stall"
    assert (report.ready, report.reason) == (False, "not connected to a broker")
    connected.set()
    assert health.check().ready
    ages = health.ages()
    assert set(ages) == {"da", "db"} and all(0 <= age < WAIT for age in ages.values())


def test_the_stall_limit_covers_the_slowest_schedule() -> None:
    config = parse_fleet(FLEET.replace("max_backoff = 0.05", "max_backoff = 30"))
    assert default_stall_after(config) == pytest.approx(2 * 30 + 30)


def test_the_notifier_outside_systemd_and_with_a_socket_path(tmp_path: Path) -> None:
    quiet = SystemdNotifier.from_environment({})
    assert not quiet.enabled and quiet.watchdog is None and quiet.notify("READY=1") is False
    other = SystemdNotifier.from_environment(
        {"NOTIFY_SOCKET": "/nowhere", "WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "1"}
    )
    assert other.watchdog is None, "WATCHDOG_PID names another process"
    directory = Path(tempfile.mkdtemp(prefix="sbn-", dir="/tmp"))  # a short path: sun_path has 108 bytes
    try:
        listener = Listener(str(directory / "notify"))
        notifier = SystemdNotifier.from_environment({"NOTIFY_SOCKET": listener.address, "WATCHDOG_USEC": "4000000"})
        assert notifier.watchdog == pytest.approx(4.0)
        assert notifier.notify("READY=1", "STATUS=up")
        assert listener.next() == ["READY=1", "STATUS=up"]
        listener.close()
        (directory / "notify").unlink()
        assert notifier.notify("WATCHDOG=1") is False, "the supervisor went away: not sent, never raised"
        notifier.close()
    finally:
        directory.rmdir()


def test_notify_systemd_follows_the_poller_until_it_stops(rig: Rig, listener: Listener) -> None:
    """What the commands call once their poller runs: nothing to stop by hand, STOPPING=1 once the poller stops."""
    rig.poller.start()
    watchdog = notify_systemd(rig.poller, {"NOTIFY_SOCKET": listener.address, "WATCHDOG_USEC": "200000"})
    listener.until("READY=1")
    listener.until("WATCHDOG=1")
    rig.poller.stop()
    listener.until("STOPPING=1")
    assert wait_until(lambda: not watchdog._thread.is_alive(), WAIT)
    assert not notify_systemd(rig.poller, {})._thread.is_alive(), "outside systemd no thread runs"
