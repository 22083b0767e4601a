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
import threading
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass, field
from urllib.parse import parse_qsl, urlencode

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.transport import RunningSimulator
from starterbus.fleet.config import FleetConfig, parse_fleet
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.transports.devicenet.scanner import Scanner
from starterbus.transports.devicenet.simulator import DeviceNetSimulator
from starterbus.transports.devicenet.transport import DeviceNetTransport
from starterbus.transports.modbus.client import ModbusRtuTransport
from starterbus.transports.modbus.line import RtuLine
from starterbus.transports.modbus.poll_plan import PollPlans
from starterbus.transports.modbus.simulator import ModbusRtuSimulator
from starterbus.transports.modbus.slave import max_read_registers
from starterbus.transports.modbus.timing import char_time, silent_interval

MODBUS_MODELS = ("jjr5000", "ssd1")
DEVICENET_MODEL = "jjr8000"
MAX_MODBUS_UNITS = 247
MAX_DEVICENET_SLAVES = 62
DEVICENET_MEASUREMENTS = ("phase_a_current",)  # one status parameter: selected once, no settling per read
DEVICENET_BITRATE = 500000
CAN_POLL_BYTES = (2, 6)  # extended assemblies: output 102 (2 bytes), input 101 (6 bytes)


# -- the fleet --------------------------------------------------------------------------------------------------


@dataclass
class LinePlan:
    name: str
    kind: str  # "modbus" | "devicenet"
    devices: list[tuple[str, str, int]] = field(default_factory=list)  # (name, model, address)

    @property
    def capacity(self) -> int:
        return MAX_MODBUS_UNITS if self.kind == "modbus" else MAX_DEVICENET_SLAVES


def plan_lines(n: int, modbus_lines: int, devicenet_lines: int) -> list[LinePlan]:
    """Deal ``n`` devices round-robin over the lines (Modbus and DeviceNet alternating); a full line is skipped."""
    lines: list[LinePlan] = []
    for i in range(max(modbus_lines, devicenet_lines)):
        if i < modbus_lines:
            lines.append(LinePlan(f"rtu-{i + 1}", "modbus"))
        if i < devicenet_lines:
            lines.append(LinePlan(f"dnet-{i + 1}", "devicenet"))
    capacity = sum(line.capacity for line in lines)
    if n > capacity:
        raise SystemExit(f"{n} devices do not fit on {len(lines)} lines (at most {capacity})")
    turn = 0
    for _ in range(n):
        while len(lines[turn % len(lines)].devices) >= lines[turn % len(lines)].capacity:
            turn += 1
        line = lines[turn % len(lines)]
        turn += 1
        address = len(line.devices) + 1
        model = MODBUS_MODELS[len(line.devices) % 2] if line.kind == "modbus" else DEVICENET_MODEL
        line.devices.append((f"{line.name}-{address:03d}", model, address))
    return [line for line in lines if line.devices]


def _bus_url(url: str, drop: str) -> str:
    base, _, query = url.partition("?")
    params = dict(parse_qsl(query))
    params.pop(drop, None)
    return f"{base}?{urlencode(params)}" if params else base


@dataclass
class Fleet:
    config: FleetConfig
    lines: list[LinePlan]
    simulators: list[RunningSimulator]

    def close(self) -> None:
        for sim in reversed(self.simulators):
            sim.close()


def start_fleet(lines: list[LinePlan], baudrate: int, period: float, devicenet_period: float) -> Fleet:
    """Start one simulator per line and build the fleet file that reaches them."""
    sims: list[RunningSimulator] = []
    parts = [f"[poll]\nperiod = {period}\nmax_backoff = 2.0\n"]
    try:
        for index, line in enumerate(lines):
            if line.kind == "modbus":
                starters = {address: SimulatedStarter(get_profile(model)) for _, model, address in line.devices}
                rtu = ModbusRtuSimulator(starters, pty=True, baudrate=baudrate).start()
                sims.append(rtu)
                url = _bus_url(rtu.client_urls()[line.devices[0][2]], "unit")
            else:
                channel = f"bench-fleet-{os.getpid()}-{index}"
                dnet = DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.05)
                for _, model, address in line.devices:
                    dnet.add_node(SimulatedStarter(get_profile(model)), address)
                sims.append(dnet.start())
                if not dnet.wait_online(10.0):
                    raise RuntimeError(f"{line.name}: simulated DeviceNet nodes did not come on line")
                url = f"devicenet://virtual/{channel}?master_mac=0&assemblies=extended&dup_mac_wait=0.05"
            parts.append(f'[[bus]]\nname = "{line.name}"\nurl = "{url}"\n')
            for name, model, address in line.devices:
                extra = ""
                if line.kind == "devicenet":
                    extra = f"\n  measurements = {json.dumps(list(DEVICENET_MEASUREMENTS))}"
                    if devicenet_period != period:
                        extra += f"\n  period = {devicenet_period}"
                parts.append(
                    f'  [[bus.device]]\n  name = "{name}"\n  model = "{model}"\n  address = {address}{extra}\n'
                )
        config = parse_fleet("\n".join(parts), "<bench fleet>")
    except BaseException:
        for sim in reversed(sims):
            sim.close()
        raise
    return Fleet(config, lines, sims)


# -- measuring --------------------------------------------------------------------------------------------------


def thread_cpu() -> dict[str, float]:
    """CPU seconds per live Python thread name, from /proc/self/task/TID/schedstat (Linux; {} elsewhere)."""
    result: dict[str, float] = {}
    for thread in threading.enumerate():
        tid = thread.native_id
        if tid is None:
            continue
        try:
            with open(f"/proc/self/task/{tid}/schedstat", encoding="ascii") as f:
                result[thread.name] = int(f.read().split()[0]) / 1e9
        except (OSError, ValueError, IndexError):
            continue
    return result


def thread_group(name: str) -> str:
    """Which part of the benchmark a thread belongs to, by the names the package gives its threads."""
    if name.startswith("bus-rtu") or name.startswith(("bus-mux", "jobs-rtu")):  # one thread polls every RTU line
        return "rtu_workers"
    if name.startswith("bus-"):
        return "dnet_workers"
    if name.startswith("devicenet-scanner"):
        return "scanners"
    if name.startswith("modbus-rtu"):
        return "rtu_sims"
    if name.startswith("devicenet-sim"):
        return "dnet_sims"
    return "other"


@dataclass
class Snapshot:
    wall: float
    cpu: float
    transactions: int
    bus_transactions: dict[str, int]  # FleetPoller transactions per bus
    samples: dict[str, int]  # good samples per device
    errors: int
    threads: dict[str, float]  # CPU seconds per thread name
    wire: dict[str, int]  # Modbus line -> RtuLine requests; DeviceNet bus -> scanner cycles


class Recorder:
    """The poller's sample sink: counts good samples per device and snapshots when every device reached a target."""

    def __init__(self, names: list[str], take: Callable[[], Snapshot]) -> None:
        self.index = {name: i for i, name in enumerate(names)}
        self.ok = [0] * len(names)
        self.errors = 0
        self.last_error: str | None = None
        self.take = take
        self.target: list[int] | None = None
        self.reached = 0
        self.snapshot: Snapshot | None = None
        self.done = threading.Event()
        self.lock = threading.Lock()  # samples (bus worker threads) against arm() (the main thread)

    def arm(self, more: int) -> None:
        """Wait for ``more`` good samples of every device from now (call with ``lock`` held)."""
        self.snapshot = None
        self.done.clear()
        self.target = [count + more for count in self.ok]
        self.reached = 0

    def __call__(self, sample: Sample) -> None:
        with self.lock:
            self._count(sample)

    def _count(self, sample: Sample) -> None:
        i = self.index[sample.device]
        if sample.error is not None:
            self.errors += 1
            self.last_error = f"{sample.device}: {sample.error}"
        if not sample.online or sample.error is not None:
            return
        self.ok[i] += 1
        target = self.target
        if target is not None and self.ok[i] == target[i]:
            self.reached += 1
            if self.reached == len(target):
                self.target = None
                self.snapshot = self.take()
                self.done.set()


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


def _f(value: object) -> float:
    assert isinstance(value, (int, float))
    return float(value)


def _lines(r: dict[str, object]) -> list[dict[str, object]]:
    lines = r["lines"]
    assert isinstance(lines, list)
    return lines


def derived(r: dict[str, object]) -> dict[str, float]:
    """Rates, CPU per transaction (whole process and per thread group) and memory per device of one size."""
    n, window, rounds = _f(r["devices"]), _f(r["window_s"]), _f(r["rounds"])
    tx, cpu = _f(r["transactions"]), _f(r["cpu_s"])
    groups = r["threads_cpu_s"]
    assert isinstance(groups, dict)
    rtu_tx = sum(_f(e["transactions"]) for e in _lines(r) if e["kind"] == "modbus")
    dnet_tx = sum(_f(e["transactions"]) for e in _lines(r) if e["kind"] == "devicenet")
    grown_kib = _f(r["peak_rss_kib"]) - _f(r["rss_base_kib"])

    def per(group: str, count: float) -> float:
        return 1e6 * float(groups.get(group, 0.0)) / count if count else 0.0

    def cores(group: str) -> float:
        return float(groups.get(group, 0.0)) / window

    return {
        "rounds_per_s": rounds / window,
        "ms_per_round": 1000 * window / rounds,
        "tx_per_s": tx / window,
        "cpu_us_per_tx": 1e6 * cpu / tx if tx else 0.0,
        "cores": cpu / window,
        "sim_share": (float(groups.get("rtu_sims", 0.0)) + float(groups.get("dnet_sims", 0.0))) / cpu if cpu else 0.0,
        "peak_mib": _f(r["peak_rss_kib"]) / 1024,
        "kib_per_device": grown_kib / n,
        "rtu_tx_per_s": rtu_tx / window,
        "dnet_tx_per_s": dnet_tx / window,
        "rtu_worker_us": per("rtu_workers", rtu_tx),
        "rtu_sim_us": per("rtu_sims", rtu_tx),
        "dnet_worker_us": per("dnet_workers", dnet_tx),
        "scanner_cores": cores("scanners"),
        "dnet_sim_cores": cores("dnet_sims"),
        "other_cores": cores("other"),
    }


def report(results: list[dict[str, object]], args: argparse.Namespace) -> None:
    print()
    print(
        f"{'devices':>7} {'per line: rtu | dnet':>27} {'start s':>7} {'rounds':>6} {'window s':>8} {'rounds/s':>8} "
        f"{'ms/round':>8} {'tx/s':>6} {'CPU us/tx':>9} {'cores':>5} {'sims':>4} {'peak MiB':>8} {'KiB/dev':>7} "
        f"{'errors':>6}"
    )
    for r in results:
        d = derived(r)
        rtu = "/".join(f"{_f(e['devices']):.0f}" for e in _lines(r) if e["kind"] == "modbus")
        dnet = "/".join(f"{_f(e['devices']):.0f}" for e in _lines(r) if e["kind"] == "devicenet")
        print(
            f"{_f(r['devices']):7.0f} {rtu + ' | ' + dnet:>27} {_f(r['startup_online_s']):7.1f} {_f(r['rounds']):6.0f} "
            f"{_f(r['window_s']):8.2f} {d['rounds_per_s']:8.2f} {d['ms_per_round']:8.1f} {d['tx_per_s']:6.0f} "
            f"{d['cpu_us_per_tx']:9.0f} {d['cores']:5.2f} {d['sim_share']:4.0%} {d['peak_mib']:8.1f} "
            f"{d['kib_per_device']:7.1f} {_f(r['errors']):6.0f}"
        )
        if r.get("tracemalloc_peak_kib") is not None:
            print(
                f"{'':7} tracemalloc peak (Python heap, start-up included): "
                f"{_f(r['tracemalloc_peak_kib']) / 1024:.1f} MiB"
            )
        if r.get("last_error"):
            print(f"{'':7} {_f(r['errors_total']):.0f} errors in the whole run; last: {r['last_error']}")

    print("\nCPU by thread group in the window (us per transaction of that kind, or cores = CPU s / wall s):")
    print(
        f"{'devices':>7} {'rtu tx/s':>8} {'rtu worker us/tx':>16} {'rtu sim us/tx':>13} {'dnet tx/s':>9} "
        f"{'dnet worker us/tx':>17} {'scanners cores':>14} {'dnet sims cores':>15} {'other cores':>11}"
    )
    for r in results:
        d = derived(r)
        print(
            f"{_f(r['devices']):7.0f} {d['rtu_tx_per_s']:8.0f} {d['rtu_worker_us']:16.0f} {d['rtu_sim_us']:13.0f} "
            f"{d['dnet_tx_per_s']:9.0f} {d['dnet_worker_us']:17.0f} {d['scanner_cores']:14.2f} "
            f"{d['dnet_sim_cores']:15.2f} {d['other_cores']:11.2f}"
        )

    if len(results) > 1:
        base = results[0]
        b = derived(base)

        def ratio(x: float, y: float) -> str:
            return f"{x / y:.2f}" if y else "-"

        print(f"\ngrowth against N={_f(base['devices']):.0f} (x; 'x devices' is the linear reference):")
        print(f"{'devices':>7} {'x devices':>9} {'ms/round':>8} {'CPU/tx':>8} {'rtu worker/tx':>13} {'KiB/dev':>8}")
        for r in results:
            d = derived(r)
            print(
                f"{_f(r['devices']):7.0f} {_f(r['devices']) / _f(base['devices']):9.1f} "
                f"{ratio(d['ms_per_round'], b['ms_per_round']):>8} {ratio(d['cpu_us_per_tx'], b['cpu_us_per_tx']):>8} "
                f"{ratio(d['rtu_worker_us'], b['rtu_worker_us']):>13} "
                f"{ratio(d['kib_per_device'], b['kib_per_device']):>8}"
            )

    silence = silent_interval(args.baudrate)
    print(
        "\nper line: ms/round = window / that line's rounds; '% fleet' = its share of the fleet round (the slowest "
        f"line sets it);\nModbus floor per round: pty = 2 x {silence * 1000:.3f} ms of silence per request (a pty "
        f"moves the bytes at once), wire = silences + 11-bit characters at {args.baudrate} baud;\n"
        f"DeviceNet floor = one CAN scan of the bus at {DEVICENET_BITRATE // 1000} kbit/s (the scanner scans every "
        "20 ms by itself; a poll reads its latest inputs)."
    )
    for r in results:
        d = derived(r)
        window = _f(r["window_s"])
        print(f"\nN={_f(r['devices']):.0f}:")
        print(
            f"  {'line':7} {'devices':>7} {'rounds':>7} {'ms/round':>9} {'% fleet':>7} {'worker us/tx':>12} "
            f"{'on the wire':>14} {'pty floor ms':>12} {'% of round':>10} {'wire floor ms':>13}"
        )
        slowest = max(_lines(r), key=lambda e: window / _f(e["rounds"]))
        for e in _lines(r):
            ms = 1000 * window / _f(e["rounds"])
            tx = _f(e["transactions"])
            worker = 1e6 * _f(e["worker_cpu_s"]) / tx if tx else 0.0
            unit = "req/s" if e["kind"] == "modbus" else "scans/s"
            if "floor_pty_s" in e:
                pty = f"{1000 * _f(e['floor_pty_s']):12.1f} {1000 * _f(e['floor_pty_s']) / ms:10.0%}"
            else:
                pty = f"{'-':>12} {'-':>10}"
            print(
                f"  {e['line']!s:7} {_f(e['devices']):7.0f} {_f(e['rounds']):7.1f} {ms:9.1f} "
                f"{ms / d['ms_per_round']:7.0%} {worker:12.0f} {_f(e['wire']) / window:6.0f} {unit:7} {pty} "
                f"{1000 * _f(e['floor_wire_s']):13.1f}{' <- slowest' if e is slowest else ''}"
            )
        ms = 1000 * window / _f(slowest["rounds"])
        line = f"  limit: {slowest['line']} ({slowest['kind']}, {_f(slowest['devices']):.0f} devices) sets the round"
        if "floor_pty_s" in slowest:
            floor = 1000 * _f(slowest["floor_pty_s"])
            line += (
                f"; {floor / ms:.0%} of its {ms:.0f} ms is the RTU silent interval, {1 - floor / ms:.0%} is time in "
                f"Python (poller, client, slave simulator, waiting for the GIL); on a real {args.baudrate} baud wire "
                f"the same line needs at least {_f(slowest['floor_wire_s']):.2f} s per round"
            )
        print(line)
    print(
        "\nNote: the simulators (Modbus slaves, DeviceNet nodes), the DeviceNet scanners and the poller's bus workers "
        "all run in this one Python\nprocess: they share one GIL and the machine's "
        f"{os.cpu_count()} cores, so 'CPU us/tx' (process CPU / FleetPoller.transactions()) includes the simulators' "
        "work\n('sims' = their share of the process CPU). 'cores' near 1.0 means the GIL is saturated: one thread "
        "runs Python at a time,\nand a thread woken by I/O (a Modbus answer, a slave's silence timer) may wait up to "
        f"the switch interval ({sys.getswitchinterval() * 1000:g} ms) for it.\nPeak MiB = ru_maxrss of the child "
        "process (start-up included); KiB/dev = (peak - RSS after imports) / devices."
    )


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
