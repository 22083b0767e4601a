"""The sans-IO master against transcripts with fed time: start-up, the duplicate MAC ID rules of an on-line
master, the communication fault and its reset, a connection and a rogue responder, any frames at all (a
property). On a wire with sans-IO slaves: test_master_node_wire.py."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starterbus.core import CanFrame
from starterbus.transports.devicenet.codec.frames import parse_candump
from starterbus.transports.devicenet.codec.transcript import expected, parse_transcript, replay
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
from starterbus.transports.devicenet.master.node import MasterNode

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
