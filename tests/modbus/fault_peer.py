"""A scripted RTU slave that misbehaves on schedule and says, in every register, which request it answers.

The peer numbers the requests it receives (0, 1, 2, ...); the answer to request ``seq`` holds ``seq + k`` in its
register ``k``. A master that returns values can therefore be checked: they must come from the request it sent
last (its own count of frames written), never from an earlier one.

Faults (one per request, from a schedule that repeats): an answer that is slow (within the timeout), split in
pieces, late (after the master's deadline, by a varying margin), late and split, sent twice back to back,
followed by trailing bytes, preceded by garbage, with a bad CRC, from another unit, an exception, or none.

The peer stays inside the fault model the master's rules are built for: a late answer arrives before the
master's quarantine can have ended (up to 0.7 of the quarantine after the master's deadline, reckoned from the
master's own start of the request, which :meth:`SequencePeer.watch` records as the master writes it; the rest
is slack for the moment between the peer's last look at the clock and its write). If the peer was held up
beyond that before a write (a loaded machine), it skips the bytes and counts them in
:attr:`SequencePeer.skipped`. If it was held up between its look at the clock and the end of the write, the
bytes may have reached the line after the model's bound: every write is recorded with the clock read just
after it (:attr:`SequencePeer.writes`), :meth:`SequencePeer.written_late` tells which requests' bytes may
have left the model (a stray taken for an answer then is the documented residual, a frame shaped like the
answer that arrives after the quarantine: counted as such, not as a pass or a failure by luck), and
:attr:`SequencePeer.off_script` which requests did not go as scripted (for tests that assert what a scripted
case must give).
"""

from __future__ import annotations

import os
import random
import select
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadResponse
from starterbus.transports.modbus.codec.timing import char_time

FAULTS = (
    "slow", "split", "late", "late_split", "twice", "trailing", "garbage", "crc", "wrong_unit", "exception", "silent",
)  # fmt: skip
#: what a schedule entry is drawn from: a good answer two times in three
CHOICES = ("ok",) * (2 * len(FAULTS)) + FAULTS
Step = tuple[str, float]  # (fault, a number in [0, 1) that varies its timing or bytes)


@dataclass(frozen=True)
class Written:
    """One write of the peer's: the bytes about request ``seq``, the clock just before and just after
    ``os.write`` (the bytes were in the line between the two), and the model's bound for them."""

    seq: int
    data: bytes
    before: float
    after: float
    latest: float

    @property
    def late(self) -> bool:
        """The write may have ended after the model's bound: the peer was held up between its look at the clock
        and the end of the write."""
        return self.after > self.latest


def answer_for(seq: int, unit: int, count: int) -> bytes:
    return ReadResponse(unit, tuple((seq + k) & 0xFFFF for k in range(count))).encode()


class SequencePeer:
    """Serves FC03 requests on ``fd`` (a pty's master side or a connected socket) in a thread."""

    def __init__(
        self, fd: int, schedule: Sequence[Step], *, timeout: float, quarantine: float, baudrate: int, seed: int = 0
    ) -> None:
        self.fd = fd
        self.schedule = list(schedule) or [("ok", 0.0)]
        self.timeout = timeout
        self.quarantine = quarantine
        self.char_time = char_time(baudrate)
        self.rng = random.Random(seed)
        self.requests: list[tuple[int, int]] = []  # (address, count) by sequence number
        self.sent_at: list[float] = []  # when the master wrote each request (see watch)
        self.deadlines: list[float] = []  # when the master gives up on each request (from sent_at when watched)
        self.skipped = 0
        self.writes: list[Written] = []  # every write, in order
        #: requests whose bytes did not reach the line when the script meant them to (skipped, written after the
        #: model's bound, or an answer meant to be in time that ended after the master's deadline): the peer or
        #: the master was held up by a loaded machine
        self.off_script: set[int] = set()
        self._written = threading.Condition()  # notified when the master writes a request
        self._hold: tuple[int, int] | None = None  # see hold
        self.sent_faults: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sequence peer", daemon=True)

    def watch(self, link: object, started: Callable[[], float] = time.monotonic) -> None:
        """Record when ``link`` (the master's) writes each request: ``started()`` read as it does (the master's
        own start time, its deadline's base, when the line's guard is given; else the clock, just before the
        write). Hooked at the link's file write where it has one (the fast path's ``transfer`` writes through
        it), else at its ``write``."""
        name = "_write" if hasattr(link, "_write") else "write"
        write = getattr(link, name)

        def recorded(data: bytes | memoryview) -> object:
            if not isinstance(data, memoryview):  # a memoryview is the rest of a frame partly written
                with self._written:
                    self.sent_at.append(started())
                    self._written.notify_all()
            return write(data)

        setattr(link, name, recorded)

    def hold(self, seq: int, until_request: int) -> None:
        """A loaded machine, scripted: the peer is held up between its look at the clock and its write of the
        bytes about request ``seq`` until the master has written request ``until_request`` (needs :meth:`watch`)."""
        self._hold = (seq, until_request)

    def _wait_for_request(self, seq: int) -> None:
        with self._written:
            self._written.wait_for(lambda: len(self.sent_at) > seq, timeout=5)

    def written_late(self, seq: int, since: float = 0.0) -> bool:
        """True if bytes about request ``seq`` may have reached the line after the model's bound, with the write
        ending after ``since`` (a stray the master must have seen before ``since`` is no excuse)."""
        return any(w.seq == seq and w.late and w.after > since for w in self.writes)

    def describe(self, *seqs: int) -> str:
        """What the peer did about requests ``seqs`` (for a failure message), times relative to the first."""
        zero = self.sent_at[0] if self.sent_at else 0.0
        parts = []
        for seq in seqs:
            sent = f"{(self.sent_at[seq] - zero) * 1000:.2f}" if 0 <= seq < len(self.sent_at) else "?"
            fault = self.schedule[seq % len(self.schedule)] if seq >= 0 else None
            writes = [
                f"{w.data.hex(' ')} in {(w.before - zero) * 1000:.2f}-{(w.after - zero) * 1000:.2f}"
                f" (bound {(w.latest - zero) * 1000:.2f})"
                for w in self.writes
                if w.seq == seq
            ]
            parts.append(f"#{seq} {fault} sent at {sent} ms, peer wrote {writes or 'nothing'}")
        return "; ".join(parts)

    def start(self) -> SequencePeer:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def _readable(self, wait: float) -> bool:
        return bool(select.select([self.fd], [], [], wait)[0])

    def _read_request(self) -> bytes | None:
        data = b""
        while len(data) < 8:
            if self._stop.is_set():
                return None
            if self._readable(0.05):
                chunk = os.read(self.fd, 8 - len(data))
                if not chunk:
                    return None
                data += chunk
        return data

    def _run(self) -> None:
        try:
            while True:
                frame = self._read_request()
                if frame is None:
                    return
                self._answer(frame, time.monotonic())
        except OSError:
            return  # the master closed its side

    def _answer(self, frame: bytes, arrival: float) -> None:
        seq = len(self.requests)
        unit, _, address, count = struct.unpack(">BBHH", frame[:6])
        self.requests.append((address, count))
        fault, x = self.schedule[seq % len(self.schedule)]
        answer = answer_for(seq, unit, count)
        # the master gives up at its deadline (request and answer wire time + timeout) and then quarantines
        sent = self.sent_at[seq] if seq < len(self.sent_at) else arrival
        deadline = sent + (8 + len(answer)) * self.char_time + self.timeout
        latest = deadline + 0.7 * self.quarantine  # the model's bound for any byte about this request
        self.deadlines.append(deadline)
        pieces: list[bytes | float] = []
        if fault == "ok":
            pieces = [answer]
        elif fault == "slow":
            pieces = [0.5 * x * self.timeout, answer]
        elif fault == "split":
            cut = 1 + int(x * (len(answer) - 1))
            pieces = [answer[:cut], 0.2 * x * self.timeout, answer[cut:]]
        elif fault in ("late", "late_split"):
            wait = deadline - time.monotonic() + 0.0005 + x * 0.55 * self.quarantine
            cut = len(answer) // 2 if fault == "late_split" else len(answer)
            pieces = [wait, answer[:cut], 0.05 * self.quarantine, answer[cut:]]
        elif fault == "twice":
            pieces = [answer + answer]
        elif fault == "trailing":
            pieces = [answer + self.rng.randbytes(1 + int(x * 3))]
        elif fault == "garbage":
            pieces = [self.rng.randbytes(1 + int(x * 6)) + answer]
        elif fault == "crc":
            pieces = [answer[:-1] + bytes([answer[-1] ^ (1 + int(x * 254))])]
        elif fault == "wrong_unit":
            pieces = [answer_for(seq, unit + 1, count)]
        elif fault == "exception":
            pieces = [ExceptionResponse(unit, 3, 2).encode()]
        self.sent_faults[fault] = self.sent_faults.get(fault, 0) + 1
        in_time = fault not in ("late", "late_split", "silent")  # the answer is meant to beat the deadline
        for piece in pieces:
            if isinstance(piece, float):
                if piece > 0:
                    time.sleep(piece)
            elif piece:
                before = time.monotonic()
                if before > latest:
                    self.skipped += 1  # outside the fault model (the peer was held up): send nothing more
                    self.off_script.add(seq)
                    return
                if self._hold is not None and self._hold[0] == seq:
                    self._wait_for_request(self._hold[1])
                os.write(self.fd, piece)
                written = Written(seq, piece, before, time.monotonic(), latest)
                self.writes.append(written)
                if written.late or (in_time and written.after > deadline):
                    self.off_script.add(seq)
