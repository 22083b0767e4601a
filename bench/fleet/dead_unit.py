"""Benchmark: does a dead unit starve its line? Live units' poll rate with and without a dead unit beside them.

Run: ``python bench/fleet/dead_unit.py [--seconds 20] [--baud 19200]``

One RTU line through the line emulator (``bench/modbus/line_emulator.py``: bytes paced at 11 bits a character)
with two live simulated units (JJR5000 unit 1, SSD1 unit 2); the fleet polls them at a 0.2 s period with the
issue's transport settings (timeout 0.3 s, retries 2). Three runs of ``--seconds`` each, side by side:

* ``no dead unit``: the two live units alone (the baseline);
* ``dead, probes``: a third unit (3) configured but absent, probed as the poller does by default (one attempt,
  0.1 s probe timeout, backoff with jitter, at most 10 % of the line's time);
* ``dead, no probes``: the same with probes switched off (every attempt on the dead unit uses the transport's
  full policy: 3 x 0.3 s), which is how the poller behaved before;
* the cases marked ``*`` set ``max_backoff`` to the period, so that the dead unit is retried as often as the
  backoff allows: with probes the bound on the line's share (10 %) is what holds them back.

Printed per run: live units' polls/s (each), the ratio to the baseline, probes and the dead unit's share of
the line's time (the poller's own count of time spent in its transactions).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.fleet.probing import ProbeSettings
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

HERE = Path(__file__).resolve().parent
EMULATOR = HERE.parent / "modbus" / "line_emulator.py"
LIVE = {1: "jjr5000", 2: "ssd1"}
DEAD = (3, "ssd1")


def fleet_text(path: str, baud: int, dead: bool, max_backoff: float) -> str:
    text = f'[poll]\nperiod = 0.2\nmax_backoff = {max_backoff}\n[[bus]]\nname = "rtu"\nurl = "modbus-rtu://{path}?baudrate={baud}&timeout=0.3&retries=2"\n'
    units = dict(LIVE)
    if dead:
        units[DEAD[0]] = DEAD[1]
    for unit, model in units.items():
        text += f'[[bus.device]]\nname = "u{unit}"\nmodel = "{model}"\naddress = {unit}\n'
    return text


def run(
    path: str, baud: int, seconds: float, dead: bool, probing: ProbeSettings, max_backoff: float
) -> dict[str, float]:
    counts: dict[str, int] = {}
    dead_busy = [0.0]
    lock = threading.Lock()
    window: list[float] = []

    def count(sample: Sample) -> None:
        with lock:
            if window and sample.online:
                counts[sample.device] = counts.get(sample.device, 0) + 1
            if window and sample.device == f"u{DEAD[0]}" and sample.wire is not None:
                dead_busy[0] += sample.wire.busy_time

    poller = FleetPoller(parse_fleet(fleet_text(path, baud, dead, max_backoff)), count, probing=probing)
    with poller:
        time.sleep(1.5)  # start-up: every unit polled once (the dead one fails once with the full policy)
        before = poller.line_stats()["rtu"]
        with lock:
            window.append(time.monotonic())
        time.sleep(seconds)
        with lock:
            elapsed = time.monotonic() - window[0]
            window.clear()
        after = poller.line_stats()["rtu"]
    result = {f"u{u}": counts.get(f"u{u}", 0) / elapsed for u in LIVE}
    result["probes"] = after.probes - before.probes
    result["dead_share"] = dead_busy[0] / elapsed
    result["line_busy"] = (after.wire.busy_time - before.wire.busy_time) / elapsed
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--baud", type=int, default=19200)
    args = parser.parse_args()
    emulator = subprocess.Popen(
        [sys.executable, str(EMULATOR), "--baud", str(args.baud)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert emulator.stdout is not None and emulator.stdin is not None
    client = emulator.stdout.readline().split(": ", 1)[1].strip()
    server = emulator.stdout.readline().split(": ", 1)[1].strip()
    starters = {unit: SimulatedStarter(get_profile(model)) for unit, model in LIVE.items()}
    sim = ModbusRtuSimulator(starters, port=server, baudrate=args.baud).start()
    try:
        cases = [
            ("no dead unit", False, ProbeSettings(), 30.0),
            ("dead, probes", True, ProbeSettings(), 30.0),
            ("dead, probes*", True, ProbeSettings(), 0.2),
            ("dead, no probes", True, ProbeSettings(timeout=None), 30.0),
            ("dead, no probes*", True, ProbeSettings(timeout=None), 0.2),
        ]
        results = [
            (name, run(client, args.baud, args.seconds, dead, probing, backoff))
            for name, dead, probing, backoff in cases
        ]
    finally:
        sim.close()
        emulator.stdin.close()
        emulator.wait(timeout=5)
    base = results[0][1]
    print(f"one RTU line at {args.baud} baud (line emulator), live units 1 (JJR5000) and 2 (SSD1), period 0.2 s,")
    print(f"timeout 0.3 s, retries 2; dead unit 3 (SSD1, absent); {args.seconds:g} s per run")
    print("* max_backoff = the period (0.2 s): the dead unit is retried as often as backoff allows")
    head = f"{'case':<17} {'u1 polls/s':>10} {'u2 polls/s':>10} {'vs baseline':>11}"
    print(f"{head} {'probes':>6} {'dead unit':>9} {'line busy':>9}")
    for name, r in results:
        ratio = min(r["u1"] / base["u1"], r["u2"] / base["u2"])
        row = f"{name:<17} {r['u1']:>10.2f} {r['u2']:>10.2f} {ratio:>11.3f}"
        print(f"{row} {int(r['probes']):>6} {r['dead_share']:>9.1%} {r['line_busy']:>9.1%}")


if __name__ == "__main__":
    main()
