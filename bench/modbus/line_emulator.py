"""A pty proxy that behaves like an RS485 line: bytes pass no faster than the baud rate (11 bits a character).

    python bench/modbus/line_emulator.py --baud 19200      # or --baud 0: no pacing (a "bare pty" hop)

It creates two pseudo-terminals and prints ``client: /dev/pts/X`` and ``server: /dev/pts/Y``; a Modbus master
opens the first, a slave the second. The line is half-duplex: one wire, each byte occupies it for one
character time and reaches the other side when its last bit would have. Commands on stdin, one per line:
``stats`` prints the statistics since the last ``stats`` as one JSON line (and starts new ones); EOF ends.

Statistics: bytes each way, the master's turnaround gaps (last byte of an answer delivered -> first byte of
the next request received), how many of them are shorter than 3.5 characters (the master broke the silent
interval), the slave's turnaround, collisions (both sides sending at once) and how late bytes were delivered.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import select
import sys
import time
import tty
from collections import deque

BITS_PER_CHAR = 11
PR_SET_TIMERSLACK = 29


def precise_timers() -> str:
    """Ask for 1 us timer slack (default 50 us) and a real-time priority where allowed: a line does not pause.

    Without them a busy 2-core machine sometimes delivers a byte milliseconds late, which a slave rightly
    takes as the end of a (truncated) frame. Returns what was granted, for the statistics.
    """
    granted = []
    try:
        ctypes.CDLL(None).prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0)
        granted.append("timerslack 1us")
    except (OSError, AttributeError):
        pass
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        granted.append("SCHED_FIFO")
    except (OSError, AttributeError):
        pass
    return ", ".join(granted) or "none"


class Stats:
    def __init__(self) -> None:
        self.bytes_to_server = 0
        self.bytes_to_client = 0
        self.master_gaps: list[float] = []
        self.slave_gaps: list[float] = []
        self.collisions = 0
        self.max_late = 0.0
        self.started = time.monotonic()
        self.scheduling = ""

    def summary(self, silence: float) -> dict[str, object]:
        def describe(gaps: list[float]) -> dict[str, object]:
            if not gaps:
                return {"count": 0}
            ordered = sorted(gaps)
            return {
                "count": len(gaps),
                "min_ms": ordered[0] * 1000,
                "median_ms": ordered[len(ordered) // 2] * 1000,
                "below_silence": sum(1 for g in gaps if g < silence),
                "p99_ms": ordered[len(ordered) * 99 // 100] * 1000,  # (a line's rare stalls, which a median hides)
                "max_ms": ordered[-1] * 1000,
            }

        return {
            "seconds": time.monotonic() - self.started,
            "bytes_to_server": self.bytes_to_server,
            "bytes_to_client": self.bytes_to_client,
            "master_turnaround": describe(self.master_gaps),
            "slave_turnaround": describe(self.slave_gaps),
            "collisions": self.collisions,
            "max_late_ms": self.max_late * 1000,
            "silence_ms": silence * 1000,
            "scheduling": self.scheduling,
        }


def open_pty() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


def run(baud: int, spin: float) -> None:
    scheduling = precise_timers()
    client_m, _client_s, client_path = open_pty()
    server_m, _server_s, server_path = open_pty()
    print(f"client: {client_path}", flush=True)
    print(f"server: {server_path}", flush=True)
    char = BITS_PER_CHAR / baud if baud else 0.0
    silence = 3.5 * BITS_PER_CHAR / (baud or 19200) if (baud or 19200) <= 19200 else 0.00175
    stats = Stats()
    pending: deque[tuple[float, int, bytes, str]] = deque()  # (deliver at, to fd, byte, "c2s" | "s2c")
    wire_free = 0.0
    wire_dir = ""  # direction of the byte on the wire / last sent
    last_delivered = {"c2s": 0.0, "s2c": 0.0}
    stdin = sys.stdin.fileno()
    watch = [client_m, server_m, stdin]
    while True:
        now = time.monotonic()
        timeout = None if not pending else max(0.0, pending[0][0] - now - (spin if len(pending) == 1 else 0.0))
        ready, _, _ = select.select(watch, [], [], timeout)
        arrived = time.monotonic()
        for fd in ready:
            if fd == stdin:
                line = sys.stdin.readline()
                if not line:
                    return
                if line.strip() == "stats":
                    stats.scheduling = scheduling
                    print(json.dumps(stats.summary(silence)), flush=True)
                    stats = Stats()
                continue
            try:
                data = os.read(fd, 4096)
            except (BlockingIOError, OSError):
                continue
            direction, target = ("c2s", server_m) if fd == client_m else ("s2c", client_m)
            if direction == "c2s":
                stats.bytes_to_server += len(data)
            else:
                stats.bytes_to_client += len(data)
            if direction != wire_dir:  # a turnaround: the other side starts talking
                if wire_free > arrived and pending:
                    stats.collisions += 1
                other = "s2c" if direction == "c2s" else "c2s"
                if last_delivered[other]:
                    gap = arrived - last_delivered[other]
                    (stats.master_gaps if direction == "c2s" else stats.slave_gaps).append(gap)
                wire_dir = direction
            for value in data:
                start = max(arrived, wire_free)
                wire_free = start + char
                pending.append((wire_free, target, bytes((value,)), direction))
        if pending and spin and len(pending) == 1:
            while time.monotonic() < pending[0][0]:  # the last byte of a frame: be exact
                pass
        now = time.monotonic()
        while pending and pending[0][0] <= now:
            due, target, byte, direction = pending.popleft()
            delivered = time.monotonic()  # the byte is the receiver's from this instant
            os.write(target, byte)
            last_delivered[direction] = delivered
            stats.max_late = max(stats.max_late, delivered - due)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baud", type=int, default=19200, help="0: no pacing")
    parser.add_argument("--spin", type=float, default=0.0, help="busy-wait this long before a frame's last byte")
    args = parser.parse_args()
    run(args.baud, args.spin if args.baud else 0.0)


if __name__ == "__main__":
    main()
