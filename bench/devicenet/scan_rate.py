"""Benchmark: polls per second of one DeviceNet master against N simulated JJR8000 slaves on python-can's
virtual bus, side by side with a bare python-can loop of the same frames, plus the wire-limited scan time.

Run: ``python bench/devicenet/scan_rate.py [--seconds 2] [--nodes 1 8 63]``

For each N the script starts one simulator thread serving N nodes (extended assemblies: 2-byte poll command,
6-byte response) and one scanner polling as fast as it can (poll=0), measures completed polls per second and
CPU time per poll (the whole process, and the scanner's I/O thread alone), then runs the bare baseline: one
thread sends the same poll commands one by one and waits for each answer, a second thread answers each with
a prebuilt 6-byte frame. The goal was at least 0.7 x the bare loop; the master's 2 ms answer guard (no answer
is used before a second answer to the same poll could have shown a duplicate responder) caps one slave at
about 450 polls/s, so the last column repeats the first scanner run without it.

The wire table computes how long one scan of a 63-node bus takes on a real CAN bus from the frames' bit
lengths: a classic CAN data frame with an 11-bit identifier has 47 + 8 x n bits (n data bytes) including
interframe space; bit stuffing adds at most floor((34 + 8 x n - 1) / 4) bits (worst case: the 34 + 8 x n
bits from start of frame to the end of the CRC stuffed every fourth bit).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import uuid
from collections.abc import Callable
from functools import partial

import can

from starterbus.core import SimulatedStarter, get_profile
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.ids import poll_command_id, poll_response_id
from starterbus.transports.devicenet.driver.scanner import Scanner
from starterbus.transports.devicenet.master.link import ANSWER_GUARD, LinkConfig, LinkState, ScannerConfig
from starterbus.transports.devicenet.simulator import DeviceNetSimulator


def bare_responder(channel: str, nodes: int) -> tuple[threading.Event, threading.Thread, can.BusABC]:
    """A thread answering every poll command of MAC 1..nodes with a prebuilt 6-byte input assembly."""
    bus = can.Bus(interface="virtual", channel=channel)
    answers = {
        poll_command_id(mac): can.Message(arbitration_id=poll_response_id(mac), data=bytes(6), is_extended_id=False)
        for mac in range(1, nodes + 1)
    }
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            message = bus.recv(0.05)
            if message is not None:
                answer = answers.get(message.arbitration_id)
                if answer is not None:
                    bus.send(answer)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return stop, thread, bus


def measure_scanner(
    nodes: int, seconds: float, responder: str = "simulator", answer_guard: float = ANSWER_GUARD
) -> dict[str, float]:
    """The scanner polling ``nodes`` slaves as fast as it can. ``responder`` "simulator": the JJR8000
    simulator answers (end to end); "bare": after the connections were set up by the simulator, the bare
    loop's answering thread takes over, so only the master's cost differs from the bare loop."""
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    profile = get_profile("jjr8000")
    simulator = DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.02)
    for mac in range(1, nodes + 1):
        simulator.add_node(SimulatedStarter(profile), mac, assemblies=AssemblySet.EXTENDED)
    simulator.start()
    simulator.wait_online(5)
    config = ScannerConfig(
        "virtual", channel, poll_period=0.0, dup_mac_wait=0.02, timeout=1.0, answer_guard=answer_guard
    )
    scanner = Scanner(config)
    bare: tuple[threading.Event, threading.Thread, can.BusABC] | None = None
    try:
        scanner.wait_online(5)
        links = [scanner.attach(LinkConfig(mac, "extended", epr_ms=5000)) for mac in range(1, nodes + 1)]
        deadline = time.monotonic() + 10
        while not all(link.state is LinkState.ESTABLISHED for link in links):
            if time.monotonic() > deadline:
                raise SystemExit(f"only {sum(link.established for link in links)} of {nodes} slaves connected")
            time.sleep(0.01)
        if responder == "bare":
            simulator.close()
            bare = bare_responder(channel, nodes)
        time.sleep(0.2)  # settle
        responses0 = sum(link.responses for link in links)
        misses0 = sum(link.misses for link in links)
        cpu0, io0, t0 = time.process_time(), scanner.io_cpu, time.perf_counter()
        time.sleep(seconds)
        responses = sum(link.responses for link in links) - responses0
        elapsed = time.perf_counter() - t0
        cpu, io = time.process_time() - cpu0, scanner.io_cpu - io0
        misses = sum(link.misses for link in links) - misses0
    finally:
        scanner.abandon() if responder == "bare" else scanner.close()
        simulator.close()
        if bare is not None:
            bare[0].set()
            bare[1].join()
            bare[2].shutdown()
    return {
        "rate": responses / elapsed,
        "cpu_us": cpu / max(responses, 1) * 1e6,
        "io_us": io / max(responses, 1) * 1e6,
        "misses": misses,
    }


def measure_bare(nodes: int, seconds: float) -> dict[str, float]:
    """The baseline: one thread sends the poll commands one by one and waits for each answer."""
    channel = f"bare-{uuid.uuid4().hex[:8]}"
    master = can.Bus(interface="virtual", channel=channel)
    stop, thread, slave = bare_responder(channel, nodes)
    commands = [
        can.Message(arbitration_id=poll_command_id(mac), data=b"\x00\x01", is_extended_id=False)
        for mac in range(1, nodes + 1)
    ]
    count = 0
    cpu0, t0 = time.process_time(), time.perf_counter()
    end = t0 + seconds
    while time.perf_counter() < end:
        for command in commands:
            master.send(command)
            if master.recv(1.0) is not None:
                count += 1
    elapsed = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    stop.set()
    thread.join()
    master.shutdown()
    slave.shutdown()
    return {"rate": count / elapsed, "cpu_us": cpu / max(count, 1) * 1e6}


def frame_bits(data_bytes: int, worst_case_stuffing: bool) -> int:
    bits = 47 + 8 * data_bytes
    if worst_case_stuffing:
        bits += (34 + 8 * data_bytes - 1) // 4
    return bits


def wire_table(nodes: int = 63) -> list[str]:
    lines = [f"wire-limited scan time of a {nodes}-node bus (poll command + poll response per node):"]
    lines.append(f"  {'assemblies':<22}{'bitrate':>9}{'nominal':>12}{'worst stuffing':>17}{'max scans/s':>14}")
    for name, command, response in (("basic 2 -> 1 (1+4 B)", 1, 4), ("extended 102 -> 101", 2, 6)):
        nominal = nodes * (frame_bits(command, False) + frame_bits(response, False))
        worst = nodes * (frame_bits(command, True) + frame_bits(response, True))
        for rate in (125_000, 250_000, 500_000):
            lines.append(
                f"  {name:<22}{rate // 1000:>6} k{nominal / rate * 1000:>10.1f} ms{worst / rate * 1000:>14.1f} ms"
                f"{rate / worst:>14.1f}"
            )
    return lines


def median_run(measure: Callable[[], dict[str, float]], repeats: int) -> dict[str, float]:
    runs = sorted((measure() for _ in range(repeats)), key=lambda run: run["rate"])
    return runs[len(runs) // 2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="length of one measurement")
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure (the median is shown)")
    parser.add_argument("--nodes", type=int, nargs="+", default=[1, 8, 63])
    args = parser.parse_args(argv)
    print(
        f"python {sys.version.split()[0]}, python-can {can.__version__}, virtual bus, "
        f"median of {args.repeats} x {args.seconds:g} s; CPU per poll = whole process (I/O thr = scanner thread)"
    )
    header = (
        f"{'N':>3}  {'bare loop':>10} {'CPU':>7}  {'scanner+bare responder':>23} {'CPU':>7} {'I/O thr':>7} {'ratio':>6}"
        f"  {'scanner+simulator':>18} {'CPU':>7} {'ratio':>6}  {'bare responder, guard 0':>24} {'ratio':>6}"
    )
    print(header)
    software: dict[int, float] = {}
    for nodes in args.nodes:
        bare = median_run(partial(measure_bare, nodes, args.seconds), args.repeats)
        master = median_run(partial(measure_scanner, nodes, args.seconds, "bare"), args.repeats)
        full = median_run(partial(measure_scanner, nodes, args.seconds, "simulator"), args.repeats)
        unguarded = median_run(partial(measure_scanner, nodes, args.seconds, "bare", 0.0), args.repeats)
        ratio, ratio_full = master["rate"] / bare["rate"], full["rate"] / bare["rate"]
        software[nodes] = nodes / full["rate"]
        print(
            f"{nodes:>3}  {bare['rate']:>8.0f}/s {bare['cpu_us']:>5.1f}us  {master['rate']:>21.0f}/s "
            f"{master['cpu_us']:>5.1f}us {master['io_us']:>5.1f}us {ratio:>5.2f}x  {full['rate']:>16.0f}/s "
            f"{full['cpu_us']:>5.1f}us {ratio_full:>5.2f}x  {unguarded['rate']:>22.0f}/s "
            f"{unguarded['rate'] / bare['rate']:>5.2f}x" + ("" if ratio >= 0.7 else "  (master below the 0.7x goal)")
        )
    print()
    print("polls/s = completed poll round trips per second (all slaves together); ratio = against the bare loop")
    print(
        f"the master holds each slave's next poll until its answer is {ANSWER_GUARD * 1000:g} ms old (no second "
        "answer: no duplicate responder); guard 0 = publish at once"
    )
    print()
    for line in wire_table():
        print(line)
    if 63 in software:
        wire = 63 * (frame_bits(2, True) + frame_bits(6, True)) / 500_000
        print()
        print(
            f"63 slaves: the scanner needs {software[63] * 1000:.1f} ms of software time per scan (with the simulator "
            f"in the same process), the wire {wire * 1000:.1f} ms at 500 kbit/s (extended, worst-case stuffing): "
            + ("the wire limits a real bus." if wire > software[63] else "software limits.")
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
