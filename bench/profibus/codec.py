"""PPO1 telegram encode+decode per second, against a bare precompiled ``struct`` pack+unpack in the same run.

    python bench/profibus/codec.py [--seconds 0.5] [--json]

What is timed (best of several repeats, each ~``seconds`` long), per operation:

- ``bare struct``: ``S.unpack(S.pack(w0, w1, w2, w3))`` with one precompiled ``struct.Struct('>4H')``: the floor;
- ``codec master cycle``: what a master does each DP cycle: encode its output telegram (``encode_ppo1`` of a
  ``Ppo1Out``) and decode the slave's input bytes (``decode_ppo1_in`` -> ``Ppo1In``);
- ``codec round trip``: ``decode_ppo1_out(encode_ppo1(t))``, the same four words out and back in;
- ``codec + meaning``: the master cycle plus reading ``.response`` and ``.indl`` (enum lookup, INDL mask);
- ``frozen dataclass`` (reference): building a 4-field frozen slotted dataclass alone, no packing.

The goal of issue 3 is a codec within 5x of bare struct. Prints the ratio of each line to bare struct.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import timeit
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

from starterbus.transports.profibus_pkw.codec.telegram import (
    Ppo1Out,
    decode_ppo1_in,
    decode_ppo1_out,
    encode_ppo1,
)

GOAL = 5.0


@dataclass(frozen=True, slots=True)
class FrozenWords:
    ind: int
    pwe: int
    stw: int
    spare: int


class Row(TypedDict):
    """One line of the report."""

    what: str
    ns: float
    per_second: int
    ratio_to_struct: float


def measure(fn: Callable[[], object], seconds: float, repeats: int = 7) -> float:
    """Best time per call (s): calibrate a loop count to ``seconds``, keep the fastest of ``repeats``."""
    timer = timeit.Timer(fn)
    number, _ = timer.autorange()
    number = max(number, int(number * seconds / 0.2))
    return min(timer.repeat(repeat=repeats, number=number)) / number


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=0.3, help="time per repeat (default 0.3)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    s4 = struct.Struct(">4H")
    pack, unpack = s4.pack, s4.unpack
    out = Ppo1Out(0x0207, 350, 0x0009, 0)  # write p7 = 350 with the start bit
    answer = bytes.fromhex("01 07 01 5E 09 00 03 C0")

    def bare() -> object:
        return unpack(pack(0x0207, 350, 0x0009, 0))

    def master_cycle() -> object:
        encode_ppo1(out)
        return decode_ppo1_in(answer)

    def round_trip() -> object:
        return decode_ppo1_out(encode_ppo1(out))

    def with_meaning() -> object:
        encode_ppo1(out)
        t = decode_ppo1_in(answer)
        return t.response, t.indl

    def frozen() -> object:
        return FrozenWords(0x0207, 350, 0x0009, 0)

    assert bare() == tuple(out) and round_trip() == out  # the same words
    rows = [
        ("bare struct pack+unpack", bare),
        ("codec master cycle (encode out + decode in)", master_cycle),
        ("codec round trip (encode + decode, same words)", round_trip),
        ("codec master cycle + .response/.indl", with_meaning),
        ("frozen dataclass build alone (reference)", frozen),
    ]
    results = [(name, measure(fn, args.seconds)) for name, fn in rows]
    floor = results[0][1]
    report: list[Row] = [
        {"what": name, "ns": round(t * 1e9, 1), "per_second": round(1 / t), "ratio_to_struct": round(t / floor, 2)}
        for name, t in results
    ]
    worst = max(r["ratio_to_struct"] for r in report[1:4])
    if args.json:
        json.dump({"python": sys.version.split()[0], "goal_ratio": GOAL, "rows": report, "worst_codec_ratio": worst},
                  sys.stdout, indent=2)  # fmt: skip
        print()
    else:
        print(f"Python {sys.version.split()[0]}; goal: codec within {GOAL:g}x of bare struct")
        print(f"{'':48} {'ns/op':>8} {'ops/s':>12} {'x struct':>9}")
        for r in report:
            print(f"{r['what']:48} {r['ns']:8.1f} {r['per_second']:12,d} {r['ratio_to_struct']:9.2f}")
        print(f"worst codec ratio {worst:.2f} -> {'within' if worst <= GOAL else 'OVER'} the {GOAL:g}x goal")
    return 0 if worst <= GOAL else 1


if __name__ == "__main__":
    sys.exit(main())
