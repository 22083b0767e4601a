"""The real parts of ``bench/serve/unattended_soak.py``: a small tmpfs, simulator lines in their own processes
behind stable paths, a TCP gate in front of mosquitto, a Sparkplug host (paho + Eclipse Tahu's schema) that
keeps every sample timestamp it receives, an OPC UA client, and ``serve`` in a thin wrapper that reports its
Python heap.

Everything here cleans up after itself in ``close()``; the soak calls them all in a ``finally``.
"""

from __future__ import annotations

import asyncio
import errno
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
import uuid
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from tahutils.tahu import sparkplug_b_pb2 as tahu  # the official schema, not starterbus's

#: ``serve`` as a real process, plus one thread writing its Python heap (obmalloc blocks, gc objects) to a file
SERVE_WRAPPER = """
import gc, json, sys, threading, time
out, every = sys.argv[1], float(sys.argv[2])
def report():
    while True:
        line = {"t": time.time(), "blocks": sys.getallocatedblocks(), "objects": len(gc.get_objects())}
        with open(out, "a") as f:
            f.write(json.dumps(line) + "\\n")
        time.sleep(every)
threading.Thread(target=report, daemon=True).start()
from starterbus.cli.main import main
sys.exit(main(["serve", *sys.argv[3:]]))
"""


def rss_kib(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text(encoding="ascii").splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def cpu_seconds(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text(encoding="ascii").rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def scrape(port: int) -> dict[str, float]:
    """serve's metrics without labels, plus the labelled ones as NAME{labels} (failures, history tables)."""
    from prometheus_client.parser import text_string_to_metric_families

    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    out: dict[str, float] = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if not s.name.startswith(("starterbus_serve", "starterbus_history", "starterbus_worker", "process_")):
                continue
            key = s.name + ("{" + ",".join(f"{k}={v}" for k, v in sorted(s.labels.items())) + "}" if s.labels else "")
            out[key] = s.value
    return out


class Tmpfs:
    """A tmpfs of ``size_mb`` mounted on ``path`` (root only); ``fill()`` takes every free byte, ``free()`` gives
    it back."""

    def __init__(self, path: Path, size_mb: int) -> None:
        self.path = path
        path.mkdir(parents=True, exist_ok=True)
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(path)], check=True)
        self.mounted = True
        self.filler = path / "filler"

    def fill(self) -> int:
        written = 0
        fd = os.open(self.filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        try:
            for chunk in (1 << 20, 4096, 1):
                block = b"\0" * chunk
                while True:
                    try:
                        written += os.write(fd, block)
                    except OSError as exc:
                        if exc.errno != errno.ENOSPC:
                            raise
                        break
        finally:
            os.close(fd)
        return written

    def free(self) -> None:
        self.filler.unlink(missing_ok=True)

    def close(self) -> None:
        if self.mounted:
            self.free()
            if subprocess.run(["umount", str(self.path)], check=False).returncode != 0:
                subprocess.run(["umount", "-l", str(self.path)], check=False)
            self.mounted = False


@dataclass
class SimLine:
    """``starterbus simulate`` on a new pty, in its own process, reached through the symlink ``link`` (a serial
    adapter's stable name): ``stop()`` kills it and removes the link (the adapter unplugged), ``start()`` again."""

    name: str
    link: Path
    units: list[tuple[int, str]]
    script: Path
    process: subprocess.Popen[str] | None = None

    def start(self) -> None:
        args = [sys.executable, "-m", "starterbus.cli.main", "simulate", "--modbus-rtu", "PTY", "--json"]
        for unit, model in self.units:
            args += ["--unit", f"{unit}:{model}"]
        self.process = subprocess.Popen([*args, "--script", str(self.script)], stdout=subprocess.PIPE, text=True)
        assert self.process.stdout is not None
        where = json.loads(self.process.stdout.readline())
        pts = where["front_ends"][0]["listen"][0].split(": ", 1)[1]
        tmp = self.link.with_name(self.link.name + ".new")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(pts)
        os.replace(tmp, self.link)

    def stop(self) -> None:
        self.link.unlink(missing_ok=True)
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)
        self.process = None


class Gate:
    """A TCP forwarder between serve and mosquitto: while mosquitto restarts, ``close()`` drops serve's connection
    and refuses new ones; ``open()`` once the host application is subscribed again (so it sees the births)."""

    def __init__(self, target_port: int, port: int) -> None:
        self.target, self.port = target_port, port
        self._server: socket.socket | None = None
        self._conns: list[socket.socket] = []
        self._lock = threading.Lock()

    def open(self) -> None:
        server = socket.socket()
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", self.port))
        server.listen()
        self._server = server
        threading.Thread(target=self._accept, args=(server,), daemon=True).start()

    def _accept(self, server: socket.socket) -> None:
        while True:
            try:
                client, _ = server.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(("127.0.0.1", self.target), timeout=2)
            except OSError:
                client.close()
                continue
            for s in (client, upstream):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                s.settimeout(None)
            with self._lock:
                self._conns += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def close(self) -> None:
        if self._server is not None:
            try:
                self._server.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._server.close()
            self._server = None
        with self._lock:
            conns, self._conns = self._conns, []
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()


@dataclass
class Received:
    """What the host application got, per device: sample timestamps (ms) and how they came."""

    live: dict[str, list[int]] = field(default_factory=lambda: defaultdict(list))
    historical: dict[str, list[int]] = field(default_factory=lambda: defaultdict(list))
    births: dict[str, list[int]] = field(default_factory=lambda: defaultdict(list))
    latency_ms: list[float] = field(default_factory=list)  # live DDATA: arrival - acquisition time
    kinds: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    trace: list[tuple[float, str, str, int, int, bool]] = field(default_factory=list)  # arrival kind device seq ts hist
    seq_gaps: int = 0  # messages missing by Sparkplug seq within a session
    bad_history_order: int = 0  # a historical DDATA older than the previous one of its device in that session


class Host:
    """A Sparkplug host application on paho-mqtt, decoding with Tahu's schema; reconnects by itself."""

    def __init__(self, port: int, group: str, node: str) -> None:
        self.got = Received()
        self.prefix = f"spBv1.0/{group}/"
        self.node = node
        self.subscribed = threading.Event()
        self._lock = threading.Lock()
        self._seq: int | None = None
        self._last_hist: dict[str, int] = {}
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"soak-host-{uuid.uuid4().hex[:8]}")
        self.client.on_connect = lambda c, *_: c.subscribe(self.prefix + "#", qos=0)
        self.client.on_subscribe = lambda *_: self.subscribed.set()
        self.client.on_disconnect = lambda *_: self.subscribed.clear()
        self.client.on_message = self._on_message
        self.client.reconnect_delay_set(0.05, 0.2)  # type: ignore[arg-type]  # paho takes seconds as floats
        self.client.connect("127.0.0.1", port, 10)
        self.client.loop_start()

    def _on_message(self, _c: mqtt.Client, _u: object, msg: mqtt.MQTTMessage) -> None:
        arrival = time.time() * 1000
        parts = msg.topic.split("/")
        kind, device = parts[2], (parts[4] if len(parts) > 4 else "")
        payload = tahu.Payload()
        payload.ParseFromString(msg.payload)
        got = self.got
        with self._lock:
            got.kinds[kind] += 1
            if kind == "NDEATH":
                return
            if kind == "NBIRTH":
                self._seq, self._last_hist = payload.seq, {}
            elif self._seq is not None:
                expected = (self._seq + 1) % 256
                got.seq_gaps += (payload.seq - expected) % 256
                self._seq = payload.seq
            stamps = [m.timestamp for m in payload.metrics if m.timestamp]
            ts = Counter(stamps).most_common(1)[0][0] if stamps else 0  # acquisition (metrics not polled: now)
            hist = any(m.is_historical for m in payload.metrics)
            got.trace.append((arrival, kind, device, payload.seq, ts, hist))
            if not device or not stamps:
                return
            if kind == "DBIRTH":
                got.births[device].append(ts)
            elif kind == "DDATA":
                if any(m.is_historical for m in payload.metrics):
                    if ts < self._last_hist.get(device, 0):
                        got.bad_history_order += 1
                    self._last_hist[device] = ts
                    got.historical[device].append(ts)
                else:
                    got.live[device].append(ts)
                    got.latency_ms.append(arrival - ts)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


class OpcUaWatcher:
    """An asyncua client in a thread of its own: subscribes to a few values, reconnects when the server goes."""

    def __init__(self, url: str, nodes: list[str]) -> None:
        self.url, self.nodes = url, nodes
        self.notifications = 0
        self.sessions = 0
        self.failures: list[str] = []
        self._stop = threading.Event()
        self.thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self.thread.start()

    def datachange_notification(self, _node: Any, _value: Any, _data: Any) -> None:
        self.notifications += 1

    async def _run(self) -> None:
        from asyncua import Client

        while not self._stop.is_set():
            try:
                async with Client(self.url, timeout=4) as client:
                    ns = await client.get_namespace_index("urn:starterbus:fleet")
                    sub = await client.create_subscription(500, self)
                    await sub.subscribe_data_change([client.get_node(f"ns={ns};s={n}") for n in self.nodes])
                    self.sessions += 1
                    state = client.get_node(f"ns={ns};s={self.nodes[0]}")
                    while not self._stop.is_set():
                        await asyncio.sleep(1.0)
                        await state.read_data_value()  # raises once the server is gone
            except Exception as exc:  # the server killed or restarting: count and reconnect
                if not self._stop.is_set():
                    self.failures.append(f"{type(exc).__name__}: {exc}"[:120])
                    await asyncio.sleep(0.5)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(15)


class ServeProcess:
    """``serve`` started through :data:`SERVE_WRAPPER`; ``kill9()`` is the hard kill, ``stop()`` SIGTERM."""

    def __init__(self, args: list[str], log: Path, heap: Path, every: float, env: dict[str, str]) -> None:
        self.args, self.log, self.heap, self.every, self.env = args, log, heap, every, env
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with self.log.open("ab") as out:
            self.process = subprocess.Popen(
                [sys.executable, "-c", SERVE_WRAPPER, str(self.heap), str(self.every), *self.args],
                stdout=out, stderr=subprocess.STDOUT, env=self.env,
            )  # fmt: skip

    @property
    def pid(self) -> int:
        assert self.process is not None
        return self.process.pid

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def kill9(self) -> None:
        if self.alive():
            assert self.process is not None
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(10)

    def stop(self, timeout: float = 30.0) -> int | None:
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)
        return self.process.returncode
