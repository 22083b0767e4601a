"""Benchmark: a simulated fleet on 8 lines (4 Modbus RTU + 4 DeviceNet) polled by :class:`FleetPoller`.

Run: ``python bench/fleet/scale.py [--sizes 20 200 1000] [--rounds 10] [--warmup-rounds 1] [--devicenet-period 0.02]``

For each fleet size N the script starts, in one fresh child process (so that peak memory and CPU belong to that
size alone):

* 4 Modbus RTU lines on pseudo-terminals at 19200 baud (8N1), each a :class:`ModbusRtuSimulator` serving its
  units (JJR5000 and SSD1 alternating; JJR8000 is left off Modbus because its profile reads 1 register per
  request), units 1..247;
* 4 DeviceNet buses on python-can's ``virtual`` interface, each a :class:`DeviceNetSimulator` with JJR8000
  nodes (extended assemblies), MAC 1..62 (MAC 0 is the scanner; 63 is left free as the factory default);

N devices are dealt round-robin over the 8 lines; a DeviceNet bus takes at most 62, the rest go to the Modbus
lines. A fleet file is generated from the simulators' URLs (as ``starterbus demo`` does), parsed with
:func:`parse_fleet` and polled by one :class:`FleetPoller`. Modbus devices have a 1 ms period, so their bus
workers run flat out (a poll = the poll plan of status word + phase currents: 1 FC03 request of 4 registers).
A DeviceNet poll (status + L1 current) reads the scanner's latest input assembly, which the scanner refreshes
every 20 ms by itself, so DeviceNet devices are polled at that period by default: with ``--devicenet-period
0.001`` their bus workers re-read the same inputs tens of times per scan in a busy loop that takes most of the
GIL and starves the I/O-bound Modbus lines (a measurement of its own, but not of the fleet's round).

Start-up (simulators, the DeviceNet duplicate MAC checks and connection sequences, opening the lines) is not
measured: the window opens once every device has answered once and then ``--warmup-rounds`` more times, and
closes at the sample that completes ``--rounds`` more polls of every device. Lines that finish their rounds
early keep polling (as in production) and their transactions count too. Reported per size:

* rounds/s and ms per round: rounds of the slowest device (the fleet's refresh rate);
* CPU per transaction: ``time.process_time()`` delta / ``FleetPoller.transactions()`` delta (the whole process,
  simulators included), and per thread group (Modbus bus workers per Modbus transaction, Modbus slave threads per
  request, DeviceNet bus workers per read, scanner and DeviceNet simulator threads in cores) from
  ``/proc/self/task/TID/schedstat``;
* peak memory: the child's ``ru_maxrss`` (peak resident set, includes start-up) minus its resident set after
  imports, and per device; ``--tracemalloc`` adds the Python heap peak (and slows everything down);
* growth ratios against the smallest size; the per-line table shows which line limits a round, and how much of
  that line's round is the silent interval that Modbus RTU mandates (3.5 characters before the answer and again
  before the next request: 2 x 2.005 ms per transaction at 19200 baud). A pty transfers bytes instantly, so the
  real-wire floor (characters at 11 bits + silences) is printed beside it.

Everything, simulators included, runs in one Python process and shares its GIL and the machine's cores.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
import tracemalloc

from starterbus.bench.fleet.scale_fleet import (
    DEVICENET_MODEL,
    MODBUS_MODELS,
    plan_lines,
    start_fleet,
)
from starterbus.bench.fleet.scale_recorder import Recorder, Snapshot, thread_cpu, thread_group
from starterbus.bench.fleet.scale_report import DEVICENET_BITRATE, report
from starterbus.core import get_profile
from starterbus.fleet.poller import FleetPoller
from starterbus.transports.devicenet.driver.scanner import Scanner
from starterbus.transports.devicenet.transport import DeviceNetTransport
from starterbus.transports.modbus.codec.timing import char_time, silent_interval
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.master.poll_plan import PollPlans
from starterbus.transports.modbus.settings import max_read_registers
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport

CAN_POLL_BYTES = (2, 6)  # extended assemblies: output 102 (2 bytes), input 101 (6 bytes)


# -- measuring --------------------------------------------------------------------------------------------------


def wire_transport_objects(poller: FleetPoller) -> tuple[dict[str, RtuLine], dict[str, Scanner]]:
    lines: dict[str, RtuLine] = {}
    scanners: dict[str, Scanner] = {}
    for runtime in poller.runtimes():
        device = runtime.device
        if device is None:
            continue
        transport = device.transport
        if isinstance(transport, ModbusRtuTransport):
            lines[runtime.config.bus] = transport.line
        elif isinstance(transport, DeviceNetTransport) and transport.scanner is not None:
            scanners[runtime.config.bus] = transport.scanner
    return lines, scanners


def modbus_poll_cost(model: str, baudrate: int) -> tuple[int, int]:
    """(requests, characters on the wire) of one poll: the poll plan of the status and the phase currents."""
    profile = get_profile(model)
    plans = PollPlans(profile, max_read_registers(profile), baudrate, silent_interval(baudrate))
    plan = plans.get(profile.phase_currents(), status=True)
    # request: unit fc addr(2) count(2) crc(2); answer: unit fc n data crc(2)
    return len(plan.requests), sum(8 + 5 + 2 * count for _, count in plan.requests)


def can_frame_bits(n: int) -> int:
    """Worst-case bits of a classic CAN data frame with an 11-bit id and n data bytes, interframe space included."""
    return 47 + 8 * n + (34 + 8 * n - 1) // 4


def measure(args: argparse.Namespace, n: int) -> dict[str, object]:
    """One fleet size, in this process: start, warm up, measure, stop. Returns the figures as a JSON-able dict."""
    rss_base_kib = _vm_kib("VmRSS")
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    if args.tracemalloc:
        tracemalloc.start()
    t0 = time.monotonic()
    lines = plan_lines(n, args.modbus_lines, args.devicenet_lines)
    fleet = start_fleet(lines, args.baudrate, args.period, args.devicenet_period)
    t_sims = time.monotonic() - t0
    names = [d.name for d in fleet.config.devices]
    holder: dict[str, FleetPoller] = {}
    wire: list[tuple[dict[str, RtuLine], dict[str, Scanner]]] = [({}, {})]

    def take() -> Snapshot:
        wall, cpu = time.monotonic(), time.process_time()
        poller = holder["poller"]
        rtu, scanners = wire[0]
        counts = {name: recorder.ok[i] for name, i in recorder.index.items()}
        per_bus = {worker.bus.name: worker.transactions for worker in poller.workers}
        w = {bus: line.transactions for bus, line in rtu.items()}
        w.update({bus: scanner.cycles for bus, scanner in scanners.items()})
        return Snapshot(wall, cpu, sum(per_bus.values()), per_bus, counts, recorder.errors, thread_cpu(), w)

    recorder = Recorder(names, take)
    result: dict[str, object] = {"devices": n}
    poller = FleetPoller(fleet.config, recorder)
    holder["poller"] = poller
    deadline = time.monotonic() + args.timeout
    try:
        with recorder.lock:
            recorder.arm(1)
        poller.start()
        if not recorder.done.wait(max(0.0, deadline - time.monotonic())):
            missing = sum(1 for c in recorder.ok if c == 0)
            raise RuntimeError(f"{missing} of {n} devices never answered (last error: {recorder.last_error})")
        t_online = time.monotonic() - t0
        wire[0] = wire_transport_objects(poller)
        if args.warmup_rounds > 0:
            with recorder.lock:
                recorder.arm(args.warmup_rounds)
            if not recorder.done.wait(max(0.0, deadline - time.monotonic())):
                raise RuntimeError("warm-up rounds did not finish in time")
        with recorder.lock:
            start = take()
            recorder.arm(args.rounds)
        if not recorder.done.wait(max(0.0, deadline - time.monotonic())):
            raise RuntimeError(f"{args.rounds} rounds did not finish within --timeout {args.timeout:g} s")
        end = recorder.snapshot
        assert end is not None
        peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        if args.tracemalloc:
            result["tracemalloc_peak_kib"] = tracemalloc.get_traced_memory()[1] / 1024
    finally:
        poller.stop()
        fleet.close()
    window = end.wall - start.wall
    transactions = end.transactions - start.transactions
    groups: dict[str, float] = {}
    for name, seconds in end.threads.items():
        group = thread_group(name)
        groups[group] = groups.get(group, 0.0) + seconds - start.threads.get(name, 0.0)
    per_line: list[dict[str, object]] = []
    for line in lines:
        samples = sum(end.samples[d[0]] - start.samples[d[0]] for d in line.devices)
        entry: dict[str, object] = {
            "line": line.name,
            "kind": line.kind,
            "devices": len(line.devices),
            "rounds": samples / len(line.devices),
            "transactions": end.bus_transactions[line.name] - start.bus_transactions[line.name],
            "worker_cpu_s": end.threads.get(f"bus-{line.name}", 0.0) - start.threads.get(f"bus-{line.name}", 0.0),
            "wire": end.wire.get(line.name, 0) - start.wire.get(line.name, 0),
        }
        if line.kind == "modbus":
            requests = chars = 0
            for _, model, _ in line.devices:
                r, c = modbus_poll_cost(model, args.baudrate)
                requests += r
                chars += c
            silence = silent_interval(args.baudrate)
            entry["floor_pty_s"] = requests * 2 * silence  # per round
            entry["floor_wire_s"] = requests * 2 * silence + chars * char_time(args.baudrate)
        else:
            bits = sum(can_frame_bits(b) for b in CAN_POLL_BYTES) * len(line.devices)
            entry["floor_wire_s"] = bits / DEVICENET_BITRATE  # one CAN scan of the bus
        per_line.append(entry)
    result.update(
        {
            "layout": [[line.name, len(line.devices)] for line in lines],
            "startup_sims_s": t_sims,
            "startup_online_s": t_online,
            "window_s": window,
            "rounds": args.rounds,
            "transactions": transactions,
            "cpu_s": end.cpu - start.cpu,
            "threads_cpu_s": groups,
            "rss_base_kib": rss_base_kib,
            "peak_rss_kib": peak_kib,
            "errors": end.errors - start.errors,
            "errors_total": recorder.errors,
            "last_error": recorder.last_error,
            "lines": per_line,
        }
    )
    return result


def _vm_kib(field_name: str) -> float:
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith(field_name + ":"):
                    return float(line.split()[1])
    except OSError:
        pass
    return 0.0


# -- the parent: one child per size, then the tables -----------------------------------------------------------


def run_child(args: argparse.Namespace, n: int) -> dict[str, object] | None:
    command = [
        sys.executable,
        os.path.abspath(__file__),
        "--child",
        str(n),
        "--rounds",
        str(args.rounds),
        "--warmup-rounds",
        str(args.warmup_rounds),
        "--period",
        str(args.period),
        "--baudrate",
        str(args.baudrate),
        "--devicenet-period",
        str(args.devicenet_period),
        *(["--switch-interval", str(args.switch_interval)] if args.switch_interval is not None else []),
        "--modbus-lines",
        str(args.modbus_lines),
        "--devicenet-lines",
        str(args.devicenet_lines),
        "--timeout",
        str(args.timeout),
    ]
    if args.tracemalloc:
        command.append("--tracemalloc")
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=args.timeout + 30, check=False)
    except subprocess.TimeoutExpired:
        print(f"  N={n}: the child did not finish within {args.timeout + 30:g} s", flush=True)
        return None
    if done.returncode != 0:
        print(f"  N={n}: the child failed (exit {done.returncode}):\n{done.stderr.strip()}", flush=True)
        return None
    for line in reversed(done.stdout.splitlines()):
        if line.startswith("{"):
            figures: dict[str, object] = json.loads(line)
            return figures
    print(f"  N={n}: no result from the child:\n{done.stdout}{done.stderr}", flush=True)
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 200, 1000], help="fleet sizes (devices)")
    parser.add_argument("--rounds", type=int, default=10, help="measured rounds per size (default 10)")
    parser.add_argument("--warmup-rounds", type=int, default=1, help="rounds after every device answered once")
    parser.add_argument("--period", type=float, default=0.001, help="poll period of the Modbus devices, s (0.001)")
    parser.add_argument(
        "--devicenet-period",
        type=float,
        default=0.02,
        help="poll period of the DeviceNet devices, s (0.02: the scanner's own cycle; 0.001 = a busy loop)",
    )
    parser.add_argument(
        "--switch-interval",
        type=float,
        help="sys.setswitchinterval() in the child, s (default: Python's, 0.005): how long a busy thread keeps the GIL",
    )
    parser.add_argument("--baudrate", type=int, default=19200, help="Modbus RTU baud rate (19200)")
    parser.add_argument("--modbus-lines", type=int, default=4)
    parser.add_argument("--devicenet-lines", type=int, default=4)
    parser.add_argument("--timeout", type=float, default=120.0, help="limit per size, s (start-up included)")
    parser.add_argument("--tracemalloc", action="store_true", help="also report the Python heap peak (slower)")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.warmup_rounds < 0:
        parser.error("--rounds must be at least 1 and --warmup-rounds at least 0")
    if args.child is not None:
        print(json.dumps(measure(args, args.child)), flush=True)
        return 0
    dnet = f" (DeviceNet {args.devicenet_period * 1000:g} ms)"
    print(
        f"fleet benchmark: {args.modbus_lines} Modbus RTU lines (pty, {args.baudrate} baud, "
        f"{'/'.join(MODBUS_MODELS)}) + {args.devicenet_lines} DeviceNet buses (virtual CAN, {DEVICENET_MODEL}); "
        f"poll period {args.period * 1000:g} ms{dnet}; {args.rounds} rounds after {args.warmup_rounds} warm-up "
        "round(s); one child process per size"
    )
    results = []
    for n in args.sizes:
        started = time.monotonic()
        print(f"  N={n} ...", end="", flush=True)
        figures = run_child(args, n)
        if figures is not None:
            print(f" {time.monotonic() - started:.1f} s", flush=True)
            results.append(figures)
    if results:
        report(results, args)
    return 0 if len(results) == len(args.sizes) else 1


if __name__ == "__main__":
    sys.exit(main())
