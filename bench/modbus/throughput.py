"""Modbus RTU masters side by side: starterbus, pymodbus (sync, async), minimalmodbus, hand-written loops.

    python bench/modbus/throughput.py [--seconds 2] [--repeat 2] [--bauds 9600,19200] [--only line|bare]
                                      [--changing]

1. Through a line emulator (``line_emulator.py``: a pty proxy pacing bytes at 11 bits per character, one
   half-duplex wire) against the starterbus simulator (``starterbus simulate --modbus-rtu PATH``), which waits
   the 3.5-character silence before answering: FC03 (4 registers) and FC06 transactions per second, each as a
   fraction of the physical limit = wire time of request + response + two 3.5-character silences.
2. Through a bare pty hop (the same proxy without pacing) against a plain pymodbus server: transactions per
   second and CPU per transaction, nominal line 19200 baud. The registers keep their values (parameters);
   ``--changing``: every FC03 answer differs from the one before (a running motor's currents).

For every client the emulator measures the master's turnaround (answer delivered -> next request) and counts
those shorter than 3.5 characters: "keeps silence" is "yes" only if there were none. Not run by the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
CLIENTS = [
    "starterbus", "starterbus-device", "pymodbus-sync", "pymodbus-async", "minimalmodbus", "exact-silence",
    "exact-nosilence",
]  # fmt: skip
FRAMES = {"fc03": (8, 13), "fc06": (8, 8)}  # request, response bytes


@dataclass
class Result:
    client: str
    tx: int
    errors: int
    wall: float
    cpu: float
    gaps: dict[str, object]

    @property
    def rate(self) -> float:
        return self.tx / self.wall if self.wall else 0.0

    @property
    def cpu_per_tx_us(self) -> float:
        return self.cpu / self.tx * 1e6 if self.tx else float("nan")

    @property
    def keeps_silence(self) -> str:
        below = int(self.gaps.get("below_silence", 0))  # type: ignore[call-overload]
        count = int(self.gaps.get("count", 0))  # type: ignore[call-overload]
        if not count:
            return "?"
        if below == 0:
            return "yes"
        return f"no ({below}/{count})"


class Emulator:
    def __init__(self, baud: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(HERE / "line_emulator.py"), "--baud", str(baud)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.proc.stdout is not None
        self.client = self.proc.stdout.readline().split(": ", 1)[1].strip()
        self.server = self.proc.stdout.readline().split(": ", 1)[1].strip()

    def stats(self) -> dict[str, object]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write("stats\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())  # type: ignore[no-any-return]

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=10)


def start_server(kind: str, path: str, baud: int, changing: bool = False) -> subprocess.Popen[str]:
    if kind == "starterbus":
        cmd = [sys.executable, "-m", "starterbus.cli.main", "simulate", "--model", "jjr5000", "--unit", "2",
               "--modbus-rtu", path, "--baudrate", str(baud)]  # fmt: skip
    else:
        cmd = [sys.executable, str(HERE / "pymodbus_server.py"), path, "--baud", str(baud)]
        cmd += ["--changing"] if changing else []
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    if kind == "starterbus":
        assert proc.stdout is not None
        proc.stdout.readline()  # "modbus-rtu: PATH": serving
    return proc


def wait_ready(path: str, baud: int) -> None:
    from starterbus.core.device import open_device

    deadline = time.monotonic() + 10
    while True:
        try:
            with open_device(f"modbus-rtu://{path}?unit=2&baudrate={baud}&timeout=0.2", "jjr5000") as device:
                device.transport.read_registers(0x0100, 1)  # type: ignore[attr-defined]
            return
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def run_best(client: str, path: str, op: str, baud: int, seconds: float, emulator: Emulator, repeat: int) -> Result:
    """Best of ``repeat`` runs for the rate (as timeit does); silence violations and errors of every run count."""
    runs = [run_client(client, path, op, baud, seconds, emulator) for _ in range(repeat)]
    best = max(runs, key=lambda r: r.rate)
    below = sum(int(r.gaps.get("below_silence", 0)) for r in runs)  # type: ignore[call-overload]
    count = sum(int(r.gaps.get("count", 0)) for r in runs)  # type: ignore[call-overload]
    mins = [float(r.gaps["min_ms"]) for r in runs if "min_ms" in r.gaps]  # type: ignore[arg-type]
    gaps: dict[str, object] = {"count": count, "below_silence": below}
    if mins:
        gaps["min_ms"] = min(mins)
    return Result(best.client, best.tx, sum(r.errors for r in runs), best.wall, best.cpu, gaps)


def run_client(client: str, path: str, op: str, baud: int, seconds: float, emulator: Emulator) -> Result:
    emulator.stats()  # start fresh statistics
    out = subprocess.run(
        [sys.executable, str(HERE / "clients.py"), client, path, "--op", op, "--baud", str(baud),
         "--seconds", str(seconds)],
        check=False, capture_output=True, text=True, timeout=seconds + 60,
    )  # fmt: skip
    gaps = emulator.stats()["master_turnaround"]
    if out.returncode != 0 or not out.stdout.strip():
        print(f"  {client}: failed: {out.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
        return Result(client, 0, 1, seconds, 0.0, gaps)  # type: ignore[arg-type]
    data = json.loads(out.stdout.strip().splitlines()[-1])
    return Result(client, data["tx"], data["errors"], data["wall"], data["cpu"], gaps)  # type: ignore[arg-type]


def limit_seconds(op: str, baud: int) -> float:
    request, response = FRAMES[op]
    return (request + response + 2 * 3.5) * 11 / baud


def print_table(headers: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(r[i]) for r in [headers, *rows]) for i in range(len(headers))]
    for n, row in enumerate([headers, *rows]):
        print(
            "  " + "  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True)))
        )
        if n == 0:
            print("  " + "  ".join("-" * w for w in widths))


def line_case(baud: int, clients: list[str], seconds: float, repeat: int) -> None:
    emulator = Emulator(baud)
    server = start_server("starterbus", emulator.server, baud)
    try:
        wait_ready(emulator.client, baud)
        for op in ("fc03", "fc06"):
            limit = limit_seconds(op, baud)
            print(
                f"\nline emulator {baud} baud, {op.upper()}{' x4 registers' if op == 'fc03' else ''}: "
                f"physical limit {1 / limit:.1f} tx/s ({limit * 1000:.2f} ms per transaction), "
                f"silence {3.5 * 11 / baud * 1000:.2f} ms, slave = starterbus simulator (waits the silence)"
            )  # fmt: skip
            results = [run_best(c, emulator.client, op, baud, seconds, emulator, repeat) for c in clients]
            rows = []
            for r in results:
                gaps = r.gaps
                rows.append([
                    r.client, f"{r.rate:.1f}", f"{r.rate * limit:.3f}", f"{r.cpu_per_tx_us:.0f}",
                    f"{gaps.get('min_ms', float('nan')):.2f}", r.keeps_silence, str(r.errors),
                ])  # fmt: skip
            print_table(["client", "tx/s", "of limit", "CPU us/tx", "min gap ms", "keeps silence", "errors"], rows)
    finally:
        server.terminate()
        server.wait(timeout=10)
        emulator.close()


def bare_case(clients: list[str], seconds: float, server_kind: str, repeat: int, changing: bool) -> None:
    baud = 19200
    emulator = Emulator(0)
    server = start_server(server_kind, emulator.server, baud, changing)
    try:
        wait_ready(emulator.client, baud)
        for op in ("fc03", "fc06"):
            print(f"\nbare pty (no pacing), {op.upper()}, nominal {baud} baud (silence 2.01 ms), "
                  f"slave = {server_kind} server{', registers changing' if changing else ''}")  # fmt: skip
            results = [run_best(c, emulator.client, op, baud, seconds, emulator, repeat) for c in clients]
            ours = next((r for r in results if r.client == "starterbus"), None)
            rows = []
            for r in results:
                ratio = r.rate / ours.rate if ours and ours.rate else float("nan")
                rows.append([
                    r.client, f"{r.rate:.0f}", f"{ratio:.2f}", f"{r.cpu_per_tx_us:.0f}",
                    f"{r.gaps.get('min_ms', float('nan')):.2f}", r.keeps_silence, str(r.errors),
                ])  # fmt: skip
            print_table(["client", "tx/s", "vs starterbus", "CPU us/tx", "min gap ms", "keeps silence", "errors"], rows)
    finally:
        server.terminate()
        server.wait(timeout=10)
        emulator.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="per client and operation")
    parser.add_argument("--repeat", type=int, default=2, help="runs per case; the best rate is reported")
    parser.add_argument("--bauds", default="9600,19200")
    parser.add_argument("--clients", default=",".join(CLIENTS))
    parser.add_argument("--only", choices=["line", "bare"], default=None)
    parser.add_argument("--bare-server", choices=["pymodbus", "starterbus"], default="pymodbus")
    parser.add_argument("--changing", action="store_true", help="bare pty: every FC03 answer differs (pymodbus)")
    args = parser.parse_args()
    clients = args.clients.split(",")
    print(
        f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs; best of {args.repeat} x {args.seconds:g} s per case"
    )
    if args.only in (None, "line"):
        for baud in (int(b) for b in args.bauds.split(",")):
            line_case(baud, clients, args.seconds, args.repeat)
    if args.only in (None, "bare"):
        bare_case(clients, args.seconds, args.bare_server, args.repeat, args.changing)


if __name__ == "__main__":
    main()
