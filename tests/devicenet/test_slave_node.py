"""The sans-IO slave node against frame transcripts (`> received`, `< sent`, `@ time`), whole and with garbage
frames interleaved; every error response; watchdogs on fake time; duplicate MAC ID collisions."""

from __future__ import annotations

import pytest

from starterbus.core import CanFrame
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.transports.devicenet.codec.connection import ConnectionState
from starterbus.transports.devicenet.codec.frames import parse_candump
from starterbus.transports.devicenet.codec.transcript import expected, parse_transcript, replay
from starterbus.transports.devicenet.settings import profile_identity
from starterbus.transports.devicenet.simulator import StarterApplication
from starterbus.transports.devicenet.slave.node import SlaveNode
from starterbus.transports.devicenet.slave.state import NodeState

SERIAL = 0x20110105

# Start-up of MAC 5 with master 0, as the scanner runs it, then a fragmented identity read and the release.
STARTUP = """
@ 1.0
< 42F#00330305011120          # second duplicate MAC ID request (the first is sent by start())
@ 2.0                         # nobody answered: on line
> 42E#004B03010300            # Allocate explicit + polled, allocator 0, on the group 2 only port
< 42B#00CB00                  # success, message body format 8/8
> 42C#000E050207            # Get polled connection produced size
< 42B#008E0600                # 6 bytes: input assembly 101
> 42C#000E050208            # consumed size
< 42B#008E0200                # 2 bytes: output assembly 102
> 42C#00100502096400          # Set expected packet rate 100 ms
< 42B#00906400                # 100 ms used: established
> 42D#0001                    # poll: stop, report status parameter 1 (status word)
< 3C5#200000000060            # network control; status word 0x6000 (ready, bus control)
> 42D#0101                    # start
< 3C5#280000000041            # starting, network control; status word 0x4100
> 42C#400E010107              # Get identity product name (XID 1)
< 42B#C0008E074A4A5238        # first fragment
> 42C#C0C000                  # acknowledged
< 42B#C081303030              # last fragment: "JJR8000"
> 42C#C0C100                  # acknowledged: nothing more
> 42C#004C030103              # Release explicit + polled
< 42B#00CC
> 42D#0101                    # no connection any more: ignored
"""

GARBAGE = [
    parse_candump(text)
    for text in (
        "434#000E010107",  # a request for MAC 6
        "435#0101",  # a poll of MAC 6
        "3C6#200000000000",  # another slave's poll response
        "42B#00CB00",  # a response on our own response identifier (we do not consume it)
        "600#DEADBEEF",  # group 3
        "7C1#00",  # group 4
        "437#00330306000000",  # MAC 6 checking its MAC
        "42C#",  # empty, for us
        "42C#05",  # one byte, another master
        "42C#050E010107",  # another master on our explicit connection
        "42E#80",  # a fragment on the group 2 only port (which does not fragment)
    )
]


def make_node(profile: Profile, **kwargs: object) -> tuple[SlaveNode, SimulatedStarter, ManualClock]:
    clock = ManualClock(0.0)
    starter = SimulatedStarter(profile, clock)
    app = StarterApplication(starter, io_refresh=0.0)
    node = SlaveNode(5, app, profile_identity(profile, serial_number=SERIAL), **kwargs)  # type: ignore[arg-type]
    return node, starter, clock


def test_first_duplicate_mac_request_on_start(jjr8000: Profile) -> None:
    node, _, _ = make_node(jjr8000)
    assert node.start(0.0) == [parse_candump("42F#00330305011120")]
    assert node.state is NodeState.CHECKING


def test_startup_transcript_fed_whole(jjr8000: Profile) -> None:
    node, starter, _ = make_node(jjr8000)
    node.start(0.0)
    steps = parse_transcript(STARTUP)
    assert replay(node, steps) == expected(steps)
    assert starter.start_count == 1
    assert starter.phase is Phase.STOPPING  # the release dropped the run command: soft stop
    assert node.allocation == 0 and node.master_mac == 0xFF


def test_startup_transcript_with_garbage_interleaved(jjr8000: Profile) -> None:
    node, _, _ = make_node(jjr8000)
    node.start(0.0)
    steps = parse_transcript(STARTUP)
    assert replay(node, steps, garbage=GARBAGE) == expected(steps)
    assert node.counters.bad_frames > 0 and node.counters.ignored_frames > 0


def test_nothing_answered_while_checking(jjr8000: Profile) -> None:
    node, _, _ = make_node(jjr8000)
    node.start(0.0)
    assert node.handle(parse_candump("42E#004B03010300"), 0.5) == []
    assert node.next_deadline() == 1.0


def online(profile: Profile, epr: int = 100, **kwargs: object) -> tuple[SlaveNode, SimulatedStarter, ManualClock]:
    node, starter, clock = make_node(profile, **kwargs)
    node.start(0.0)
    steps = parse_transcript(
        f"""
        @ 2.0
        > 42E#004B03010300
        > 42C#00100502 09{epr & 0xFF:02X}{epr >> 8:02X}
        """
    )
    replay(node, steps)
    assert node.state is NodeState.ONLINE
    return node, starter, clock


def polled_state(node: SlaveNode) -> ConnectionState:
    return node.polled.state


def node_state(node: SlaveNode) -> NodeState:
    return node.state


def exchange(node: SlaveNode, text: str, now: float = 2.5) -> str:
    """Send one frame, return what came back as candump text (space separated)."""
    return " ".join(frame.text() for frame in node.handle(parse_candump(text), now))


# Every error response the node gives: (request frames in order, expected answer to the last one)
ERRORS = [
    # allocation on the group 2 only port
    (["42E#004B03010400"], "42B#0094020 2"),  # bit-strobe requested: resource unavailable, invalid choice
    (["42E#004B03011000"], "42B#00940202"),  # change of state requested
    (["42E#004B03012300"], "42B#00940202"),  # cyclic (+ explicit + polled)
    (["42E#004B03010000"], "42B#00942002"),  # choice 0: invalid parameter
    (["42E#004B03018300"], "42B#00942002"),  # reserved bit 7
    (["42E#004B030103"], "42B#009413FF"),  # allocator MAC missing
    (["42E#004B0301030000"], "42B#009415FF"),  # too much data
    (["42E#004B03010340"], "42B#009420FF"),  # allocator MAC 64
    (["42E#004B03020300"], "42B#009416FF"),  # DeviceNet object instance 2
    (["42E#004B01010300"], "42B#00940803"),  # not the DeviceNet object: the port takes Allocate/Release only
    (["42E#000E010107"], "42B#00940803"),  # Get on the group 2 only port
    (["42E#004B03010300", "42E#074B03010307"], "42B#07940C01"),  # allocated to master 0, master 7 asks
    (["42E#004B03010300", "42E#004B03010100"], "42B#00940B02"),  # explicit already allocated to us
    (["42E#004B03010300", "42E#074C030103"], "42B#07940C01"),  # release by another master
    (["42E#004C030103"], "42B#00940B02"),  # release of nothing allocated
    (["42E#004B03010100", "42E#004C030102"], "42B#00940B02"),  # polled not allocated
    (["42E#004C0301"], "42B#009413FF"),  # release without choice
    # objects through the explicit connection
    (["42E#004B03010300", "42C#000E64010100"], "42B#009405FF"),  # no class 0x64: path destination unknown
    (["42E#004B03010300", "42C#000E010201"], "42B#009416FF"),  # identity instance 2
    (["42E#004B03010300", "42C#000E010108"], "42B#009414FF"),  # identity attribute 8
    (["42E#004B03010300", "42C#0010010101 3303"], "42B#00940EFF"),  # vendor id is not settable
    (["42E#004B03010300", "42C#00330101"], "42B#009408FF"),  # unknown service 0x33
    (["42E#004B03010300", "42C#000E01010100"], "42B#009415FF"),  # Get with extra data
    (["42E#004B03010300", "42C#000E0101"], "42B#009413FF"),  # Get without attribute id
    (["42E#004B03010300", "42C#0010050209 64"], "42B#009413FF"),  # EPR needs a UINT
    (["42E#004B03010300", "42C#0010050209 640000"], "42B#009415FF"),  # EPR too long
    (["42E#004B03010300", "42C#000E050301"], "42B#009416FF"),  # bit-strobe connection does not exist
    (["42E#004B03010100", "42C#000E050201"], "42B#009416FF"),  # polled connection not allocated
    (["42E#004B03010300", "42C#0010050 20C09"], "42B#009409FF"),  # watchdog action 9
    (["42E#004B03010300", "42C#0005010101"], "42B#009420FF"),  # identity reset type 1
    (["42E#004B03010300", "42C#000E020101"], "42B#009414FF"),  # message router has no attributes
    (["42E#004B03010300", "42C#00100466030100"], "42B#00940EFF"),  # outputs only through the polled connection
    (["42E#004B03010300", "42C#0010030101 07"], "42B#00940EFF"),  # MAC id is set on the keypad
]


@pytest.mark.parametrize(("requests", "answer"), ERRORS)
def test_error_responses(jjr8000: Profile, requests: list[str], answer: str) -> None:
    node, _, _ = make_node(jjr8000)
    node.start(0.0)
    node.tick(1.0)
    node.tick(2.0)
    result = ""
    for text in requests:
        result = exchange(node, text.replace(" ", ""))
    assert result == answer.replace(" ", "")
    assert node.counters.error_responses >= 1


def test_success_answers(jjr8000: Profile) -> None:
    node, _, _ = online(jjr8000)
    assert exchange(node, "42C#000E010101") == "42B#008E3303"  # vendor 819
    assert exchange(node, "42C#000E010102") == "42B#008E2D00"  # device type 45
    assert exchange(node, "42C#000E010105") == "42B#008E0100"  # status: owned
    assert exchange(node, "42C#000E030105") == "42B#008E0300"  # allocation: explicit + polled, master 0
    assert exchange(node, "42C#000E030101") == "42B#008E05"  # MAC id 5
    assert exchange(node, "42C#000E030102") == "42B#008E02"  # 500 kbit/s
    assert exchange(node, "42C#000E050201") == "42B#008E03"  # established
    assert exchange(node, "42C#000E05020C") == "42B#008E00"  # watchdog: transition to timed out
    assert exchange(node, "42C#000E050101") == "42B#008E03"  # explicit established
    assert exchange(node, "42C#000E050109") == "42B#008EC409"  # explicit EPR 2500 ms
    assert exchange(node, "42C#000E05020E") == "42B#008E200424653003"  # produced path: assembly 101 attribute 3
    assert exchange(node, "42C#000E046603") == "42B#008E0000"  # output assembly 102 data (2 bytes)
    assert exchange(node, "42C#0010050209 0500".replace(" ", "")) == "42B#00900A00"  # 5 ms rounds up to the 10 ms tick


def test_identity_reset_releases_the_connection_set(jjr8000: Profile) -> None:
    node, _, _ = online(jjr8000)
    assert exchange(node, "42C#0005010100") == "42B#0085"
    assert node.allocation == 0 and node.polled.state is ConnectionState.NON_EXISTENT


def test_fragmented_request_is_reassembled(jjr8000: Profile) -> None:
    """Master -> slave fragmentation: a Set_Attribute_Single with 8 data bytes, acknowledged fragment by fragment."""
    node, _, _ = online(jjr8000)
    assert exchange(node, "42C#8000100101070841") == "42B#80C000"
    assert exchange(node, "42C#80414A5238303030") == "42B#80C100"
    assert exchange(node, "42C#80823030") == "42B#80C200 42B#00940EFF"  # reassembled: attribute 7 not settable
    assert exchange(node, "42C#80413030") == ""  # middle fragment without a first: dropped, no acknowledgement
    assert exchange(node, "42C#8000100101070841") == "42B#80C000"
    assert exchange(node, "42C#80424A52") == ""  # count 2 after 0: out of order, dropped
    assert "out of order" in node.events[-1][1]


def test_unacknowledged_fragment_is_sent_again_then_abandoned(jjr8000: Profile) -> None:
    node, _, _ = online(jjr8000)
    first = exchange(node, "42C#000E010107", now=3.0)
    assert first == "42B#80008E074A4A5238"
    assert node.tick(3.5) == []
    assert [f.text() for f in node.tick(4.0)] == ["42B#80008E074A4A5238"]  # retransmitted once
    assert node.tick(5.0) == []  # then given up
    assert "abandoned" in node.events[-1][1]


def test_polled_watchdog_times_out_and_stops_the_motor(jjr8000: Profile) -> None:
    node, starter, clock = online(jjr8000, epr=100)  # inactivity timeout 400 ms
    assert exchange(node, "42D#0101", 2.1).startswith("3C5#28")  # start
    assert starter.start_count == 1
    clock.advance(60.0)  # the ramp ends: running
    assert exchange(node, "42D#0101", 2.3).startswith("3C5#24")
    assert node.next_deadline() == pytest.approx(2.7)
    assert node.tick(2.69) == [] and polled_state(node) is ConnectionState.ESTABLISHED
    node.tick(2.71)
    assert polled_state(node) is ConnectionState.TIMED_OUT
    assert starter.phase is Phase.STOPPING  # the documented safe state: soft stop, run command dropped
    assert "timed out" in node.events[-1][1]
    assert exchange(node, "42D#0101", 2.8) == ""  # a timed-out connection consumes nothing
    assert exchange(node, "42C#00100502096400", 2.8) == "42B#00940CFF"  # release and allocate again
    assert exchange(node, "42C#004C030103", 2.8) == "42B#00CC"
    assert exchange(node, "42E#004B03010300", 2.8) == "42B#00CB00"
    assert exchange(node, "42C#00100502096400", 2.8) == "42B#00906400"
    clock.advance(100.0)
    assert exchange(node, "42D#0001", 2.9).startswith("3C5#20")  # stopped; the held start bit did not restart it


def test_epr_zero_means_no_watchdog(jjr8000: Profile) -> None:
    node, _, _ = online(jjr8000, epr=0)
    exchange(node, "42D#0101", 2.1)
    node.tick(11.9)  # long silence on the polled connection; the explicit one (10 s) is not due yet
    assert node.polled.state is ConnectionState.ESTABLISHED
    assert node.next_deadline() == pytest.approx(12.0)


def test_explicit_watchdog_releases_the_set(jjr8000: Profile) -> None:
    node, starter, _ = online(jjr8000, epr=1000)
    exchange(node, "42D#0101", 2.5)
    assert node.next_deadline() == pytest.approx(6.5)  # polled: 4 x 1000 ms
    for t in (6.0, 9.0, 11.0):
        exchange(node, "42D#0101", t)  # polls keep the polled connection alive, not the explicit one
    node.tick(12.01)  # explicit: 2500 ms x 4 after allocation at 2.0
    assert node.allocation == 0 and node.master_mac == 0xFF
    assert starter.phase is Phase.STOPPING
    assert exchange(node, "42E#074B03010307", 12.1) == "42B#07CB00"  # another master may take it now


def test_idle_poll_stops_the_motor_and_still_answers(jjr8000: Profile) -> None:
    node, starter, _ = online(jjr8000)
    exchange(node, "42D#0101", 2.1)
    assert exchange(node, "42D#", 2.2).startswith("3C5#")
    assert starter.phase is Phase.STOPPING
    assert exchange(node, "42D#010102", 2.3) == ""  # wrong size: ignored


def test_duplicate_request_while_checking_is_a_collision(jjr8000: Profile) -> None:
    node, _, _ = make_node(jjr8000)
    node.start(0.0)
    node.handle(parse_candump("42F#00330399999999"), 0.5)
    assert node.state is NodeState.COMM_FAULT
    assert "duplicate MAC ID 5" in node.fault_reason
    node.tick(5.0)
    assert node.handle(parse_candump("42E#004B03010300"), 5.0) == []


def test_online_node_answers_requests_and_faults_on_responses(jjr8000: Profile) -> None:
    node, _, _ = online(jjr8000)
    assert exchange(node, "42F#00330399999999") == "42F#80330305011120"
    assert node_state(node) is NodeState.ONLINE
    assert exchange(node, "42F#80330399999999") == ""
    assert node_state(node) is NodeState.COMM_FAULT
    assert node.allocation == 0


def test_bad_duplicate_mac_frame_is_ignored(jjr8000: Profile) -> None:
    node, _, _ = make_node(jjr8000)
    node.start(0.0)
    assert node.handle(CanFrame(0x42F, b"\x00"), 0.1) == []
    assert node.state is NodeState.CHECKING


def test_basic_assemblies_follow_pro_type(jjr8000: Profile) -> None:
    clock = ManualClock(0.0)
    starter = SimulatedStarter(jjr8000, clock)
    app = StarterApplication(starter, assemblies=None, io_refresh=0.0)
    node = SlaveNode(5, app)
    node.start(0.0)
    replay(node, parse_transcript("@ 1\n@ 2\n> 42E#004B03010300\n> 42C#00100502096400"))
    assert exchange(node, "42C#000E050207") == "42B#008E0400"  # PRO type 0 (default): basic, 4 bytes
    assert exchange(node, "42D#01", 2.5) == "3C5#28000000"
    starter.params["profibus_type"] = 1
    assert exchange(node, "42C#000E050207") == "42B#008E0600"
