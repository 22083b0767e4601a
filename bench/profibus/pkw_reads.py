"""PKW parameter reads per second through the simulated and the gateway channel, with DP cycles per read.

    python bench/profibus/pkw_reads.py [--seconds 1.0] [--json]

Every read is one complete PKW handshake (clear cycle with "no task" until "no response", then the task until
its answer, see docs/profibus.md) of JJR8000 p3 (ramp time), timed at the link level (``CyclicLink.pkw``) and
once at the Device level (``Device.read``: validation, scaling). Channels:

- ``sim``: the in-process simulated DP slave (no I/O);
- ``gateway``: the simulated Modbus TCP gateway on loopback (a real pymodbus server with its own DP cycle),
  reached with pymodbus' sync TCP client: each exchange is an FC16 write and an FC03 read; with its default
  input staleness margin (``stale_cycles=1``); ``gw-m0``: the same with ``stale_cycles=0``.

Level ``link`` reads p3 back to back: every task has the INDL of the one before, the case the staleness margin
costs most; ``mixed`` alternates p3 and p4. Level ``open`` opens a session and reads p3 once, again and again
(what a new session costs before its first value: the start fence reads included); "cycles/read" is then the
exchanges per session.

``cycle=0`` runs exchanges back to back on demand; ``cycle>0`` exchanges every cycle (deadlines of the I/O loop,
driven here by the reading thread while it waits), so a read costs at least two cycle times. The ``floor``
line is a bare pymodbus FC16 + FC03 pair against the same gateway: one exchange with nothing of ours in it.
"cycles/read" counts exchanges per read (mean).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable

from starterbus.core.device import Device, open_device
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.profibus_pkw.codec.codes import TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import pkw_request
from starterbus.transports.profibus_pkw.driver.channels import attach_slave, detach_slave
from starterbus.transports.profibus_pkw.driver.link import CyclicLink
from starterbus.transports.profibus_pkw.master.handshake import Limits
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator
from starterbus.transports.profibus_pkw.transport import ProfibusPkwTransport

READ_P3 = pkw_request(TaskCode.READ_PARAMETER, 3)
READ_P4 = pkw_request(TaskCode.READ_PARAMETER, 4)
#: does this tree know input staleness margins (``stale_cycles`` in the URL)? The bench also runs on older trees
#: (PYTHONPATH=<checkout of another commit>) so that a baseline can be measured side by side.
HAS_MARGIN = "stale_cycles" in getattr(Limits, "__dataclass_fields__", {})


def timed(op: Callable[[], object], seconds: float) -> tuple[int, float]:
    op()  # warm up
    n = 0
    t0 = time.perf_counter()
    end = t0 + seconds
    while time.perf_counter() < end:
        op()
        n += 1
    return n, time.perf_counter() - t0


def link_reads(url: str, seconds: float, *, mixed: bool = False) -> dict[str, object]:
    """Reads of p3 back to back (each task on the INDL of the one before), or alternating p3 and p4 (mixed)."""
    with open_device(url, "jjr8000") as dev:
        transport = dev.transport
        assert isinstance(transport, ProfibusPkwTransport) and transport.link is not None
        link: CyclicLink = transport.link
        cycles: list[int] = []
        flip = [False]

        def op() -> None:
            request = READ_P4 if mixed and flip[0] else READ_P3
            flip[0] = not flip[0]
            job = link.pkw(request)
            assert job.response is not None and job.response.indl == request.indl
            cycles.append(job.cycles)

        n, wall = timed(op, seconds)
        return {"reads": n, "per_second": round(n / wall, 1), "ms_per_read": round(1000 * wall / n, 3),
                "cycles_per_read": round(sum(cycles) / len(cycles), 2), "max_cycles": max(cycles)}  # fmt: skip


def session_opens(url: str, seconds: float) -> dict[str, object]:
    """Open a session, read p3 once, close: the cost of a session's first value."""
    exchanges: list[int] = []

    def op() -> None:
        with open_device(url, "jjr8000") as dev:
            transport = dev.transport
            assert isinstance(transport, ProfibusPkwTransport) and transport.link is not None
            job = transport.link.pkw(READ_P3)
            assert job.response is not None and job.response.indl == 3
            exchanges.append(transport.link.stats().exchanges)

    n, wall = timed(op, seconds)
    return {"reads": n, "per_second": round(n / wall, 1), "ms_per_read": round(1000 * wall / n, 3),
            "cycles_per_read": round(sum(exchanges) / len(exchanges), 2), "max_cycles": max(exchanges)}  # fmt: skip


def device_reads(url: str, seconds: float) -> dict[str, object]:
    dev: Device
    with open_device(url, "jjr8000") as dev:
        n, wall = timed(lambda: dev.read_value("ramp_time"), seconds)
    return {"reads": n, "per_second": round(n / wall, 1), "ms_per_read": round(1000 * wall / n, 3)}


def floor_exchanges(port: int, seconds: float) -> dict[str, object]:
    from pymodbus.client import ModbusTcpClient

    client = ModbusTcpClient("127.0.0.1", port=port)
    try:

        def op() -> None:
            client.write_registers(0, [0, 0, 8, 0], device_id=1)
            client.read_holding_registers(0, count=4, device_id=1)

        n, wall = timed(op, seconds)
    finally:
        client.close()  # type: ignore[no-untyped-call]  # pymodbus 3.x leaves ModbusTcpClient.close() unannotated
    return {"exchanges": n, "per_second": round(n / wall, 1), "ms_per_exchange": round(1000 * wall / n, 3)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=1.0, help="time per line (default 1.0)")
    parser.add_argument("--gateway-cycle", type=float, default=0.001, help="the simulated gateway's DP cycle (s)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    profile = get_profile("jjr8000")
    rows: list[dict[str, object]] = []

    attach_slave("bench", SimulatedStarter(profile))
    try:
        for cycle in ("0", "0.001", "0.005"):
            url = f"profibus-pkw+sim://bench?ppo=1&cycle={cycle}"
            rows.append({"channel": "sim", "cycle": cycle, "level": "link", **link_reads(url, args.seconds)})
        url = "profibus-pkw+sim://bench?ppo=1&cycle=0"
        rows.append({"channel": "sim", "cycle": "0", "level": "mixed", **link_reads(url, args.seconds, mixed=True)})
        url = "profibus-pkw+sim://bench?ppo=1&cycle=0"
        rows.append({"channel": "sim", "cycle": "0", "level": "device", **device_reads(url, args.seconds)})
        rows.append({"channel": "sim", "cycle": "0", "level": "open", **session_opens(url, args.seconds)})
    finally:
        detach_slave("bench")

    with ProfibusGatewaySimulator(SimulatedStarter(profile), port=0, ppo=1, cycle=args.gateway_cycle) as sim:
        floor = floor_exchanges(sim.port, args.seconds)
        for cycle in ("0", "0.005"):
            url = f"{sim.url(0)}&cycle={cycle}"
            rows.append({"channel": "gateway", "cycle": cycle, "level": "link", **link_reads(url, args.seconds)})
            rows.append(
                {"channel": "gateway", "cycle": cycle, "level": "mixed", **link_reads(url, args.seconds, mixed=True)}
            )
            if HAS_MARGIN:  # the gateway's default margin is stale_cycles=1; without it, as before
                url += "&stale_cycles=0"
                rows.append({"channel": "gw-m0", "cycle": cycle, "level": "link", **link_reads(url, args.seconds)})
        rows.append({"channel": "gateway", "cycle": "0", "level": "device",
                     **device_reads(f"{sim.url(0)}&cycle=0", args.seconds)})  # fmt: skip
        for cycle in ("0", "0.005"):
            url = f"{sim.url(0)}&cycle={cycle}"
            rows.append({"channel": "gateway", "cycle": cycle, "level": "open", **session_opens(url, args.seconds)})

    if args.json:
        json.dump({"gateway_dp_cycle": args.gateway_cycle, "floor": floor, "rows": rows}, sys.stdout, indent=2)
        print()
        return 0
    print(f"JJR8000 p3 reads; simulated gateway DP cycle {args.gateway_cycle * 1000:g} ms")
    print(
        f"floor: bare pymodbus FC16+FC03 pair on the gateway: {floor['per_second']} exchanges/s "
        f"({floor['ms_per_exchange']} ms)"
    )
    print(f"{'channel':8} {'cycle s':>8} {'level':7} {'reads/s':>10} {'ms/read':>9} {'cycles/read':>12} {'x floor':>8}")
    for r in rows:
        cyc = r.get("cycles_per_read", "")
        ratio = ""
        if r["channel"] in ("gateway", "gw-m0"):
            ratio = f"{float(r['ms_per_read']) / float(floor['ms_per_exchange']):.1f}"  # type: ignore[arg-type]
        print(
            f"{r['channel']:8} {r['cycle']:>8} {r['level']:7} {r['per_second']:>10} {r['ms_per_read']:>9} "
            f"{cyc!s:>12} {ratio:>8}"
        )
    print("x floor: time per read / time of one bare FC16+FC03 exchange (a read needs at least 2 exchanges)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
