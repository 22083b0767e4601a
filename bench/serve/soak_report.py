"""The figures of ``bench/serve/unattended_soak.py``: samples matched between the history and the host
application (each loss put on the event it fell in), memory per serve process, latency, counters."""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import sqlite3
import statistics
from collections import defaultdict
from pathlib import Path
from typing import Any

GAP = 2.5  # s between two samples of a device (polled every second) that count as samples not taken


def _windows(
    events: list[dict[str, Any]], start: str, end: str, before: float, after: float
) -> list[tuple[float, float]]:
    """From each ``start`` event to the next ``end`` event (the same: around each one), widened."""
    out, opened = [], None
    for e in events:
        if start == end and e["kind"] == start:
            out.append((e["t"] - before, e["t"] + after))
        elif e["kind"] == start:
            opened = e["t"]
        elif e["kind"] == end and opened is not None:
            out.append((opened - before, e["t"] + after))
            opened = None
    return out


def _inside(t: float, windows: list[tuple[float, float]]) -> bool:
    return any(a <= t <= b for a, b in windows)


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def _memory(stats: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per serve process (pid): RSS and heap after its first two slots (warm-up) and at its last."""
    by_pid: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for row in stats:
        by_pid[row["pid"]].append(row)
    out = []
    for pid, rows in by_pid.items():
        steady = rows[2:] if len(rows) > 4 else rows
        rss = [r["rss_kib"] / 1024 for r in steady if r["rss_kib"]]
        blocks = [r["heap_blocks"] for r in steady if "heap_blocks" in r]
        objects = [r["gc_objects"] for r in steady if "gc_objects" in r]
        cpu = [r["cpu_s"] for r in rows if r["cpu_s"]]
        span = rows[-1]["t"] - rows[0]["t"]
        out.append(
            {
                "pid": pid,
                "slots": len(rows),
                "rss_mib": [round(rss[0], 1), round(rss[-1], 1), round(min(rss), 1), round(max(rss), 1)] if rss else [],
                "heap_blocks": [blocks[0], blocks[-1], min(blocks), max(blocks)] if blocks else [],
                "gc_objects": [objects[0], objects[-1]] if objects else [],
                "cpu_core": round((cpu[-1] - cpu[0]) / span, 3) if len(cpu) > 1 and span > 0 else None,
            }
        )
    return out


def analyse(soak: Any, args: argparse.Namespace, db: Path) -> dict[str, Any]:
    events, got = soak.events, soak.host.got
    before = _windows(events, "broker down", "broker down", 1.5, 0.5)  # the instant before the drop was seen
    during = _windows(events, "broker down", "broker up", -0.5, 0.0)  # buffered: nothing may be lost
    after = _windows(events, "broker up", "broker up", 0.0, 3.0)  # the new session's births
    disk = _windows(events, "disk full", "disk freed", 1.0, 10.0)
    line = _windows(events, "line lost", "line back", 1.0, 10.0)
    kill_t = next((e["t"] for e in events if e["kind"] == "serve killed (-9)"), None)
    restart_t = next((e["t"] for e in events if e["kind"] == "serve restarted"), None)
    serve_down = [(kill_t - 0.5, restart_t + 30.0)] if kill_t and restart_t else []
    killed = [(kill_t - 1.0, kill_t)] if kill_t else []
    starting = [(e["t"], e["t"] + 20.0) for e in events if e["kind"] in ("serve started", "serve restarted")]
    stop_t = next((e["t"] for e in events if e["kind"] == "serve stopping"), float("inf"))
    lost_line = soak.lost_line.name + "-"

    history: dict[str, set[int]] = defaultdict(set)
    gap_events: list[str] = []
    if db.exists():
        with contextlib.closing(sqlite3.connect(db)) as conn:
            for device, t in conn.execute("SELECT device, time FROM samples WHERE online = 1"):
                history[device].add(int(t * 1000))
            gap_events = [text for (text,) in conn.execute("SELECT text FROM events WHERE kind = 'gap' ORDER BY time")]
    received: dict[str, set[int]] = defaultdict(set)
    duplicates = 0
    for device in set(got.live) | set(got.historical) | set(got.births):
        data = got.live.get(device, []) + got.historical.get(device, [])
        duplicates += len(data) - len(set(data))
        received[device] = set(data) | set(got.births.get(device, []))

    if args.keep:  # the raw matching, for a closer look
        raw = {d: {"history": sorted(history[d]), "received": sorted(received[d])} for d in history}
        (soak.work / "matching.json").write_text(json.dumps(raw), encoding="utf-8")
        (soak.work / "trace.json").write_text(json.dumps(got.trace), encoding="utf-8")
    not_published: dict[str, int] = defaultdict(int)
    not_recorded: dict[str, int] = defaultdict(int)
    not_sampled: dict[str, int] = defaultdict(int)
    other_gaps: list[str] = []
    for device in sorted(set(history) | set(received)):
        h, r = history[device], received[device]
        for ts in h - r:
            t = ts / 1000
            where = (
                "at the final stop" if t >= stop_t - 1.0
                else "serve killed (-9)" if _inside(t, killed)
                else "serve starting (polled before the edge node took samples)" if _inside(t, starting)
                else "broker restart: sent before the drop was seen (QoS 0)" if _inside(t, before)
                else "broker restart: while the broker was down" if _inside(t, during)
                else "broker restart: the new session's first seconds" if _inside(t, after)
                else "other"
            )  # fmt: skip
            not_published[where] += 1
        for ts in r - h:
            t = ts / 1000
            where = (
                "serve killed (-9): not yet written" if _inside(t, serve_down)
                else "disk full (beyond --record-backlog)" if _inside(t, disk)
                else "other"
            )  # fmt: skip
            not_recorded[where] += 1
        times = sorted(h | r)
        for a, b in itertools.pairwise(times):
            if (b - a) / 1000 <= GAP:
                continue
            missing = round((b - a) / 1000) - 1
            mid = ((a + b) / 2) / 1000
            if device.startswith(lost_line) and _inside(mid, line):
                not_sampled["line lost (device offline)"] += missing
            elif _inside(mid, serve_down):
                not_sampled["serve not running (kill -9 -> restart)"] += missing
            else:
                not_sampled["other"] += missing
                other_gaps.append(f"{device} {(b - a) / 1000:.1f} s at +{a / 1000 - events[0]['t']:.0f} s")
    final: dict[str, float] = next((r["metrics"] for r in reversed(soak.stats) if r.get("metrics")), {})
    lat = got.latency_ms
    opcua = soak.opcua
    serve_log = (soak.work / "serve.log").read_text(encoding="utf-8", errors="replace")
    return {
        "timeline": {"slots": args.slots, "slot_s": args.slot, "down_s": args.down, "plan": soak.timeline.describe()},
        "devices": args.lines * args.per_line,
        "samples_in_history": sum(len(v) for v in history.values()),
        "samples_received": sum(len(v) for v in received.values()),
        "received_live": sum(len(v) for v in got.live.values()),
        "received_historical": sum(len(v) for v in got.historical.values()),
        "duplicates": duplicates,
        "seq_gaps": got.seq_gaps,
        "history_out_of_order": got.bad_history_order,
        "not_published": dict(not_published),
        "not_recorded": dict(not_recorded),
        "not_sampled": dict(not_sampled),
        "other_gaps": other_gaps[:20],
        "history_gap_events": gap_events,
        "messages": dict(got.kinds),
        "latency_ms": {
            "count": len(lat),
            "p50": round(_percentile(lat, 0.50), 2),
            "p95": round(_percentile(lat, 0.95), 2),
            "p99": round(_percentile(lat, 0.99), 2),
            "max": round(max(lat), 1) if lat else None,
            "mean": round(statistics.fmean(lat), 2) if lat else None,
        },
        "memory": _memory(soak.stats),
        "final_metrics": {k: v for k, v in final.items() if not k.startswith("process_")},
        "opcua": {"sessions": opcua.sessions, "notifications": opcua.notifications, "failures": opcua.failures[:8]}
        if opcua
        else None,
        "serve_exit": next((e.get("exit_code") for e in events if e["kind"] == "serve stopped"), None),
        "serve_log_tracebacks": serve_log.count("Traceback"),
        "serve_log_errors": [ln for ln in serve_log.splitlines() if " ERROR " in ln or "error:" in ln][:30],
        "load": [round(r["load"], 1) for r in soak.stats[:: max(1, len(soak.stats) // 12)]],
        "t0": events[0]["t"],
        "events": [{**e, "t": round(e["t"] - events[0]["t"], 1)} for e in events],
    }


def print_report(r: dict[str, Any]) -> None:
    print("\n== soak:", r["timeline"]["plan"])
    print(f"devices {r['devices']}; samples in the history {r['samples_in_history']}, received by the host "
          f"{r['samples_received']} (live {r['received_live']}, historical {r['received_historical']})")  # fmt: skip
    print(f"duplicates {r['duplicates']}; seq gaps {r['seq_gaps']}; history out of order {r['history_out_of_order']}")
    for key in ("not_published", "not_recorded", "not_sampled"):
        print(f"{key}: {r[key] or 0}")
    if r["other_gaps"]:
        print("  other gaps:", "; ".join(r["other_gaps"]))
    print("history gap events:", *r["history_gap_events"], sep="\n  ")
    print("latency ms:", r["latency_ms"])
    for m in r["memory"]:
        print(f"serve pid {m['pid']}: {m['slots']} slots, RSS MiB first/last/min/max {m['rss_mib']}, heap blocks "
              f"{m['heap_blocks']}, gc objects {m['gc_objects']}, CPU {m['cpu_core']} core")  # fmt: skip
    print("opcua:", r["opcua"])
    print("messages:", r["messages"])
    print("final metrics:", r["final_metrics"])
    print(f"serve exit {r['serve_exit']}; tracebacks in its log {r['serve_log_tracebacks']}; load {r['load']}")
    for line in r["serve_log_errors"]:
        print("  log:", line)
