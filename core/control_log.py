"""The record of control outputs that reach a simulated starter: how tests prove that a read never actuates.

What counts (the manuals' control word, docs/manuals.md#1-common-model: bit 0 start / soft stop, bit 2 fault
reset, bit 3 bus control, where bit 3 = 0 is "no operation"):

One-off writes of the control word (Modbus FC06 to the control register) always count: the device acts on
their levels, so even 0x0000 is a soft stop for a JJR5000.

Cyclic writes (Profibus PZD STW, DeviceNet poll output, CANopen RPDO) count when they are not "no operation"
and not the word already in force: when they set the start, reset or bus-control bit, or clear a run bit that
was in force (a stop). A DP master (a gateway) must send an STW on every cycle; 0x0000 there is the manuals'
"no operation" and a master that only reads sends exactly that, so it does not count. A cyclic master holding
one word is one output, counted when the word first reached the starter.

A lost command connection (``command_lost``: a polled I/O connection timed out or was released, a CANopen
master's heartbeat lost) counts when it drops a run command, because the motor soft-stops.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from starterbus.core.status import CW_BUS_CONTROL, CW_RESET, CW_START, describe_control_word

COMMAND_BITS = CW_START | CW_RESET | CW_BUS_CONTROL
LOG_SIZE = 256  # records kept; ``total`` counts every one


@dataclass(frozen=True, slots=True)
class ControlWrite:
    """One control output that reached the starter."""

    time: float  # the starter's clock
    word: int  # the control word written (after a lost connection: the word left in force)
    cyclic: bool
    source: str = ""  # the front end's description (protocol, service), "" if it gives none
    lost: bool = False  # a lost command connection dropped the run command

    def describe(self) -> str:
        if self.lost:
            return f"run command dropped ({self.source or 'command connection lost'}) at t={self.time:g}"
        how = "cyclic" if self.cyclic else "one-off"
        where = f" from {self.source}" if self.source else ""
        bits = ", ".join(describe_control_word(self.word))
        return f"control word 0x{self.word:04X} ({bits}; {how}{where}) at t={self.time:g}"


def counts(word: int, previous: int, *, cyclic: bool) -> bool:
    """Whether writing ``word`` over ``previous`` (the word in force) is a control output (the rules above)."""
    if not cyclic:
        return True
    if word == previous:
        return False
    return bool(word & COMMAND_BITS) or bool(previous & CW_START)


class ControlLog:
    """The last :data:`LOG_SIZE` control outputs and how many there were in all. Not locked: its owner's lock
    (the starter's) guards it."""

    def __init__(self, size: int = LOG_SIZE) -> None:
        self.records: deque[ControlWrite] = deque(maxlen=size)
        self.total = 0

    def add(self, record: ControlWrite) -> None:
        self.records.append(record)
        self.total += 1

    def since(self, mark: int) -> list[ControlWrite]:
        """The records added after ``total`` was ``mark`` (as many as are still kept)."""
        new = self.total - mark
        return list(self.records)[-new:] if new > 0 else []
