"""Modbus TCP: CPU and wall time per ``read_registers`` (FC03, 4 registers), side by side with pymodbus's
``ModbusTcpClient`` and, with ``--before``, another starterbus checkout, against one simulated gateway in a
process of its own (``tcp_framer.py`` runs the gateway's threads in the client's process).

    python -m starterbus.bench.modbus.tcp_cpu [--reads 200] [--rounds 30] [--before DIR]

``DIR``: a directory holding a ``starterbus`` that is the other checkout (e.g. a symlink to a ``git worktree`` of
an earlier commit), put first on that client's ``PYTHONPATH``. Each client is a process of its own, connected
once; round after round, each in a rotated order does ``--reads`` reads and reports the CPU time of its process
and the wall time. Turns this short see the same machine, so the ratios of the totals hold on a shared machine
(as ``cpu_floor.py``); the median of the per-round ratios is printed too. Not run by the tests.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from dataclasses import dataclass, field

GATEWAY = """
import sys
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
sim = ModbusTcpSimulator({2: SimulatedStarter(get_profile("jjr5000"))}).start()
print(sim.address[1], flush=True)
sys.stdin.read()
"""

#: a client process: ``KIND PORT`` on its command line, then a count of reads per line of its input
CLIENT = """
import sys, threading, time
kind, port = sys.argv[1], int(sys.argv[2])
if kind == "pymodbus":
    from pymodbus.client import ModbusTcpClient
    client = ModbusTcpClient("127.0.0.1", port=port)
    client.connect()
    def read():
        client.read_holding_registers(0x0100, count=4, device_id=2)
else:
    from starterbus.core.device import open_device
    device = open_device(f"modbus-tcp://127.0.0.1:{port}?unit=2", "jjr5000").open()
    read = lambda: device.transport.read_registers(0x0100, 4)
for _ in range(300):
    read()
print(threading.active_count(), flush=True)
for line in sys.stdin:
    count = int(line)
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(count):
        read()
    print(time.process_time() - cpu, time.perf_counter() - wall, flush=True)
"""


@dataclass
class Client:
    name: str
    process: subprocess.Popen[str]
    threads: int = 0
    cpu: list[float] = field(default_factory=list)
    wall: list[float] = field(default_factory=list)

    def turn(self, reads: int) -> None:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(f"{reads}\n")
        self.process.stdin.flush()
        cpu, wall = map(float, self.process.stdout.readline().split())
        self.cpu.append(cpu / reads * 1e6)
        self.wall.append(wall / reads * 1e6)


def start(name: str, kind: str, port: int, pythonpath: str | None) -> Client:
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [pythonpath, env.get("PYTHONPATH")]))
    process = subprocess.Popen(
        [sys.executable, "-c", CLIENT, kind, str(port)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert process.stdout is not None
    return Client(name, process, int(process.stdout.readline()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reads", type=int, default=200, help="reads per client per round")
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--before", metavar="DIR", help="a directory whose starterbus is the other checkout")
    args = parser.parse_args()
    gateway = subprocess.Popen(
        [sys.executable, "-c", GATEWAY], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    clients: list[Client] = []
    try:
        assert gateway.stdout is not None
        port = int(gateway.stdout.readline())
        clients.append(start("modbus-tcp", "starterbus", port, None))
        if args.before:
            clients.append(start("modbus-tcp before", "starterbus", port, args.before))
        clients.append(start("pymodbus ModbusTcpClient", "pymodbus", port, None))
        for round_ in range(args.rounds):
            for client in clients[round_ % len(clients) :] + clients[: round_ % len(clients)]:
                client.turn(args.reads)
        base = clients[-1]
        for client in clients:
            cpu, wall = statistics.fmean(client.cpu), statistics.fmean(client.wall)
            paired = statistics.median(c / b for c, b in zip(client.cpu, base.cpu, strict=True))
            print(
                f"FC03 x4 round trip, {client.name}: {wall:.0f} us wall, {cpu:.1f} us CPU per read "
                f"({cpu / statistics.fmean(base.cpu):.2f}x pymodbus's CPU, paired {paired:.2f}x), "
                f"{client.threads} thread(s)"
            )
        if args.before:
            now, before = clients[0], clients[1]
            paired = statistics.median(a / b for a, b in zip(now.cpu, before.cpu, strict=True))
            print(
                f"this checkout / before: CPU {statistics.fmean(now.cpu) / statistics.fmean(before.cpu):.2f} "
                f"(paired {paired:.2f}), wall {statistics.fmean(now.wall) / statistics.fmean(before.wall):.2f}"
            )
    finally:
        for client in clients:
            if client.process.stdin is not None:
                client.process.stdin.close()
            client.process.wait(10)
        if gateway.stdin is not None:
            gateway.stdin.close()
        gateway.wait(10)


if __name__ == "__main__":
    main()
