"""Frame transcripts: ``id#data`` lines with a direction, to replay against a sans-IO node.

A transcript line is ``> 42E#004B03010300`` (a frame the node receives), ``< 42B#00CB00`` (a frame the node
must send in answer), ``@ 1.25`` (the time moves to 1.25 s: the node's timers run) or a comment (``#`` at the
start) / blank line. :func:`replay` feeds the received frames to a :class:`~starterbus.transports.devicenet.
slave_node.SlaveNode` and returns what it sent, so a test compares that with the ``<`` lines; the frames can
be interleaved with garbage (frames for other nodes, malformed frames) that must not change the answers.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from starterbus.core.errors import DecodeError
from starterbus.transports.devicenet.frames import CanFrame, parse_candump
from starterbus.transports.devicenet.slave_node import SlaveNode


@dataclass(frozen=True, slots=True)
class Step:
    kind: str  # ">" received by the node, "<" sent by the node, "@" time
    frame: CanFrame | None = None
    time: float = 0.0


def parse_transcript(text: str) -> list[Step]:
    steps = []
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("  #", 1)[0].strip()
        if not line or line.startswith("#"):
            continue
        kind, _, rest = line.partition(" ")
        if kind == "@":
            try:
                steps.append(Step("@", time=float(rest)))
            except ValueError:
                raise DecodeError(f"line {number}: {rest!r} is not a time", raw.encode(), "transcript") from None
        elif kind in (">", "<"):
            steps.append(Step(kind, parse_candump(rest)))
        else:
            raise DecodeError(f"line {number}: expected '>', '<' or '@' first", raw.encode(), "transcript")
    return steps


def expected(steps: Sequence[Step]) -> list[CanFrame]:
    return [step.frame for step in steps if step.kind == "<" and step.frame is not None]


def replay(
    node: SlaveNode, steps: Sequence[Step], garbage: Iterable[CanFrame] = (), start: float = 0.0
) -> list[CanFrame]:
    """Feed the ``>`` frames (each preceded by the garbage frames, if any) and ``@`` times to ``node``;
    returns every frame the node sent, in order (its start-up frames excluded)."""
    junk = list(garbage)
    now = start
    sent: list[CanFrame] = []
    for step in steps:
        if step.kind == "@":
            now = step.time
            sent += node.tick(now)
        elif step.kind == ">" and step.frame is not None:
            for frame in junk:
                sent += node.handle(frame, now)
            sent += node.handle(step.frame, now)
    return sent
