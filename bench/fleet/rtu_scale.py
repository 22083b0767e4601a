"""Benchmark: the fleet poller at scale on real-speed RTU lines, with its own CPU measured apart.

Run: ``python bench/fleet/rtu_scale.py [--sizes 20 200 992] [--lines 16] [--seconds 20] [--period 1.0]
[--floor] [--rig-batch | --emulators-on CPU] [--baseline [--baseline-first]]``

For each size N: ``--lines`` RTU lines at 19200 baud, each a line emulator process
(``bench/modbus/line_emulator.py``: bytes paced at 11 bits a character, half duplex); ONE simulator process
(this script with ``serve``) serving every line's units (JJR5000 and SSD1 alternating, units 1..62 at most);
and the poller in this process (one thread for every line: fleet/mux.py), polling the status (status word +
phase currents: one FC03 of 4 registers per device, the poll plan) of the N devices at ``--period``. 62
devices fit a line at 19200 baud and 1 s: one such FC03 takes 16.04 ms of wire (21 characters + two
3.5-character silences), 62 of them 0.995 s; 16 lines x 62 = 992 devices is the fleet of "1000 devices on 16
lines".

The window opens once every device has answered once and closes ``--seconds`` later. Reported per size:

* rounds/s: the slowest device's good polls per second (the fleet's refresh rate), and the mean;
* per line: rounds/s, the physical limit of its plan (``min(1/period, 1/wire time per round)`` from
  ``Transport.plan``), their ratio (goal >= 0.95), and the line's wire utilisation as the poller counted it
  (``FleetPoller.line_stats()``: frames and silences over the window) and as the emulator saw it (bytes);
* the poller's CPU as a fraction of one core (``time.process_time()`` of this process over the window: the
  simulators and the emulators run in other processes), and per transaction;
* errors and timeouts; the share of the window the poller spent inside its transactions (busy); the turnarounds
  the emulator saw, median and 99th percentile (``--json``: the longest too; master: answer delivered -> next
  request; slave: request -> answer; the plan counts 3.5 characters = 2.005 ms each), and how often the master
  broke the 3.5-character silence;
* the CPU of the rig (the simulator process and the emulators), since all of it shares the machine's cores, and
  how often the poller's process was preempted (involuntary context switches) and slept (voluntary ones) a
  transaction: the emulators take a real-time priority where allowed (the report says which), so each byte they
  pace takes a core from the poller when both are busy; ``--rig-batch`` or ``--emulators-on CPU`` takes that
  share out (``bench/fleet/rig.py``);
* with ``--floor``: the rig's own limit, without the poller: one thread sends the same FC03 to every unit of
  every line back to back (the poller's LineTask, waited on with select, no schedule and no samples); its rate
  against the wire limit of the plan (1 / wire per round);
* with ``--baseline``: the same size again with a thread per bus (``FleetPoller(multiplex=False)``, the poller
  before fleet/mux.py), then the ratio of the two pollers' CPU and their slowest lines side by side
  (``--baseline-first``: the thread per bus runs first; the second run of a pair tends to do a little better).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

from starterbus.bench.fleet.rig import AS_ASKED, RigScheduling, process_cpu
from starterbus.bench.modbus.throughput import Emulator

HERE = Path(__file__).resolve().parent
MODELS = ("jjr5000", "ssd1")
MAX_UNITS = 62
BAUD = 19200


def layout(n: int, lines: int) -> list[int]:
    """Devices per line: ``n`` dealt round-robin over ``lines``."""
    if n > lines * MAX_UNITS:
        raise SystemExit(f"{n} devices do not fit {lines} lines of {MAX_UNITS}")
    return [n // lines + (1 if i < n % lines else 0) for i in range(lines)]


# -- the simulator process ------------------------------------------------------------------------------------------


def serve(paths: list[str], counts: list[int]) -> None:
    from starterbus.core.registry import get_profile
    from starterbus.core.simulator import SimulatedStarter
    from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

    sims = []
    for path, count in zip(paths, counts, strict=True):
        starters = {u: SimulatedStarter(get_profile(MODELS[u % 2])) for u in range(1, count + 1)}
        sims.append(ModbusRtuSimulator(starters, port=path, baudrate=BAUD).start())
    print("ready", flush=True)
    sys.stdin.read()  # until the parent closes our stdin
    for sim in sims:
        sim.close()


# -- the poller's side ------------------------------------------------------------------------------------------------


def fleet_text(emulators: list[Emulator], counts: list[int], period: float) -> str:
    parts = [f"[poll]\nperiod = {period}\nmax_backoff = 5.0\n"]
    for i, (emulator, count) in enumerate(zip(emulators, counts, strict=True)):
        if not count:
            continue
        url = f"modbus-rtu://{emulator.client}?baudrate={BAUD}&timeout=0.2&retries=1"
        parts.append(f'[[bus]]\nname = "rtu-{i + 1:02d}"\nurl = "{url}"\n')
        for unit in range(1, count + 1):
            parts.append(
                f'[[bus.device]]\nname = "rtu-{i + 1:02d}-{unit:02d}"\nmodel = "{MODELS[unit % 2]}"\naddress = {unit}\n'
            )
    return "".join(parts)


def direct_loop(emulators: list[Emulator], counts: list[int], seconds: float) -> list[float]:
    """The floor without the poller: one thread sending every unit's status FC03 (the same request as the poll
    plan) on every line back to back, each transaction a LineTask (the poller's own) waited on with select.
    Returns transactions/s per line."""
    import select

    from starterbus.core.device import Device, open_device
    from starterbus.core.errors import StarterbusError
    from starterbus.core.polling import PollResult
    from starterbus.transports.modbus.codec.frames import ReadRequest, Response
    from starterbus.transports.modbus.driver.line_task import LineTask
    from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport

    lines: list[list[Device]] = []
    for index, count in enumerate(counts):
        url = f"modbus-rtu://{emulators[index].client}?baudrate={BAUD}&timeout=0.2&retries=1"
        lines.append([open_device(f"{url}&unit={u}", MODELS[u % 2]).open() for u in range(1, count + 1)])

    def task(device: Device) -> LineTask:
        transport = device.transport
        assert isinstance(transport, ModbusRtuTransport)
        exchange = transport.line.prepare(ReadRequest(transport.unit, 1, 4), transport.config.policy)

        def finish(responses: list[Response]) -> PollResult:
            return PollResult(None, [])

        return LineTask(transport.line, [exchange], transport.counters(), lambda e, r: None, finish)

    done = [0] * len(counts)
    failed: list[str] = []
    turn = [0] * len(counts)
    tasks = [task(devices[0]) for devices in lines]
    now = time.monotonic()
    start = now + 1.0
    end = start + seconds
    before: list[int] = []
    try:
        while now < end:
            if not before and now >= start:
                before, t0 = list(done), now
            for i in range(len(tasks)):
                if tasks[i].wake_at <= now:
                    tasks[i].advance(now)
                while tasks[i].done:
                    try:
                        tasks[i].result()
                        done[i] += 1
                    except StarterbusError as exc:
                        failed.append(str(exc))
                    turn[i] = (turn[i] + 1) % len(lines[i])
                    tasks[i] = task(lines[i][turn[i]])
                    tasks[i].advance(time.monotonic())
            wait = min(t.wake_at for t in tasks) - time.monotonic()
            fds = {t.fd: i for i, t in enumerate(tasks) if t.fd >= 0}
            ready = select.select(list(fds), [], [], max(0.0, wait))[0]
            now = time.monotonic()
            for fd in ready:
                tasks[fds[fd]].advance(now)
        t1 = now
    finally:
        for current in tasks:
            current.cancel()
        for devices in lines:
            for device in devices:
                device.close()
    if failed:
        print(f"  without the poller: {len(failed)} failed transactions, e.g. {failed[0]}", flush=True)
    return [(a - b) / (t1 - t0) for a, b in zip(done, before, strict=True)]


def measure(
    n: int,
    lines: int,
    seconds: float,
    period: float,
    floor: bool = False,
    multiplex: bool = True,
    rig: RigScheduling = AS_ASKED,
) -> dict[str, object]:
    from starterbus.fleet.config import parse_fleet
    from starterbus.fleet.plan import fleet_plan
    from starterbus.fleet.poller import FleetPoller, Sample

    counts = layout(n, lines)
    used = [c for c in counts if c]
    emulators = [Emulator(BAUD) for _ in used]
    sims = subprocess.Popen(
        [sys.executable, __file__, "serve", "--paths", *[e.server for e in emulators], "--counts", *map(str, used)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert sims.stdout is not None and sims.stdin is not None
    try:
        if sims.stdout.readline().strip() != "ready":
            raise RuntimeError("the simulator process did not start")
        pids = [sims.pid, *(e.proc.pid for e in emulators)]
        rig.apply(pids[0], pids[1:])
        config = parse_fleet(fleet_text(emulators, used, period), "<rtu scale>")
        plans = {p.name: p for p in fleet_plan(config)}
        good: dict[str, int] = {d.name: 0 for d in config.devices}
        errors = [0]
        seen = threading.Event()
        lock = threading.Lock()

        def count(sample: Sample) -> None:
            with lock:
                if sample.online and sample.error is None:
                    good[sample.device] += 1
                    if not seen.is_set() and all(good.values()):
                        seen.set()
                else:
                    errors[0] += 1

        poller = FleetPoller(config, count, multiplex=multiplex)
        with poller:
            if not seen.wait(60.0):
                raise RuntimeError(f"devices never answered: {[d for d, c in good.items() if not c][:5]}")
            time.sleep(period)  # a round after the first answers: every line runs its steady schedule
            with lock:
                start_good, start_errors = dict(good), errors[0]
            for e in emulators:
                e.stats()
            start_stats = poller.line_stats()
            t0, c0, r0 = time.monotonic(), time.process_time(), [process_cpu(pid) for pid in pids]
            u0 = resource.getrusage(resource.RUSAGE_SELF)
            time.sleep(seconds)
            with lock:
                end_good, end_errors = dict(good), errors[0]
            t1, c1, r1 = time.monotonic(), time.process_time(), [process_cpu(pid) for pid in pids]
            u1 = resource.getrusage(resource.RUSAGE_SELF)
            end_stats = poller.line_stats()
            wire_seen = [e.stats() for e in emulators]
        direct = direct_loop(emulators, used, seconds) if floor else []
    finally:
        sims.stdin.close()
        sims.wait(timeout=20)
        for e in emulators:
            e.close()
    window = t1 - t0
    rates = {d: (end_good[d] - start_good[d]) / window for d in end_good}
    per_line = []
    transactions = 0
    for index, ((name, plan), seen_stats) in enumerate(zip(plans.items(), wire_seen, strict=True)):
        devices = [d.name for d in plan.devices]
        line_rate = statistics.mean(rates[d] for d in devices)
        limit = min(1.0 / period, plan.max_rounds_per_s or float("inf"))
        before, after = start_stats[name], end_stats[name]
        wire = after.wire.minus(before.wire)
        transactions += wire.transactions
        chars = int(seen_stats["bytes_to_server"]) + int(seen_stats["bytes_to_client"])  # type: ignore[call-overload]
        turnaround = seen_stats["master_turnaround"]
        slave = seen_stats["slave_turnaround"]
        per_line.append(
            {
                "line": name,
                "devices": len(devices),
                "rounds_per_s": line_rate,
                "limit_rounds_per_s": limit,
                "of_limit": line_rate / limit,
                "plan_wire_per_round_s": plan.wire_time,
                "wire_utilisation": wire.wire_time / window,
                "busy": wire.busy_time / window,
                "direct_of_wire_limit": direct[index] * (plan.wire_time or 0) / len(devices) if direct else None,
                "emulator_bytes_utilisation": chars * 11 / BAUD / window,
                "timeouts": wire.timeouts,
                "retries": wire.retries,
                "silence_broken": turnaround.get("below_silence", 0) if isinstance(turnaround, dict) else None,
                "master_turnaround_ms": turnaround.get("median_ms") if isinstance(turnaround, dict) else None,
                "slave_turnaround_ms": slave.get("median_ms") if isinstance(slave, dict) else None,
                "master_turnaround_p99_ms": turnaround.get("p99_ms") if isinstance(turnaround, dict) else None,
                "slave_turnaround_p99_ms": slave.get("p99_ms") if isinstance(slave, dict) else None,
                "master_turnaround_max_ms": turnaround.get("max_ms") if isinstance(turnaround, dict) else None,
                "slave_turnaround_max_ms": slave.get("max_ms") if isinstance(slave, dict) else None,
            }
        )
    return {
        "devices": n,
        "poller": "one thread (multiplexed)" if multiplex else "a thread per bus",
        "lines": len(used),
        "window_s": window,
        "rounds_per_s_min": min(rates.values()),
        "rounds_per_s_mean": statistics.mean(rates.values()),
        "poller_cpu_cores": (c1 - c0) / window,
        "simulator_cpu_cores": (r1[0] - r0[0]) / window,
        "emulators_cpu_cores": (sum(r1[1:]) - sum(r0[1:])) / window,
        "cpu_per_transaction_us": (c1 - c0) / transactions * 1e6 if transactions else None,
        "transactions_per_s": transactions / window,
        "preempted_per_transaction": (u1.ru_nivcsw - u0.ru_nivcsw) / transactions if transactions else None,
        "slept_per_transaction": (u1.ru_nvcsw - u0.ru_nvcsw) / transactions if transactions else None,
        # what the emulators were granted (real-time only as root): the rig differs without it
        "rig": rig.describe(str(w.get("scheduling")) for w in wire_seen),
        "errors": end_errors - start_errors,
        "per_line": per_line,
    }


def report(result: dict[str, object]) -> None:
    lines = result["per_line"]
    assert isinstance(lines, list)
    of_limit = [line["of_limit"] for line in lines]
    print(
        f"{result['devices']:>5} devices on {result['lines']:>2} lines, {result['poller']}: "
        f"rounds/s min {result['rounds_per_s_min']:.3f} mean {result['rounds_per_s_mean']:.3f}; "
        f"lines at {min(of_limit):.3f}..{max(of_limit):.3f} of their plan's limit; "
        f"poller CPU {result['poller_cpu_cores']:.3f} of a core "
        f"({result['cpu_per_transaction_us']:.0f} us per transaction, {result['transactions_per_s']:.0f} tx/s); "
        f"errors {result['errors']}; the rig ({result['rig']}): simulator process {result['simulator_cpu_cores']:.2f}, "
        f"emulators {result['emulators_cpu_cores']:.2f} cores; the poller preempted "
        f"{result['preempted_per_transaction']:.2f}, asleep {result['slept_per_transaction']:.2f} times a transaction",
        flush=True,
    )
    direct = [line["direct_of_wire_limit"] for line in lines if line["direct_of_wire_limit"] is not None]
    if direct:
        print(
            f"  without the poller (one thread sending the same FC03 to every unit of every line back to back): "
            f"{min(direct):.3f}..{max(direct):.3f} of the wire limit of the plan (1 / wire time per round)"
        )
    head = f"  {'line':<7} {'dev':>3} {'rounds/s':>8} {'limit':>6} {'of lim':>6} {'wire %':>6} {'emul %':>6} {'t/o':>4}"
    print(f"{head} {'busy %':>6} {'master ms':>9} {'p99':>5} {'slave ms':>8} {'p99':>5} {'<3.5ch':>6}")
    for line in lines:
        print(
            f"  {line['line']:<7} {line['devices']:>3} {line['rounds_per_s']:>8.3f} {line['limit_rounds_per_s']:>6.3f} "
            f"{line['of_limit']:>6.3f} {line['wire_utilisation'] * 100:>6.1f} "
            f"{line['emulator_bytes_utilisation'] * 100:>6.1f} {line['timeouts']:>4} {line['busy'] * 100:>6.1f} "
            f"{line['master_turnaround_ms'] or 0:>9.3f} {line['master_turnaround_p99_ms'] or 0:>5.2f} "
            f"{line['slave_turnaround_ms'] or 0:>8.3f} {line['slave_turnaround_p99_ms'] or 0:>5.2f} "
            f"{line['silence_broken']:>6}",
            flush=True,
        )


def compare(result: dict[str, object], base: dict[str, object]) -> None:
    """One line of ratios: the multiplexed poller against a thread per bus, run side by side."""

    def lowest(r: dict[str, object]) -> float:
        lines = r["per_line"]
        assert isinstance(lines, list)
        return min(float(line["of_limit"]) for line in lines)

    cpu, base_cpu = float(result["poller_cpu_cores"]), float(base["poller_cpu_cores"])  # type: ignore[arg-type]
    print(
        f"  one thread vs a thread per bus: poller CPU {cpu:.3f} / {base_cpu:.3f} = {cpu / base_cpu:.2f}x; "
        f"slowest line {lowest(result):.3f} / {lowest(base):.3f} of its plan's limit",
        flush=True,
    )


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "serve":
        p = argparse.ArgumentParser()
        p.add_argument("--paths", nargs="+", required=True)
        p.add_argument("--counts", nargs="+", type=int, required=True)
        a = p.parse_args(sys.argv[2:])
        serve(a.paths, a.counts)
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", type=int, default=[20, 200, 992])
    parser.add_argument("--lines", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--period", type=float, default=1.0)
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    parser.add_argument(
        "--floor", action="store_true", help="also measure the rig without the poller (the same FC03 back to back)"
    )
    parser.add_argument("--rig-batch", action="store_true", help="the rig (emulators, simulator) under SCHED_BATCH")
    parser.add_argument("--emulators-on", type=int, metavar="CPU", help="every line emulator's thread on that CPU")
    parser.add_argument(
        "--baseline",
        action="store_true",
        help="also run the poller with a thread per bus (multiplex=False) right after, and print the ratios",
    )
    parser.add_argument(
        "--baseline-first",
        action="store_true",
        help="with --baseline: the thread per bus first (the second run of a pair tends to do a little better)",
    )
    args = parser.parse_args()
    rig = RigScheduling(args.rig_batch, args.emulators_on)
    rig.check()
    results = []
    for n in args.sizes:
        if args.baseline and args.baseline_first:
            base = measure(n, args.lines, args.seconds, args.period, multiplex=False, rig=rig)
            report(base)
        result = measure(n, args.lines, args.seconds, args.period, args.floor, rig=rig)
        report(result)
        if args.baseline and not args.baseline_first:
            base = measure(n, args.lines, args.seconds, args.period, multiplex=False, rig=rig)
            report(base)
        results.append(result)
        if args.baseline:
            results.append(base)
            compare(result, base)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
