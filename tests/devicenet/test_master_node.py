"""The sans-IO master against transcripts and against sans-IO slaves on an in-memory wire with fed time:
start-up, the duplicate MAC ID rules of an on-line master, the communication fault and its reset, a rogue
responder, a flood of foreign traffic, slave loss and return, a master restart, the scan interval."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starterbus.core import CanFrame, ManualClock, Phase, Profile, SimulatedStarter
from starterbus.transports.devicenet.codec.frames import parse_candump
from starterbus.transports.devicenet.codec.ids import poll_command_id, poll_response_id
from starterbus.transports.devicenet.codec.transcript import Wire, expected, parse_transcript, replay
from starterbus.transports.devicenet.master.link import (
    CommunicationFaultError,
    DuplicateResponderError,
    InputSample,
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

SERIAL = 0x12345678
FOREIGN_RESPONSE = "407#80341278563412"  # a duplicate MAC ID response for MAC 0 (vendor 0x1234)

# The master (MAC 0, vendor 0, serial 0x12345678) alone on the bus: the check, the on-line rules, the fault
# and the reset it performs by itself 1 s later.
ONLINE_RULES = f"""
@ 1.0
< 407#00000078563412          # second duplicate MAC ID request (the first is sent by start())
@ 2.0                         # nobody answered: on line
> 407#00341278563412          # another node checks MAC 0: answered, the master stays on line
< 407#80000078563412
> {FOREIGN_RESPONSE}          # a response for MAC 0 while on line: communication fault, silence
> 407#00341278563412          # faulted: not even answered
@ 2.5
@ 3.0                         # the reset: the whole check again
< 407#00000078563412
@ 4.0
< 407#00000078563412
@ 5.0                         # on line again
> 407#00341278563412
< 407#80000078563412
"""

GARBAGE = [
    parse_candump(text)
    for text in (
        "40F#00330301000000",  # MAC 1 checking its MAC (no link for it)
        "3C5#200000000060",  # a poll response nobody asked this master for
        "42B#00CB00",  # an explicit response for a slave it has no link to
        "407#8034",  # a short duplicate MAC ID frame
        "407#",  # empty
        "600#DEADBEEF",  # group 3
        "7C1#00",  # group 4
    )
]


def state(node: MasterNode) -> ScannerState:
    return node.state  # (read through a call: mypy would narrow the attribute across calls that change it)


def latest(link: MasterLink) -> InputSample | None:
    return link.sample


def link_state(link: MasterLink) -> LinkState:
    return link.state


def master(**kwargs: object) -> MasterNode:
    config = ScannerConfig("wire", "0", **kwargs)  # type: ignore[arg-type]
    return MasterNode(config, SERIAL)


@pytest.mark.parametrize("garbage", [[], GARBAGE], ids=["clean", "with-garbage"])
def test_online_rules_transcript(garbage: list[CanFrame]) -> None:
    node = master()
    assert [f.text() for f in node.start(0.0)] == ["407#00000078563412"]
    steps = parse_transcript(ONLINE_RULES)
    sent = replay(node, steps, garbage)
    assert [f.text() for f in sent] == [f.text() for f in expected(steps)]
    assert state(node) is ScannerState.ONLINE and node.fault is None


# MAC 5 attached at 2.0 s (EPR 100 ms, scanned every 10 ms): the connection sequence (transaction ids toggle),
# the first poll, and a second answer to it.
CONNECTION = """
> 42B#40CB00                  # allocated (XID 1)
< 42C#000E050109              # Get the explicit connection's expected packet rate
> 42B#008EC409                # 2500 ms
< 42C#400E050207              # Get the polled connection's produced size
> 42B#408E0600                # 6 bytes
< 42C#000E050208              # consumed size
> 42B#008E0200                # 2 bytes: extended assemblies 101/102
< 42C#40100502096400          # Set the expected packet rate: 100 ms
> 42B#40906400                # 100 ms used: established
@ 2.05
< 42D#0001                    # first poll: stop, report status parameter 1
> 3C5#200000000060            # the slave's answer
> 3C5#EEEEEEEEEEEE            # a second answer to the same poll: another node answers for MAC 5
@ 2.06
< 42D#0001                    # still polled (the rogue may go away), its inputs withheld
> 3C5#200000000060
@ 2.07
< 42D#0001
"""


@pytest.mark.parametrize("garbage", [[], GARBAGE[:1] + GARBAGE[3:]], ids=["clean", "with-garbage"])
def test_connection_and_rogue_transcript(garbage: list[CanFrame]) -> None:
    node = master()
    node.start(0.0)
    replay(node, parse_transcript("@ 1.0\n@ 2.0"))
    link = node.attach(LinkConfig(5, epr_ms=100, interval=0.01), 2.0)
    assert [f.text() for f in node.tick(2.0)] == ["42E#404B03010300"]  # Allocate explicit + polled
    steps = parse_transcript(CONNECTION)
    sent = replay(node, steps, garbage, start=2.0)
    assert [f.text() for f in sent] == [f.text() for f in expected(steps)]
    error = node.link_error(link)
    assert isinstance(error, DuplicateResponderError) and "20 00 00 00 00 60 and EE EE EE EE EE EE" in str(error)
    assert link.sample is None and link.duplicates == 1


frames_strategy = st.lists(
    st.tuples(
        st.sampled_from([0x3C5, 0x42B, 0x407, 0x42F, 0x3C6, 0x433]) | st.integers(0, 0x7FF),
        st.binary(max_size=8),
        st.floats(0.0, 0.05),
    ),
    max_size=40,
)


@settings(max_examples=150, deadline=None)
@given(frames_strategy)
def test_any_frames_never_break_the_master(frames: list[tuple[int, bytes, float]]) -> None:
    node = master()
    node.start(0.0)
    replay(node, parse_transcript("@ 1.0\n@ 2.0"))
    link = node.attach(LinkConfig(5, epr_ms=100, interval=0.01), 2.0)
    node.tick(2.0)
    replay(node, parse_transcript(CONNECTION.partition("@ 2.05")[0]), start=2.0)
    assert link.established
    now = 2.0
    for can_id, data, step in frames:
        now += step
        for frame in node.handle(CanFrame(can_id, data), now) + node.tick(now):
            assert frame.can_id in (0x407, 0x42C, 0x42D, 0x42E)  # only its own identifiers
    assert node._in_flight >= 0 and node.state in (ScannerState.ONLINE, ScannerState.FAULT)
    error = node.link_error(link)
    assert error is None or isinstance(error, (CommunicationFaultError, DuplicateResponderError))


def test_fault_names_the_cause_and_every_call_fails_at_once() -> None:
    node = master()
    node.start(0.0)
    replay(node, parse_transcript(f"@ 1.0\n@ 2.0\n> {FOREIGN_RESPONSE}"))
    assert state(node) is ScannerState.FAULT
    link = node.attach(LinkConfig(5), 2.1)
    assert link.state is LinkState.FAULTED
    error = node.link_error(link)
    assert isinstance(error, CommunicationFaultError)
    text = str(error)
    assert "duplicate MAC ID 0" in text and "vendor 4660" in text and "0x12345678" in text
    assert FOREIGN_RESPONSE.upper() in text and "timeout" not in text and "established" not in text
    assert node.tick(2.2) == []  # faulted: silent
    assert node.reset(2.3)[0].text() == "407#00000078563412"  # a manual reset re-runs the check


def test_no_auto_reset_stays_faulted() -> None:
    node = master(auto_reset=False)
    node.start(0.0)
    replay(node, parse_transcript(f"@ 1.0\n@ 2.0\n> {FOREIGN_RESPONSE}\n@ 100.0"))
    assert state(node) is ScannerState.FAULT and node.deadline > 100.0


# -- on a wire with sans-IO slaves -------------------------------------------------------------------------


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
