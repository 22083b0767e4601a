"""A scripted RTU slave that misbehaves on schedule and says, in every register, which request it answers.

The peer numbers the requests it receives (0, 1, 2, ...); the answer to request ``seq`` holds ``seq + k`` in its
register ``k``. A master that returns values can therefore be checked: they must come from the request it sent
last (its own count of frames written), never from an earlier one.

Faults (one per request, from a schedule that repeats): an answer that is slow (within the timeout), split in
pieces, late (after the master's deadline, by a varying margin), late and split, sent twice back to back,
followed by trailing bytes, preceded by garbage, with a bad CRC, from another unit, an exception, or none.

The peer stays inside the fault model the master's rules are built for: a late answer arrives before the
master's quarantine can have ended (up to 0.7 of the quarantine after the master's deadline, reckoned from
when the master wrote the request: :meth:`SequencePeer.watch` records it; the rest is slack for the moment
between the peer's last look at the clock and its write). If the peer was held up beyond that (a loaded
machine), it skips the bytes and counts them in :attr:`SequencePeer.skipped` instead of breaking the model.
"""

from __future__ import annotations

import os
import random
import select
import struct
import threading
import time
from collections.abc import Sequence

from starterbus.transports.modbus.frames import ExceptionResponse, ReadResponse
from starterbus.transports.modbus.timing import char_time

FAULTS = (
    "slow", "split", "late", "late_split", "twice", "trailing", "garbage", "crc", "wrong_unit", "exception", "silent",
)  # fmt: skip
#: what a schedule entry is drawn from: a good answer two times in three
CHOICES = ("ok",) * (2 * len(FAULTS)) + FAULTS
Step = tuple[str, float]  # (fault, a number in [0, 1) that varies its timing or bytes)


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
        self.skipped = 0
        self.sent_faults: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sequence peer", daemon=True)

    def watch(self, link: object) -> None:
        """Record when ``link`` (the master's) writes each request, just before it does."""
        write = link.write  # type: ignore[attr-defined]

        def recorded(data: bytes) -> None:
            self.sent_at.append(time.monotonic())
            write(data)

        link.write = recorded  # type: ignore[attr-defined]

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
        for piece in pieces:
            if isinstance(piece, float):
                if piece > 0:
                    time.sleep(piece)
            elif piece:
                if time.monotonic() > latest:
                    self.skipped += 1  # outside the fault model (the peer was held up): send nothing more
                    return
                os.write(self.fd, piece)
