"""Check: what serve publishes, hashed, beside an older tree: the same digests mean the same bytes.

    python bench/serve/wire_digest.py [--before DIR]

Two digests (sha256), each tree's modules in a process of its own:

* ``session``: a scripted edge session (seeded random, fixed times) of four runs of 1500 steps, ``--refresh`` off
  and 7.5 s, each with wild and with steady devices: samples (offline, statuses that do not tell every bit, keys
  not read, values at the bounds, or moving by a few steps, inside and outside the deadbands of 0, 0.5, 1 and 3
  steps), ticks, connections and losses, history batches, DCMDs (commands,
  writes, garbage) done or refused, rebirths; every action's topic, payload bytes and QoS (or repr), and the
  session's counters at the end;
* ``ddata``: 30,000 DDATA payloads of random metrics of every data type (nulls, bounds, wrong types, aliases and
  names, timestamps, seq or none) through ``payloads.encode``: each payload's bytes, or its exception's type.

``--before DIR``: also the tree in DIR (a directory holding ``starterbus/``); exit 1 if a digest differs.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import random
import subprocess
import sys
from pathlib import Path
from typing import Any


def session_digest() -> tuple[str, int]:
    from starterbus.core.model import Value
    from starterbus.core.registry import get_profile
    from starterbus.core.status import Command, decode_status_word
    from starterbus.fleet.config import DeviceConfig, RemotePolicy
    from starterbus.fleet.poller import Sample
    from starterbus.serve.actions import CommandRequest, Publish, SessionOptions
    from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
    from starterbus.serve.schema import DataType, Payload
    from starterbus.serve.session import EdgeSession

    profile = get_profile("jjr5000")
    rng = random.Random(29036)
    wanted = ("phase_a_current", "phase_b_current", "phase_c_current", "line_voltage")
    meas = tuple(k for k in wanted if any(p.key == k for p in profile.measurements))
    params = ("ramp_time",)
    remote = RemotePolicy(frozenset({Command.START, Command.SOFT_STOP}), frozenset({"ramp_time"}))
    configs = [DeviceConfig(f"dev{i}", "l1", "jjr5000", "x", i + 1, 1.0, meas, params, remote) for i in range(5)]
    words = [0x2000, 0x2200, 0x2201, 0x0400, 0x2600, 0x0000]

    def build(refresh: float) -> Any:
        aliases = Aliases()
        node = node_metrics(aliases)
        steps = [0.0, 1.0, 3.0, 1.0, 0.5]
        devices = {
            c.name: device_metrics(
                c, profile, aliases, deadband_steps=steps[i], per_key={"ramp_time": 2.0} if i == 3 else None
            )
            for i, c in enumerate(configs)
        }
        return EdgeSession(SessionOptions("g", "n", refresh=refresh, buffer_messages=50), node, devices)

    walk: dict[tuple[str, str], int] = {}

    def steady(c: Any, t: float) -> Any:
        """A device that answers every poll with every value, which moves by 0-3 steps, its state seldom."""
        word = words[1] if rng.random() < 0.95 else rng.choice(words)
        values = {}
        for k in meas + params:
            p = profile.point(k)
            raw = walk.get((c.name, k), (p.raw_min + p.raw_max) // 2) + rng.choice([0, 0, 1, -1, 2, -3])
            walk[c.name, k] = raw = max(p.raw_min, min(p.raw_max, raw))
            values[k] = Value.from_raw(p, raw)
        if rng.random() < 0.02:
            del values[rng.choice(meas)]  # one key not read this poll
        return Sample(c.name, "l1", "jjr5000", t, True, decode_status_word(word, profile.faults), values, None, 0)

    def sample(c: Any, t: float, calm: bool) -> Any:
        if calm and rng.random() < 0.98:
            return steady(c, t)
        if rng.random() < 0.07:
            return Sample(c.name, "l1", "jjr5000", t, False, None, {}, "timeout", 1)
        status: Any = decode_status_word(rng.choice(words), profile.faults)
        values = {}
        for k in meas + params:
            if rng.random() < 0.1:
                continue  # not read this poll: quality bad
            p = profile.point(k)
            middle = (p.raw_min + p.raw_max) // 2
            near = rng.randint(p.raw_min, min(p.raw_max, p.raw_min + 5))
            raw = rng.choice([p.raw_min, p.raw_max, middle, rng.randint(p.raw_min, p.raw_max), near])
            values[k] = Value.from_raw(p, raw)
        if rng.random() < 0.15:
            status = None  # a path without the status word
        elif rng.random() < 0.15:
            bus = None if rng.random() < 0.5 else status.bus_control
            status = dataclasses.replace(status, ready=None, bus_control=bus)
        return Sample(c.name, "l1", "jjr5000", t, True, status, values, None, 0)

    def dcmd(name: str, typ: DataType, value: Any, ts: int) -> bytes:
        p = Payload(timestamp=ts)
        m = p.metrics.add(name=name, timestamp=ts, datatype=int(typ))
        if typ == DataType.BOOLEAN:
            m.boolean_value = value
        elif typ == DataType.INT32:
            m.int_value = value & 0xFFFFFFFF
        else:
            m.double_value = value
        return bytes(p.SerializeToString())

    out: list[tuple[object, ...]] = []

    def rec(actions: Any) -> None:
        for a in actions:
            out.append(("P", a.topic, a.payload.hex(), a.qos) if isinstance(a, Publish) else ("A", repr(a)))

    for refresh, calm in ((0.0, False), (7.5, False), (0.0, True), (7.5, True)):
        s = build(refresh)
        t = 1_800_000_000.0
        rec([s.next_will()])
        for step in range(1500):
            t += rng.choice([0.05, 0.2, 0.5, 1.0, 1.0001])
            ev = rng.random()
            if ev < 0.7 or step < 10:
                c = rng.choice(configs)
                rec(s.on_sample(sample(c, t - rng.random() * 0.01, calm), t))
            elif ev < 0.75:
                rec(s.on_tick(t))
            elif ev < 0.8 and not s.connected:
                rec([s.next_will()])
                s.connect_sent()
                rec(s.on_connected(t))
            elif ev < 0.83 and s.connected:
                s.on_disconnected()
            elif ev < 0.88:
                ps, ids = s.history(t, 7)
                rec(ps)
                s.history_sent(ids[: len(ids) // 2 + 1])
            elif ev < 0.93:
                c = rng.choice(configs)
                ms = int(t * 1000)
                data = [
                    dcmd("Device Control/Start", DataType.BOOLEAN, True, ms),
                    dcmd("Parameters/ramp_time", DataType.INT32, rng.randint(-5, 300), ms),
                    dcmd("Device Control/Reset", DataType.BOOLEAN, True, ms),
                    b"\x01garbage",
                ][rng.randint(0, 3)]
                acts = s.on_message(f"spBv1.0/g/DCMD/n/{c.name}", data, t)
                rec(acts)
                for a in acts:
                    if isinstance(a, CommandRequest):
                        if rng.random() < 0.5:
                            rec(s.command_done(a.device, "ok", t + 0.01))
                        else:
                            rec(s.refuse(a.device, "busy", t + 0.01, failed=rng.random() < 0.5))
            elif ev < 0.95:
                rebirth = dcmd("Node Control/Rebirth", DataType.BOOLEAN, True, int(t * 1000))
                rec(s.on_message("spBv1.0/g/NCMD/n", rebirth, t))
            else:
                rec(s.on_tick(t + 100))
        out.append(("END", s.seq, s.published, s.dropped, s.online))
    return hashlib.sha256(repr(out).encode()).hexdigest(), len(out)


def ddata_digest() -> tuple[str, int]:
    from starterbus.serve.metrics import MetricDef
    from starterbus.serve.payloads import encode
    from starterbus.serve.schema import DataType

    rng = random.Random(36)
    ts0 = 1_800_000_000_123
    types = [
        *(DataType.INT8, DataType.INT16, DataType.INT32, DataType.INT64, DataType.UINT8, DataType.UINT16),
        *(DataType.UINT32, DataType.UINT64, DataType.FLOAT, DataType.DOUBLE, DataType.BOOLEAN, DataType.STRING),
        *(DataType.TEXT, DataType.DATETIME),
    ]

    def value(t: DataType) -> Any:
        if rng.random() < 0.1:
            return None
        if t in (DataType.DOUBLE, DataType.FLOAT):
            floats = [0.0, -0.0, math.inf, -math.inf, math.nan, 1e308, 1e39, 5e-324, rng.uniform(-1e6, 1e6)]
            return rng.choice([*floats, 3, True, "1.5", "x"])
        if t == DataType.BOOLEAN:
            return rng.choice([True, False, 0, 1, "", "a"])
        if t in (DataType.STRING, DataType.TEXT):
            text = "".join(rng.choice("aé中\x00𝄞 /") for _ in range(rng.randint(0, 300)))
            return rng.choice([text, 5, 1.5, True, "\ud800"])
        ints = [0, 1, -1, 127, 128, -(2**31), 2**31 - 1, 2**63 - 1, -(2**63), 2**64 - 1, 2**70]
        return rng.choice([*ints, rng.randint(-(2**40), 2**40), True, 1.7, "12", "x"])

    digest = hashlib.sha256()
    n = 30_000
    for _ in range(n):
        entries = []
        for j in range(rng.randint(0, 12)):
            t = rng.choice(types)
            d = MetricDef(f"m{j}", t, rng.choice([None, 1, 127, 128, 300, 2**20, 2**40]))
            entries.append((d, value(t), rng.choice([0, 1, 127, 128, ts0, 2**63, 2**64 - 1])))
        timestamp = rng.choice([0, 1, ts0, 2**64 - 1])
        seq = rng.choice([None, 0, 127, 255])
        try:
            payload = encode(entries, timestamp=timestamp, seq=seq, birth=False)
        except Exception as exc:  # which exception a bad value raises is part of the digest
            payload = type(exc).__name__.encode()
        digest.update(payload + b"|")
    return digest.hexdigest(), n


def digests(root: Path | None) -> dict[str, Any]:
    if root is None:
        session, actions = session_digest()
        ddata, payloads = ddata_digest()
        return {"session": session, "actions": actions, "ddata": ddata, "payloads": payloads}
    env = dict(os.environ)
    plugin = root / "starterbus" / "plugins" / "starterbus-canopen"
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(plugin), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    out = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--json"], env=env, capture_output=True, text=True, check=True
    )
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--before", type=Path, help="also this tree (a directory holding starterbus/)")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # a tree's digests, for --before
    args = parser.parse_args()
    after = digests(None)
    if args.json:
        print(json.dumps(after))
        return
    print(f"this tree: session {after['session']} ({after['actions']} actions), ddata {after['ddata']}")
    if args.before is not None:
        before = digests(args.before)
        print(f"{args.before}: session {before['session']} ({before['actions']} actions), ddata {before['ddata']}")
        same = before == after
        print("the same bytes" if same else "DIFFERENT")
        if not same:
            sys.exit(1)


if __name__ == "__main__":
    main()
