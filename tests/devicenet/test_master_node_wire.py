"""The sans-IO master against sans-IO slaves on an in-memory wire with fed time: the connection sequence and
polls, the communication fault and its reset, a real duplicate, a rogue responder, late answers, a flood of
foreign traffic, slave loss and return, a master restart, the scan interval and keep-alives."""

from __future__ import annotations

import itertools

import pytest

from starterbus.core import CanFrame, ManualClock, Phase, Profile, SimulatedStarter
from starterbus.tests.devicenet.test_master_node import FOREIGN_RESPONSE, SERIAL, latest, link_state, master, state
from starterbus.transports.devicenet.codec.frames import parse_candump
from starterbus.transports.devicenet.codec.ids import poll_command_id, poll_response_id
from starterbus.transports.devicenet.codec.transcript import Wire
from starterbus.transports.devicenet.master.link import (
    CommunicationFaultError,
    DuplicateResponderError,
    LinkConfig,
    LinkState,
    MasterLink,
    ScannerConfig,
    ScannerState,
)
from starterbus.transports.devicenet.master.node import RESET_BACKOFF, MasterNode
from starterbus.transports.devicenet.master.polling import CLEAR_POLLS
from starterbus.transports.devicenet.settings import profile_identity
from starterbus.transports.devicenet.simulator import StarterApplication
from starterbus.transports.devicenet.slave.node import SlaveNode
from starterbus.transports.devicenet.slave.state import NodeState


def slave(profile: Profile, mac: int = 5) -> tuple[SlaveNode, SimulatedStarter]:
    starter = SimulatedStarter(profile, ManualClock(0.0))
    app = StarterApplication(starter, io_refresh=0.0)
    node = SlaveNode(mac, app, profile_identity(profile, serial_number=mac), dup_mac_wait=0.1)
    return node, starter


class Rogue:
    """A node answering polls for ``mac`` without ever checking its MAC id."""

    def __init__(self, mac: int, data: bytes) -> None:
        self.command, self.answer = poll_command_id(mac), CanFrame(poll_response_id(mac), data)

    def handle(self, frame: CanFrame, now: float) -> list[CanFrame]:
        return [self.answer] if frame.can_id == self.command else []

    def tick(self, now: float) -> list[CanFrame]:
        return []


class Flood:
    """Foreign traffic: ``per_ms`` frames every millisecond, for other nodes and other masters."""

    TEXTS = ("3C9#0102030405", "44D#0001", "44B#00CB00", "413#00CB00", "63F#FFFFFFFF", "0C1#01", "4FF#00112233")

    def __init__(self, per_ms: int) -> None:
        self.per_ms = per_ms
        self.frames = [parse_candump(text) for text in self.TEXTS]
        self.count = 0

    def handle(self, frame: CanFrame, now: float) -> list[CanFrame]:
        return []

    def tick(self, now: float) -> list[CanFrame]:
        out = [self.frames[(self.count + i) % len(self.frames)] for i in range(self.per_ms)]
        self.count += self.per_ms
        return out


def online(jjr8000: Profile, interval: float = 0.01, epr_ms: int = 100) -> tuple[Wire, MasterNode, MasterLink]:
    wire = Wire()
    node, _ = slave(jjr8000)
    wire.add("slave", node, node.start(0.0))
    scanner = master(dup_mac_wait=0.1)
    wire.add("master", scanner, scanner.start(0.0))
    link = scanner.attach(LinkConfig(5, epr_ms=epr_ms, interval=interval), 0.0)
    wire.run(0.5)
    assert link.established and link.sample is not None
    return wire, scanner, link


def plain(texts: list[str]) -> list[str]:
    """Frames with the transaction id bit of explicit headers cleared (the master toggles it per request)."""
    out = []
    for text in texts:
        frame = parse_candump(text)
        if 0x400 <= frame.can_id < 0x600 and frame.can_id & 7 in (3, 4, 6) and frame.data:
            frame = CanFrame(frame.can_id, bytes((frame.data[0] & 0xBF,)) + frame.data[1:])
        out.append(frame.text())
    return out


def test_connection_sequence_and_polls_on_the_wire(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000)
    starter = wire.nodes["slave"].app.starter  # type: ignore[attr-defined]
    sent = plain(wire.frames("master"))
    assert sent[:3] == ["407#00000078563412", "407#00000078563412", "42E#004B03010300"]
    seq = scanner.set_outputs(link, wire.now, run=True)
    wire.send("master", scanner.tick(wire.now))
    wire.run(wire.now + 0.01)
    assert link.acked_seq >= seq and starter.phase is Phase.STARTING
    assert link.sample is not None and link.sample.data[0] & 0x08  # the starting bit


def test_fault_on_line_then_the_reset_reestablishes(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000)
    fault_at, mark = wire.now, len(wire.log)
    wire.send("other", [parse_candump(FOREIGN_RESPONSE)])
    assert state(scanner) is ScannerState.FAULT and link.state is LinkState.FAULTED
    assert isinstance(scanner.link_error(link), CommunicationFaultError)
    wire.run(fault_at + RESET_BACKOFF[0] - 0.01)
    assert [f for _, sender, f in wire.log[mark:] if sender == "master"] == []  # a faulted node says nothing
    assert wire.nodes["slave"].polled.state.name == "TIMED_OUT"  # type: ignore[attr-defined]
    wire.run(fault_at + RESET_BACKOFF[0] + 0.25)  # two requests 0.1 s apart, then the connection again
    assert [f.text() for _, sender, f in wire.log[mark:] if sender == "master"][:2] == ["407#00000078563412"] * 2
    assert state(scanner) is ScannerState.ONLINE and link.established and scanner.link_error(link) is None
    assert "42B#00940B02" in plain(wire.frames("slave", since=fault_at))  # our old allocation: released, allocated


def test_a_real_duplicate_keeps_failing_the_check_with_backoff(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000)
    twin, _ = slave(jjr8000, mac=0)  # a node that really uses MAC 0 (it went on line while we were faulted)
    start = wire.now
    wire.send("other", [parse_candump(FOREIGN_RESPONSE)])
    wire.add("twin", twin, [])
    twin.state = NodeState.ONLINE  # it is on line: it answers the master's checks
    wire.run(start + 16.0)
    assert state(scanner) is ScannerState.FAULT and isinstance(scanner.link_error(link), CommunicationFaultError)
    checks = [t for t, s, f in wire.log if s == "master" and f.text() == "407#00000078563412" and t > start]
    gaps = [b - a for a, b in itertools.pairwise(checks)]
    assert len(gaps) == 3 and [round(gap) for gap in gaps] == [2, 4, 8]  # the backoff doubles


@pytest.mark.parametrize("first", ["slave", "rogue"])
def test_rogue_responder_is_reported_never_taken(jjr8000: Profile, first: str) -> None:
    wire, scanner, link = online(jjr8000)
    real = link.sample.data  # type: ignore[union-attr]
    node = wire.nodes.pop("slave")
    rogue = Rogue(5, b"\xee" * 6)
    if first == "rogue":
        wire.add("rogue", rogue)
        wire.add("slave", node)
    else:
        wire.add("slave", node)
        wire.add("rogue", rogue)
    seen: set[bytes] = set()
    for _ in range(50):
        wire.run(wire.now + 0.005)
        if link.sample is not None:
            seen.add(link.sample.data)
    assert rogue.answer.data not in seen  # not one value from the rogue
    error = scanner.link_error(link)
    assert isinstance(error, DuplicateResponderError)
    assert "EE EE EE EE EE EE" in str(error) and "MAC 5" in str(error)
    assert link.sample is None and link.established  # still polled: the rogue may go away
    wire.remove("rogue")
    wire.run(wire.now + CLEAR_POLLS * 0.02)
    current = latest(link)
    assert scanner.link_error(link) is None and current is not None and current.data[:4] == real[:4]


class Delayed:
    """A node whose frames reach the bus ``delay`` seconds late (as a host's receive queue under load)."""

    def __init__(self, node: SlaveNode, delay: float) -> None:
        self.node, self.delay = node, delay
        self.held: list[tuple[float, CanFrame]] = []

    def handle(self, frame: CanFrame, now: float) -> list[CanFrame]:
        self.held += [(now + self.delay, out) for out in self.node.handle(frame, now)]
        return []

    def tick(self, now: float) -> list[CanFrame]:
        self.held += [(now + self.delay, out) for out in self.node.tick(now)]
        due = [frame for at, frame in self.held if at <= now]
        self.held = [(at, frame) for at, frame in self.held if at > now]
        return due


def test_late_answers_are_no_duplicates(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000)
    node = wire.nodes.pop("slave")
    assert isinstance(node, SlaveNode)
    wire.add("slave", Delayed(node, 0.07))  # answers arrive after the poll's 50 ms deadline
    scanner.set_outputs(link, wire.now, select=3)
    wire.run(wire.now + 2.0)
    assert link.established and link.misses > 5 and link.late > 5
    assert link.duplicates == 0 and scanner.link_error(link) is None
    sample = latest(link)
    assert sample is not None and sample.select == 3 and sample.select_count > 5


def test_flood_of_foreign_traffic_does_not_slow_polls(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000)
    before = scanner.polls_sent
    wire.run(wire.now + 1.0)
    quiet = scanner.polls_sent - before
    flood = Flood(per_ms=8)  # 8000 frames/s, more than a 500 kbit/s bus carries with these lengths
    wire.add("flood", flood)
    before, ignored = scanner.polls_sent, scanner.ignored
    wire.run(wire.now + 1.0)
    assert flood.count == 8000
    assert scanner.polls_sent - before >= 0.95 * quiet
    assert link.established and link.misses == 0 and link.duplicates == 0
    assert scanner.ignored - ignored == 8000
    assert not any(frame.can_id in scanner.wanted for frame in flood.frames)  # the driver drops them unread


def test_slave_loss_and_return(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000)
    scanner.set_outputs(link, wire.now, run=True)
    wire.run(wire.now + 0.05)
    wire.remove("slave")  # power off
    lost_at = wire.now
    wire.run(lost_at + 0.45)  # 4 x EPR (100 ms) of silence
    assert not link.established and not link.run  # the start must be sent again
    assert "run command dropped" in str(link.last_error)
    node, _ = slave(jjr8000)  # power on: a fresh node checks its MAC, then answers allocation again
    wire.add("slave", node, node.start(wire.now))
    wire.run(wire.now + 2.5)  # an allocation attempt may be waiting out its 1 s timeout
    assert link_state(link) is LinkState.ESTABLISHED and scanner.link_error(link) is None


def test_master_restart_with_the_old_allocation(jjr8000: Profile) -> None:
    wire, _, _ = online(jjr8000)
    wire.remove("master")  # crashed: no release
    wire.run(wire.now + 0.5)
    second = MasterNode(ScannerConfig("wire", "0", dup_mac_wait=0.1), SERIAL + 1)
    restart = wire.now
    wire.add("master", second, second.start(wire.now))
    link = second.attach(LinkConfig(5, interval=0.01), wire.now)
    wire.run(wire.now + 0.5)
    assert link.established
    assert "42B#00940B02" in plain(wire.frames("slave", since=restart))  # already in requested mode
    released = [t for t in plain(wire.frames("master", since=restart)) if t == "42E#004C030103"]
    assert len(released) == 1


def test_scan_interval_follows_the_period_and_reads_expedite(jjr8000: Profile) -> None:
    wire, scanner, link = online(jjr8000, interval=1.0, epr_ms=2000)
    before = scanner.polls_sent
    wire.run(wire.now + 10.0)
    assert 9 <= scanner.polls_sent - before <= 11  # one poll a second, not fifty
    assert link.established and link.keepalive == 2.5
    sample = link.sample
    scanner.expedite(link, wire.now, 2)  # a reader wants fresh inputs now
    wire.send("master", scanner.tick(wire.now))
    wire.run(wire.now + 0.01)
    assert link.sample is not None and sample is not None and link.sample.at > sample.at
    assert scanner.polls_sent - before >= 11


@pytest.mark.parametrize("io", [False, True], ids=["monitoring", "polling"])
def test_keep_alives_due_close_together_go_in_one_pass(jjr8000: Profile, io: bool) -> None:
    wire = Wire()
    for mac in (5, 6):
        node, _ = slave(jjr8000, mac)
        wire.add(f"slave{mac}", node, node.start(0.0))
    scanner = master(dup_mac_wait=0.1)
    wire.add("master", scanner, scanner.start(0.0))
    first = scanner.attach(LinkConfig(5, io=io), 0.0)
    wire.run(0.3)
    second = scanner.attach(LinkConfig(6, io=io), wire.now)  # 0.3 s later: its keep-alives would trail by 0.3 s
    wire.run(0.8)
    assert first.established and second.established and first.last_explicit_at != second.last_explicit_at
    for _ in range(100):  # 10 s: four keep-alive periods; neither link ever waits longer than its period
        wire.run(wire.now + 0.1)
        assert wire.now - first.last_explicit_at <= first.keepalive + 0.01
        assert wire.now - second.last_explicit_at <= second.keepalive + 0.01
    assert first.last_explicit_at == second.last_explicit_at  # in step: one pass over the links serves both
