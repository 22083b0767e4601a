"""A slave that repeats good answers, through a paced line: how many foreign values get through (issue 25, item 7).

    python bench/modbus/repeats.py [--reads 2570] [--bauds 19200,9600] [--timeout 0.05] [--seed 1]
                                   [--repeat-share 0.15] [--rules on,off]

A scripted slave (this script with ``--slave``, its own process) serves FC03 through ``line_emulator.py`` (bytes
no faster than the baud rate, one half-duplex wire) and puts in every register the number of the request it
answers. Per request, on a fixed random schedule: no answer (10 %), a late answer (10 %: after the master's
deadline by 0.1-0.9 timeouts, inside the quarantine), else a good answer after the silence, which with
``--repeat-share`` it sends AGAIN 5 ms to 1.5 timeouts later. The master (``read_registers`` of two registers,
every read the same shape, ``wire_check=on``, ``retries=1``, quarantine = timeout) checks every value against
the request it sent last; a value from another request is counted as wrong, by what the slave did with that
request (repeated, late).

``--rules off`` runs the same with rule 5 (a line seen repeating an answer is quarantined after answers too)
turned off, for the figures before it. Not run by the tests.
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import random
import select
import subprocess
import sys
import time
import tty
from pathlib import Path

HERE = Path(__file__).resolve().parent
SILENT, LATE = 0.10, 0.10


def slave(path: str, baud: int, timeout: float, seed: int, repeat_share: float) -> None:
    """Serve FC03 on ``path`` until stdin closes; print what was done with each request as one JSON line."""
    from starterbus.transports.modbus.codec.frames import ReadResponse

    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    char = 11 / baud
    silence = 3.5 * char
    rng = random.Random(seed)
    due: list[tuple[float, int, bytes]] = []  # (when, order, bytes) to write
    fates: list[str] = []  # what was done with each request: ok, silent, late, repeated
    buffer = b""
    order = 0
    stdin = sys.stdin.fileno()
    while True:
        wait = max(0.0, due[0][0] - time.monotonic()) if due else None
        ready = select.select([fd, stdin], [], [], wait)[0]
        now = time.monotonic()
        if stdin in ready and not os.read(stdin, 1024):
            break
        if fd in ready:
            try:
                buffer += os.read(fd, 256)
            except BlockingIOError:
                pass
        while len(buffer) >= 8:
            frame, buffer = buffer[:8], buffer[8:]
            seq = len(fates)
            answer = ReadResponse(frame[0], tuple((seq + k) & 0xFFFF for k in range(frame[5]))).encode()
            draw = rng.random()
            if draw < SILENT:
                fates.append("silent")
                continue
            order += 1
            if draw < SILENT + LATE:
                fates.append("late")
                late = now + timeout + len(answer) * char + rng.uniform(0.1, 0.6) * timeout  # inside the quarantine
                heapq.heappush(due, (late, order, answer))
                continue
            heapq.heappush(due, (now + silence, order, answer))
            if rng.random() < repeat_share:
                fates.append("repeated")
                later = now + silence + len(answer) * char + rng.uniform(0.005, 1.5 * timeout)
                order += 1
                heapq.heappush(due, (later, order, answer))
            else:
                fates.append("ok")
        while due and due[0][0] <= time.monotonic():
            os.write(fd, heapq.heappop(due)[2])
    print(json.dumps(fates), flush=True)


def measure(baud: int, reads: int, timeout: float, seed: int, repeat_share: float, rules: bool) -> dict[str, object]:
    from starterbus.core.device import open_device
    from starterbus.core.errors import StarterbusError
    from starterbus.transports.modbus.master import guard

    if not rules:  # rule 5 off: a repeat seen changes nothing
        guard.LineGuard.repeat_seen = lambda self, quarantine: None  # type: ignore[method-assign]
    emulator = subprocess.Popen(
        [sys.executable, str(HERE / "line_emulator.py"), "--baud", str(baud)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert emulator.stdout is not None and emulator.stdin is not None
    client = emulator.stdout.readline().split(": ", 1)[1].strip()
    server = emulator.stdout.readline().split(": ", 1)[1].strip()
    peer = subprocess.Popen(
        [sys.executable, __file__, "--slave", server, "--bauds", str(baud), "--timeout", str(timeout),
         "--seed", str(seed), "--repeat-share", str(repeat_share)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    url = f"modbus-rtu://{client}?unit=2&baudrate={baud}&timeout={timeout}&retries=1&wire_check=on"
    rng = random.Random(seed)
    values = errors = 0
    wrong: list[tuple[int, int]] = []  # (request sent last, request whose answer was returned)
    started = time.monotonic()
    with open_device(url, "jjr5000") as device:
        transport = device.transport
        line = transport.line  # type: ignore[attr-defined]
        for _ in range(reads):
            try:
                got = transport.read_registers(rng.randrange(0x1000), 2)  # type: ignore[attr-defined]
            except StarterbusError:
                errors += 1
                continue
            seq = line.requests - 1
            if got == ((seq) & 0xFFFF, (seq + 1) & 0xFFFF):
                values += 1
            else:
                wrong.append((seq, got[0]))
        guard_ = line.guard  # the code before rule 5 has neither attribute
        repeats_seen, suspect = getattr(guard_, "repeats", None), getattr(guard_, "suspect", None)
    elapsed = time.monotonic() - started
    assert peer.stdin is not None and peer.stdout is not None
    peer.stdin.close()
    fates: list[str] = json.loads(peer.stdout.readline())
    peer.wait(timeout=10)
    emulator.stdin.close()
    emulator.wait(timeout=10)
    kinds: dict[str, int] = {}
    for seq, origin in wrong:
        kind = fates[origin] if 0 <= origin < len(fates) else "?"
        kind += " -> " + (fates[seq] if 0 <= seq < len(fates) else "?")  # and what the current request got
        kinds[kind] = kinds.get(kind, 0) + 1
    return {
        "baud": baud, "rule 5": "on" if rules else "off", "reads": reads, "values": values, "errors": errors,
        "wrong": len(wrong), "wrong by kind": kinds, "repeated answers sent": fates.count("repeated"),
        "repeats seen": repeats_seen, "suspect at the end": suspect, "reads/s": round(reads / elapsed, 1),
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=2570)
    parser.add_argument("--bauds", default="19200,9600")
    parser.add_argument("--timeout", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat-share", type=float, default=0.15, help="good answers sent a second time")
    parser.add_argument("--rules", default="on,off", help="rule 5 on, off, or both (on,off)")
    parser.add_argument("--slave", metavar="PATH", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.slave:
        slave(args.slave, int(args.bauds), args.timeout, args.seed, args.repeat_share)
        return
    for rules in args.rules.split(","):
        for baud in (int(b) for b in args.bauds.split(",")):
            # each case in its own process: turning the rule off patches the guard class
            out = subprocess.run(
                [sys.executable, __file__, "--case", str(baud), rules, str(args.reads), str(args.timeout),
                 str(args.seed), str(args.repeat_share)],
                check=True, capture_output=True, text=True,
            )  # fmt: skip
            print(out.stdout.strip(), flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--case":
        baud, rules, reads, timeout, seed, share = sys.argv[2:8]
        result = measure(int(baud), int(reads), float(timeout), int(seed), float(share), rules == "on")
        print(json.dumps(result))
    else:
        main()
