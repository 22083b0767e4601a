"""Soak: one compressed hour of ``serve --record --opcua`` on a bad day (issue 26, item 7).

Run (root: it mounts a tmpfs): ``python bench/serve/unattended_soak.py [--slots 60] [--slot 12] [--down 2]
[--lines 5] [--per-line 10] [--tmpfs-mb 48] [--out FILE.json] [--keep]``

The timeline is ``--slots`` slots that stand for one minute each (60: one hour); a slot runs ``--slot`` seconds
of wall clock (12: the hour in 12 minutes). Only the spacing of the events is compressed: the polls (1 s), a
broker restart (``--down`` s without a broker) and the time serve takes to notice run at real speed, so the
compressed hour has five times the outage share of a real one.

* ``--lines`` Modbus RTU lines of ``--per-line`` devices (JJR5000 and SSD1 alternating; a few motors running),
  each ``starterbus simulate`` on a pseudo-terminal in its own process, reached by the fleet file through a
  symlink (a serial adapter's stable name); polled every second.
* ``serve`` (a real process: ``cli.main`` in a wrapper that writes its Python heap every slot) with ``--record``
  on a tmpfs of ``--tmpfs-mb`` MB, ``--opcua`` (anonymous, security None) and ``--metrics``; ``--refresh 0.001``
  so that every poll of a device is one DDATA (live or stored) and can be matched to its history row by its
  acquisition time.
* mosquitto is restarted at the start of every slot: serve's connection is dropped (a TCP gate in front of the
  broker closes), mosquitto stops, ``--down`` s later it starts on the same port, the host application
  subscribes again, then the gate opens for serve (so the host sees every new session from its NBIRTH).
* the history's disk fills (a filler file takes the whole tmpfs) for 4 slots, twice; one simulator line is
  stopped and its symlink removed for 4 slots, then started again; in slot 4/5 of the run the broker stays
  away for two slots and serve is killed (``kill -9``) once it has buffered, then started again while the
  broker is still away.
* a Sparkplug host (paho, Eclipse Tahu's schema) keeps the acquisition time of every sample it receives (DBIRTH,
  live and historical DDATA), Sparkplug seq gaps and live latency; an asyncua client subscribes to 3 devices.

At the end serve is stopped with SIGTERM (exit 0 expected) and every sample the history holds is matched with
what the host received: lost on the way to the host, lost from the history, never sampled (a gap in both),
each by the event it fell in. Everything is started by this script and cleaned up (processes, the tmpfs) on
the way out, also on an error, Ctrl-C, SIGTERM or the overall time limit.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import sqlite3
import tempfile
import time
from pathlib import Path
from typing import Any

from starterbus.bench.serve.soak_parts import (
    Gate,
    Host,
    OpcUaWatcher,
    ServeProcess,
    SimLine,
    Tmpfs,
    cpu_seconds,
    rss_kib,
    scrape,
)
from starterbus.bench.serve.soak_report import analyse, print_report
from starterbus.serve.embedded import Mosquitto, free_port, start_mosquitto

MODELS = ("jjr5000", "ssd1")
GROUP, NODE = "soak", "node1"


class Timeline:
    """Which slot holds which event, for any number of slots (60: the hour)."""

    def __init__(self, slots: int) -> None:
        if slots < 30:
            raise SystemExit("--slots: at least 30 (the events need room)")
        self.slots = slots
        self.disk_full = [(slots // 6, slots // 6 + 4), (7 * slots // 12, 7 * slots // 12 + 4)]
        self.line_lost = (slots // 3, slots // 3 + 4)
        self.kill = 4 * slots // 5  # the broker stays away for this slot and the next; serve is killed in it

    def describe(self) -> str:
        (a, b), (c, d) = self.disk_full
        return (
            f"broker restart every slot; disk full in slots {a}-{b} and {c}-{d}; line lost in slots "
            f"{self.line_lost[0]}-{self.line_lost[1]}; broker away in slots {self.kill}-{self.kill + 1}, "
            f"serve killed (-9) and restarted in slot {self.kill}"
        )


def write_fleet(work: Path, lines: list[SimLine]) -> Path:
    text = ["[poll]", "period = 1.0", "max_backoff = 2.0", ""]
    for line in lines:
        text += ["[[bus]]", f'name = "{line.name}"', f'url = "modbus-rtu://{line.link}?baudrate=9600&timeout=0.2"']
        for unit, model in line.units:
            text += ["  [[bus.device]]", f'  name = "{line.name}-{unit:02d}"', f'  model = "{model}"']
            text += [f"  address = {unit}", '  measurements = ["phase_a_current"]', ""]
    path = work / "fleet.toml"
    path.write_text("\n".join(text), encoding="utf-8")
    return path


def wait_for(pred: Any, what: str, timeout: float, step: float = 0.1) -> None:
    """Until ``pred()`` is true (an observable); a soak that cannot go on says what it waited for."""
    deadline = time.monotonic() + timeout
    while True:
        with contextlib.suppress(Exception):
            if pred():
                return
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(step)


class Soak:
    def __init__(self, args: argparse.Namespace, work: Path) -> None:
        self.args, self.work = args, work
        self.timeline = Timeline(args.slots)
        self.events: list[dict[str, Any]] = []  # what happened when (wall clock), for the analysis
        self.stats: list[dict[str, Any]] = []
        self.tmpfs: Tmpfs | None = None
        self.lines: list[SimLine] = []
        self.broker: Mosquitto | None = None
        self.gate: Gate | None = None
        self.host: Host | None = None
        self.serve: ServeProcess | None = None
        self.opcua: OpcUaWatcher | None = None
        self.metrics_port = free_port()

    @property
    def lost_line(self) -> SimLine:
        return self.lines[min(2, len(self.lines) - 1)]

    def note(self, kind: str, **more: Any) -> None:
        self.events.append({"t": time.time(), "kind": kind, **more})
        print(f"  {time.strftime('%H:%M:%S')} {kind} {json.dumps(more) if more else ''}", flush=True)

    # -- the parts ----------------------------------------------------------------------------------------

    def setup(self) -> None:
        a = self.args
        self.tmpfs = Tmpfs(self.work / "history", a.tmpfs_mb)
        for i in range(a.lines):
            units = [(u, MODELS[(u - 1) % 2]) for u in range(1, a.per_line + 1)]
            script = self.work / f"line-{i + 1}.script"
            script.write_text("".join(f"2 {u} start\n" for u, _ in units if u % 3 == 1), encoding="utf-8")
            self.lines.append(SimLine(f"rtu{i + 1}", self.work / f"line-{i + 1}", units, script))
        for line in self.lines:
            line.start()
        fleet = write_fleet(self.work, self.lines)
        port = free_port()
        self.broker = start_mosquitto(port)
        self.gate = Gate(port, free_port())
        self.gate.open()
        self.host = Host(port, GROUP, NODE)
        wait_for(self.host.subscribed.is_set, "the host's subscription", 15)
        opcua_url = f"opc.tcp://127.0.0.1:{free_port()}"
        serve_args = [
            str(fleet), "--mqtt", f"mqtt://127.0.0.1:{self.gate.port}", "--group", GROUP, "--node", NODE,
            "--state-file", str(self.work / "state.json"), "--buffer-file", str(self.work / "buffer.db"),
            "--record", str(self.work / "history" / "history.db"), "--refresh", "0.001", "--reconnect-delay", "1",
            "--metrics", f"127.0.0.1:{self.metrics_port}", "--opcua", opcua_url, "--opcua-anonymous",
            "--opcua-allow-insecure", "--opcua-pki", str(self.work / "pki"), "-v",
        ]  # fmt: skip
        env = dict(os.environ, STARTERBUS_AUDIT_LOG=str(self.work / "audit.jsonl"))
        self.serve = ServeProcess(serve_args, self.work / "serve.log", self.work / "heap.jsonl", a.slot, env)
        self.serve.start()
        self.note("serve started", pid=self.serve.pid)
        devices = a.lines * a.per_line
        host = self.host
        wait_for(lambda: len(host.got.births) == devices, f"DBIRTHs of all {devices} devices", 90)
        first = [f"{line.name}-01" for line in self.lines[:3]]
        nodes = [f"{d}.{k}" for d in first for k in ("Status.State", "Measurements.phase_a_current")]
        self.opcua = OpcUaWatcher(opcua_url, nodes)

    def close(self) -> None:
        parts = (self.opcua, self.serve, "history", self.host, self.gate, self.broker, *self.lines, self.tmpfs)
        for part in parts:
            try:
                if part == "history":
                    self.save_history()
                elif isinstance(part, ServeProcess):
                    part.stop(10)
                elif isinstance(part, SimLine):
                    part.stop()
                elif part is not None and not isinstance(part, str):
                    part.close()
            except Exception as exc:  # clean up the rest whatever one step did
                print(f"cleanup: {type(exc).__name__}: {exc}", flush=True)

    def save_history(self) -> None:
        """The history (serve stopped) copied off the tmpfs before it is unmounted."""
        db = self.work / "history" / "history.db"
        if db.exists():
            src, dst = sqlite3.connect(db), sqlite3.connect(self.work / "history-final.db")
            try:
                src.backup(dst)
            finally:
                src.close()  # the tmpfs must not stay busy
                dst.close()

    # -- the events ---------------------------------------------------------------------------------------

    def broker_down(self) -> None:
        assert self.gate is not None and self.broker is not None
        self.gate.close()  # serve's connection drops at once, as when the broker dies
        self.broker.close()
        self.note("broker down")

    def broker_up(self) -> None:
        assert self.gate is not None and self.broker is not None and self.host is not None
        self.broker = start_mosquitto(self.broker.port)
        wait_for(self.host.subscribed.is_set, "the host subscribed again", 15, 0.02)
        self.gate.open()
        self.note("broker up")

    def metric(self, name: str) -> float:
        return scrape(self.metrics_port).get(name, float("nan"))

    def kill_during_outage(self) -> None:
        assert self.serve is not None
        stored = self.metric("starterbus_serve_history_stored_total")
        more = 2 * self.args.lines * self.args.per_line  # two seconds of samples
        wait_for(lambda: self.metric("starterbus_serve_history_stored_total") >= stored + more, "buffered DDATA", 30)
        self.serve.kill9()
        self.note("serve killed (-9)")
        self.serve.start()
        self.note("serve restarted", pid=self.serve.pid)
        wait_for(lambda: self.metric("starterbus_serve_buffered") > 0, "the restarted serve's buffer", 60)
        self.note("restarted serve buffering", buffered=self.metric("starterbus_serve_buffered"))

    def sample_stats(self, slot: int, t0: float) -> None:
        assert self.serve is not None
        row: dict[str, Any] = {"slot": slot, "t": round(time.time() - t0, 1), "pid": self.serve.pid}
        row["rss_kib"], row["cpu_s"] = rss_kib(self.serve.pid), cpu_seconds(self.serve.pid)
        with contextlib.suppress(OSError, ValueError, IndexError):
            heap = json.loads((self.work / "heap.jsonl").read_text().splitlines()[-1])
            row["heap_blocks"], row["gc_objects"] = heap["blocks"], heap["objects"]
        with contextlib.suppress(OSError):
            row["metrics"] = scrape(self.metrics_port)
        row["load"] = os.getloadavg()[0]
        self.stats.append(row)
        m = row.get("metrics", {})
        buffered, dropped = m.get("starterbus_serve_buffered", -1), m.get("starterbus_serve_dropped_total", -1)
        print(
            f"slot {slot:2d} t={row['t']:6.0f}s RSS {row['rss_kib'] / 1024:6.1f} MiB "
            f"blocks {row.get('heap_blocks', 0):7d} buffered {buffered:5.0f} dropped {dropped:3.0f} "
            f"history backlog {m.get('starterbus_history_backlog', -1):5.0f} load {row['load']:.1f}",
            flush=True,
        )

    def run(self) -> None:
        a, tl = self.args, self.timeline
        assert self.tmpfs is not None and self.serve is not None
        t0 = time.time()
        print(f"timeline: {a.slots} slots of {a.slot:g} s; {tl.describe()}", flush=True)
        for slot in range(a.slots):
            start = t0 + slot * a.slot
            time.sleep(max(0.0, start - time.time()))
            if slot == tl.kill:
                self.broker_down()
                self.kill_during_outage()
            elif slot == tl.kill + 1:
                pass  # still away
            else:
                self.broker_down()
                time.sleep(a.down)
                self.broker_up()
            time.sleep(max(0.0, start + a.slot / 2 - time.time()))
            for first, last in tl.disk_full:
                if slot == first:
                    self.note("disk full", filler_bytes=self.tmpfs.fill())
                elif slot == last:
                    self.tmpfs.free()
                    self.note("disk freed")
            if slot == tl.line_lost[0]:
                self.lost_line.stop()
                self.note("line lost", line=self.lost_line.name)
            elif slot == tl.line_lost[1]:
                self.lost_line.start()
                self.note("line back", line=self.lost_line.name)
            if slot == tl.kill + 1:
                time.sleep(max(0.0, start + a.slot * 0.9 - time.time()))
                self.broker_up()
            time.sleep(max(0.0, start + a.slot * 0.95 - time.time()))
            self.sample_stats(slot, t0)
        # settle: the buffer and the history's backlog empty, the last live messages in, then a clean stop
        wait_for(lambda: self.metric("starterbus_serve_buffered") == 0, "an empty buffer", 120, 0.5)
        wait_for(lambda: self.metric("starterbus_history_backlog") == 0, "an empty history backlog", 120, 0.5)
        time.sleep(3)
        self.sample_stats(a.slots, t0)
        self.note("serve stopping")
        code = self.serve.stop(60)
        self.note("serve stopped", exit_code=code)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slots", type=int, default=60, help="slots of the timeline, one minute each (60: an hour)")
    ap.add_argument("--slot", type=float, default=12.0, help="wall-clock seconds of a slot")
    ap.add_argument("--down", type=float, default=2.0, help="seconds without a broker at each restart")
    ap.add_argument("--lines", type=int, default=5)
    ap.add_argument("--per-line", type=int, default=10)
    ap.add_argument("--tmpfs-mb", type=int, default=48)
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    ap.add_argument("--keep", action="store_true", help="keep the work directory (logs, history, buffer)")
    args = ap.parse_args()
    if os.geteuid() != 0:
        raise SystemExit("the soak mounts a tmpfs: run it as root")
    limit = int(args.slots * args.slot + 600)  # setup, settle and analysis included; then it stops anyway

    def stop(signum: int, _frame: object) -> None:
        raise SystemExit(f"stopped by signal {signum}")

    for signum in (signal.SIGTERM, signal.SIGALRM, signal.SIGHUP):
        signal.signal(signum, stop)
    signal.alarm(limit)
    work = Path(tempfile.mkdtemp(prefix="starterbus-soak-"))
    soak = Soak(args, work)
    print(f"work directory {work}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs", flush=True)
    try:
        soak.setup()
        soak.run()
    finally:
        soak.close()
        signal.alarm(0)
    result = analyse(soak, args, work / "history-final.db")
    print_report(result)
    if args.out:
        args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    else:
        print(f"kept {work}")


if __name__ == "__main__":
    main()
