"""Benchmark: the DeviceNet master under foreign traffic, and its CPU at the scan interval a caller asks for.

Run: ``python bench/devicenet/load.py [--seconds 3] [--nodes 8] [--flood 0 4000 8000 28000] [--periods 0.02 1]``

flood: one simulator thread serves N JJR8000 slaves, one scanner polls them every 10 ms, and a third thread
puts foreign frames (other nodes' polls and answers, group 3 traffic) on the bus at the given rate (paced in
batches of 1 ms). A 500 kbit/s bus carries about 4,000 to 8,000 frames/s of such traffic; 28,000/s is what the
issue measured the old master at. Printed: the flood rate reached, the poll answers per second and their ratio
to the run without flood, the misses, and whether the master stayed on line with every slave connected.

period: the I/O thread's CPU per second of wall time with N slaves at ``period=P`` (scan interval and expected
packet rate follow P, as the transport's URL parameter sets them), side by side with the polls per second, as
ratios against the first period given (the old fixed 20 ms scan), and per poll sent. The I/O thread is the
process's scheduler thread ``starterbus-io`` (all of it: its waits, every driver it serves: here only this bus,
a virtual bus waited on in its own queue, so no ``can-reader`` thread; one would be added); before issue 29 it
was the scanner thread. The machine's other load moves these figures by 10-20 % from run to run: compare runs
of two trees alternated, per poll.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import uuid

import can

from starterbus.core import SimulatedStarter, get_profile
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.driver.scanner import Scanner, SlaveLink
from starterbus.transports.devicenet.master.link import LinkConfig, ScannerConfig, ScannerState
from starterbus.transports.devicenet.simulator import DeviceNetSimulator
from starterbus.transports.devicenet.url import timing_for_period

FOREIGN = [
    can.Message(arbitration_id=can_id, data=bytes.fromhex(data), is_extended_id=False)
    for can_id, data in (
        (0x3E9, "0102030405"),  # poll response of MAC 41
        (0x54D, "0001"),  # poll command to MAC 41
        (0x54B, "00CB00"),  # explicit response of MAC 41
        (0x63F, "FFFFFFFF"),  # group 3
        (0x0E9, "01"),  # group 1 of MAC 41
        (0x557, "00330329000000"),  # MAC 42 checking its MAC
    )
]


def setup(nodes: int, interval: float, epr_ms: int) -> tuple[str, DeviceNetSimulator, Scanner, list[SlaveLink]]:
    channel = f"load-{uuid.uuid4().hex[:8]}"
    profile = get_profile("jjr8000")
    simulator = DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.02)
    for mac in range(1, nodes + 1):
        simulator.add_node(SimulatedStarter(profile), mac, assemblies=AssemblySet.EXTENDED)
    simulator.start()
    simulator.wait_online(5)
    scanner = Scanner(ScannerConfig("virtual", channel, dup_mac_wait=0.02, timeout=1.0))
    scanner.wait_online(5)
    links = [
        scanner.attach(LinkConfig(mac, "extended", epr_ms=epr_ms, interval=interval)) for mac in range(1, nodes + 1)
    ]
    if not scanner.wait_for(lambda: all(link.established for link in links), 10):
        raise SystemExit(f"only {sum(link.established for link in links)} of {nodes} slaves connected")
    return channel, simulator, scanner, links


def flood(channel: str, rate: int, stop: threading.Event, sent: list[int]) -> None:
    bus = can.Bus(interface="virtual", channel=channel)
    per_ms = max(1, rate // 1000)
    count = 0
    start = time.perf_counter()
    try:
        while not stop.is_set():
            for i in range(per_ms):
                bus.send(FOREIGN[(count + i) % len(FOREIGN)])
            count += per_ms
            ahead = start + count / rate - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)  # pacing the load generator, not synchronising a test
    finally:
        sent.append(count)
        bus.shutdown()


def measure_flood(nodes: int, rate: int, seconds: float) -> dict[str, float]:
    channel, simulator, scanner, links = setup(nodes, 0.01, 100)
    stop = threading.Event()
    sent: list[int] = []
    flooder = threading.Thread(target=flood, args=(channel, rate, stop, sent)) if rate else None
    try:
        if flooder is not None:
            flooder.start()
        time.sleep(0.3)
        answers0, misses0, t0 = (
            sum(link.responses for link in links),
            sum(link.misses for link in links),
            time.perf_counter(),
        )
        time.sleep(seconds)
        elapsed = time.perf_counter() - t0
        answers = sum(link.responses for link in links) - answers0
        misses = sum(link.misses for link in links) - misses0
        stop.set()
        if flooder is not None:
            flooder.join()
        connected = sum(link.established for link in links)
        online = scanner.state is ScannerState.ONLINE
    finally:
        stop.set()
        scanner.close()
        simulator.close()
    return {
        "flood": (sent[0] / (elapsed + 0.3)) if sent else 0.0,
        "answers": answers / elapsed,
        "misses": misses,
        "connected": connected,
        "online": float(online),
    }


def measure_period(nodes: int, period: float, seconds: float) -> dict[str, float]:
    interval, epr_ms = timing_for_period(period)
    _, simulator, scanner, _ = setup(nodes, interval, epr_ms)
    try:
        time.sleep(0.3)
        polls0, cpu0, t0 = scanner.polls_sent, scanner.io_cpu, time.perf_counter()
        time.sleep(seconds)
        elapsed = time.perf_counter() - t0
        polls, cpu = scanner.polls_sent - polls0, scanner.io_cpu - cpu0
    finally:
        scanner.close()
        simulator.close()
    return {"polls": polls / elapsed, "cpu": cpu / elapsed, "interval": interval, "epr": epr_ms}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="length of one measurement")
    parser.add_argument("--nodes", type=int, default=8)
    parser.add_argument("--flood", type=int, nargs="*", default=[0, 4000, 8000, 28000], help="frames/s")
    parser.add_argument("--periods", type=float, nargs="*", default=[0.02, 1.0], help="seconds")
    args = parser.parse_args(argv)
    print(f"python {sys.version.split()[0]}, python-can {can.__version__}, virtual bus, {args.nodes} slaves")
    if args.flood:
        print()
        print(
            f"{'flood asked':>12} {'reached':>9} {'answers/s':>10} {'ratio':>6} {'misses':>7} {'connected':>10} "
            f"{'on line':>8}"
        )
        quiet = None
        for rate in args.flood:
            run = measure_flood(args.nodes, rate, args.seconds)
            quiet = quiet or run["answers"]
            print(
                f"{rate:>10}/s {run['flood']:>7.0f}/s {run['answers']:>10.1f} {run['answers'] / quiet:>5.2f}x "
                f"{run['misses']:>7.0f} {run['connected']:>6.0f}/{args.nodes:<3} {'yes' if run['online'] else 'NO':>8}"
            )
    if args.periods:
        print()
        print(
            f"{'period':>8} {'interval':>9} {'EPR':>8} {'polls/s':>9} {'ratio':>7} {'I/O CPU':>9} {'ratio':>7} "
            f"{'per poll':>9}"
        )
        base = None
        for period in args.periods:
            run = measure_period(args.nodes, period, args.seconds)
            base = base or run
            print(
                f"{period:>7g}s {run['interval']:>8g}s {run['epr']:>6.0f}ms {run['polls']:>9.1f} "
                f"{run['polls'] / base['polls']:>6.3f}x {run['cpu'] * 100:>8.2f}% {run['cpu'] / base['cpu']:>6.3f}x "
                f"{run['cpu'] / max(run['polls'], 1e-9) * 1e6:>7.1f}us"
            )
        print("I/O CPU = the I/O thread's CPU time per second of wall time (% of one core), and per poll sent")
    return 0


if __name__ == "__main__":
    sys.exit(main())
