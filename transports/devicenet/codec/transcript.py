"""Frame transcripts: ``id#data`` lines with a direction, to replay against a sans-IO node.

A transcript line is ``> 42E#004B03010300`` (a frame the node receives), ``< 42B#00CB00`` (a frame the node
must send in answer), ``@ 1.25`` (the time moves to 1.25 s: the node's timers run) or a comment (``#`` at the
start) / blank line. :func:`replay` feeds the received frames to a sans-IO node (the slave's
:class:`~starterbus.transports.devicenet.slave.node.SlaveNode` or the master's
:class:`~starterbus.transports.devicenet.master.node.MasterNode`) and returns what it sent, so a test compares
that with the ``<`` lines; the frames can be interleaved with garbage (frames for other nodes, malformed
frames) that must not change the answers.

:class:`Wire` is an in-memory CAN bus between sans-IO nodes with a fed clock: every frame a node sends reaches
every other node at once, in order, and the time only moves when the test says so.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from starterbus.core import CanFrame, DecodeError
from starterbus.transports.devicenet.codec.frames import parse_candump


class Node(Protocol):
    """A sans-IO DeviceNet node: frames and times in, frames out."""

    def handle(self, frame: CanFrame, now: float) -> list[CanFrame]: ...

    def tick(self, now: float) -> list[CanFrame]: ...


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


def replay(node: Node, steps: Sequence[Step], garbage: Iterable[CanFrame] = (), start: float = 0.0) -> list[CanFrame]:
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


@dataclass
class Wire:
    """An in-memory bus: ``add`` nodes, ``send`` what one of them said, ``run`` the clock forward."""

    now: float = 0.0
    step: float = 0.001
    nodes: dict[str, Node] = field(default_factory=dict)
    log: list[tuple[float, str, CanFrame]] = field(default_factory=list)  # (time, sender, frame)

    def add(self, name: str, node: Node, frames: Iterable[CanFrame] = ()) -> None:
        """Connect ``node`` (and put its start-up ``frames`` on the bus)."""
        self.nodes[name] = node
        self.send(name, frames)

    def remove(self, name: str) -> None:
        """Disconnect a node (power off: it neither hears nor says anything any more)."""
        del self.nodes[name]

    def send(self, sender: str, frames: Iterable[CanFrame]) -> None:
        queue = deque((sender, frame) for frame in frames)
        while queue:
            source, frame = queue.popleft()
            self.log.append((self.now, source, frame))
            for name, node in list(self.nodes.items()):
                if name != source:
                    queue.extend((name, answer) for answer in node.handle(frame, self.now))

    def run(self, until: float) -> None:
        """Move the clock to ``until`` in steps of ``step``, running every node's timers at each."""
        while self.now < until - 1e-12:
            self.now = min(round(self.now + self.step, 9), until)
            for name, node in list(self.nodes.items()):
                self.send(name, node.tick(self.now))

    def frames(self, sender: str | None = None, since: float = 0.0) -> list[str]:
        """candump texts of what was on the bus (from ``sender`` only, if given) since a time."""
        return [f.text() for t, s, f in self.log if t >= since and (sender is None or s == sender)]
