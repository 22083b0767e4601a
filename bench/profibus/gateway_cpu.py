"""CPU of a status read and of a PKW read through the Modbus TCP gateway channel, on demand (``cycle=0``).

    cd /tmp && python -m starterbus.bench.profibus.gateway_cpu [--seconds 2] [--json]
    cd /tmp && PYTHONPATH=/path/to/other/tree python -m starterbus.bench.profibus.gateway_cpu   # the same, there

The simulated gateway (a pymodbus server with its own DP cycle) runs in a process of its own, always from the
installed tree, so only the client side is measured and the server is the same for every tree compared. Per
row: operations, CPU of this process per operation (every thread of it: user + system, and the user part alone,
the Python side; the system part is mostly the loopback TCP stack), wall time per operation, and DP exchanges per
operation (``CyclicLink.stats``), so trees whose reads take a different number of
exchanges compare per exchange too. Rows: ``status`` (``Device.status``: PZD, fresh inputs) and ``pkw``
(``CyclicLink.pkw`` of JJR8000 p3: clear + task).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable

from starterbus.core.device import open_device

SERVER = """
import sys
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator
sim = ProfibusGatewaySimulator(SimulatedStarter(get_profile("jjr8000")), port=0, ppo=1, cycle=float(sys.argv[1]))
sim.start()
print(sim.port, flush=True)
sys.stdin.read()
sim.close()
"""


def measure(op: Callable[[], object], exchanges: Callable[[], int], seconds: float) -> dict[str, float]:
    op()  # warm up
    n, first = 0, exchanges()
    use0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    end = t0 + seconds
    while time.perf_counter() < end:
        op()
        n += 1
    use, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter() - t0
    user = use.ru_utime - use0.ru_utime
    cpu = user + use.ru_stime - use0.ru_stime
    per = (exchanges() - first) / n
    return {
        "ops": n,
        "cpu_us": round(1e6 * cpu / n, 1),
        "user_us": round(1e6 * user / n, 1),
        "wall_us": round(1e6 * wall / n, 1),
        "exchanges": round(per, 2),
        "cpu_us_per_exchange": round(1e6 * cpu / n / per, 1) if per else 0.0,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=2.0, help="time per row (default 2.0)")
    parser.add_argument("--gateway-cycle", type=float, default=0.001, help="the simulated gateway's DP cycle (s)")
    parser.add_argument(
        "--stale-time", type=float, default=0.0, help="the URL's stale_time (s; the simulated gateway's URLs: 2 cycles)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the server from the installed tree
    server = subprocess.Popen(
        [sys.executable, "-c", SERVER, str(args.gateway_cycle)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd="/",
    )
    try:
        assert server.stdout is not None
        port = int(server.stdout.readline())
        url = f"profibus-pkw+gateway://127.0.0.1:{port}?ppo=1&out=0&in=0&unit=1&cycle=0"
        if args.stale_time:
            url += f"&stale_time={args.stale_time:g}"
        rows: dict[str, dict[str, float]] = {}
        with open_device(url, "jjr8000") as dev:
            link = dev.transport.link  # type: ignore[attr-defined]
            from starterbus.transports.profibus_pkw.codec.codes import TaskCode
            from starterbus.transports.profibus_pkw.codec.telegram import pkw_request

            p3 = pkw_request(TaskCode.READ_PARAMETER, 3)
            count: Callable[[], int] = lambda: link.stats().exchanges  # noqa: E731
            rows["status"] = measure(dev.status, count, args.seconds)
            rows["pkw"] = measure(lambda: link.pkw(p3), count, args.seconds)
    finally:
        if server.stdin is not None:
            server.stdin.close()
        server.wait(10)
    if args.json:
        json.dump(
            {"gateway_dp_cycle": args.gateway_cycle, "stale_time": args.stale_time, "rows": rows}, sys.stdout, indent=2
        )
        print()
        return 0
    print(
        f"gateway channel, cycle=0, simulated gateway DP cycle {args.gateway_cycle * 1000:g} ms, "
        f"stale_time {args.stale_time * 1000:g} ms"
    )
    print(
        f"{'row':7} {'ops':>6} {'CPU us/op':>10} {'user us/op':>11} {'wall us/op':>11} {'exch/op':>8} "
        f"{'CPU us/exch':>12}"
    )
    for name, r in rows.items():
        print(
            f"{name:7} {r['ops']:>6} {r['cpu_us']:>10} {r['user_us']:>11} {r['wall_us']:>11} {r['exchanges']:>8} "
            f"{r['cpu_us_per_exchange']:>12}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
