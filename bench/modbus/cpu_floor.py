"""CPU per Modbus FC03 transaction against a hand-written exact-length floor, side by side (issue 14, item 4).

    python bench/modbus/cpu_floor.py [--tx 2000] [--rounds 7] [--changing] [--watch-floor]

On a bare pty hop (``line_emulator.py`` without pacing) to a plain pymodbus server, nominal 19200 baud, one
process measures in turn, round after round: the floor (``clients.exact_ops``: sleep out the 3.5-character
silence, write, ``select``, read exactly the predicted length), starterbus's raw ``read_registers`` and
``Device.read`` of the same four registers. Interleaving the three in one process makes the ratios robust to
what else the machine is doing; the median of the rounds is reported, with the spread, and the median of the
ratios within each round (paired: the clients of one round ran under the same load). ``--watch-floor`` adds
a fourth client, the same loop watching the line during the silence after each answer (as starterbus does
for the trailing-bytes rule) instead of sleeping before the request, and the ratios to it. Not run by the tests.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

from starterbus.bench.modbus import clients, throughput

BAUD = 19200


def cpu_per_tx(op: Callable[[], object], count: int) -> float:
    """Microseconds of this process's CPU per call of ``op``."""
    for _ in range(50):
        op()
    start = time.process_time()
    for _ in range(count):
        op()
    return (time.process_time() - start) / count * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tx", type=int, default=2000, help="transactions per client and round")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--changing", action="store_true", help="every FC03 answer differs (pymodbus server)")
    parser.add_argument("--watch-floor", action="store_true", help="also the floor that watches the silence")
    args = parser.parse_args()
    emulator = throughput.Emulator(0)
    server = throughput.start_server("pymodbus", emulator.server, BAUD, args.changing)
    samples: dict[str, list[float]] = {"floor": [], "raw": [], "device": []}
    floors = [("floor", False), ("watch", True)] if args.watch_floor else [("floor", False)]
    samples.update({name: [] for name, _ in floors})
    try:
        throughput.wait_ready(emulator.client, BAUD)
        for _ in range(args.rounds):
            for name, watch in floors:
                op, close = clients.exact_ops(emulator.client, BAUD, "fc03", True, watch=watch)
                samples[name].append(cpu_per_tx(op, args.tx))
                close()
            raw, close = clients.starterbus_ops(emulator.client, BAUD, "fc03", False)
            samples["raw"].append(cpu_per_tx(raw, args.tx))
            close()
            device, close = clients.starterbus_ops(emulator.client, BAUD, "fc03", True)
            samples["device"].append(cpu_per_tx(device, args.tx))
            close()
    finally:
        server.terminate()
        server.wait(timeout=10)
        emulator.close()
    median = {name: statistics.median(values) for name, values in samples.items()}
    print(
        f"FC03 x4 on a bare pty, {args.rounds} rounds x {args.tx} transactions"
        f"{', registers changing' if args.changing else ''}: CPU us per transaction (median, min-max)"
    )
    for name, values in samples.items():
        print(f"  {name:7s} {median[name]:6.1f}  ({min(values):.1f}-{max(values):.1f})")
    ratios = [median["raw"] / median["floor"], median["device"] / median["floor"]]
    per_round = [(r / f, d / f) for f, r, d in zip(samples["floor"], samples["raw"], samples["device"], strict=True)]
    print(f"  ratio to the floor: read_registers {ratios[0]:.2f}x   Device.read {ratios[1]:.2f}x   (goals 1.2x, 1.5x)")
    print("  per round:        " + "  ".join(f"{r:.2f}/{d:.2f}" for r, d in per_round))
    paired = [statistics.median(r for r, _ in per_round), statistics.median(d for _, d in per_round)]
    print(f"  median of the per-round ratios: read_registers {paired[0]:.2f}x   Device.read {paired[1]:.2f}x")
    if args.watch_floor:
        watching = median["watch"]
        print(
            f"  ratio to the watching floor ({watching / median['floor']:.2f}x the floor): read_registers "
            f"{median['raw'] / watching:.2f}x   Device.read {median['device'] / watching:.2f}x"
        )


if __name__ == "__main__":
    main()
