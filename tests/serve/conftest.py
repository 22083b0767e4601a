"""Real parts for serve: mosquitto on a free loopback port, a paho-mqtt host application decoding with Tahu's
schema (the tahutils package ships Eclipse Tahu's generated sparkplug_b_pb2), serve as a subprocess, and
Modbus RTU simulators on pseudo-terminals."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion
from tahutils.tahu import sparkplug_b_pb2 as tahu  # the official schema, not starterbus's

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.serve.embedded import Mosquitto, free_port, mosquitto_binary, start_mosquitto
from starterbus.tests.serve.certificates import write_certificates
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

TahuPayload = Any
WAIT = 15.0


@pytest.fixture
def broker() -> Iterator[Mosquitto]:
    if mosquitto_binary() is None:
        pytest.skip("mosquitto is not installed (apt-get install mosquitto)")
    b = start_mosquitto()
    try:
        yield b
    finally:
        b.close()


@dataclass
class Message:
    topic: str
    payload: TahuPayload  # None for STATE (JSON, not protobuf)
    raw: bytes

    @property
    def kind(self) -> str:
        return self.topic.split("/")[2]

    @property
    def device(self) -> str | None:
        parts = self.topic.split("/")
        return parts[4] if len(parts) > 4 else None


@dataclass
class Host:
    """A Sparkplug host application: paho-mqtt, every spBv1.0 message decoded with Tahu's schema."""

    client: mqtt.Client
    group: str = "g1"
    node: str = "n1"
    messages: list[Message] = field(default_factory=list)
    cond: threading.Condition = field(default_factory=threading.Condition)
    aliases: dict[str, dict[int, str]] = field(default_factory=dict)  # device -> alias -> name

    def on_message(self, _c: mqtt.Client, _u: object, msg: mqtt.MQTTMessage) -> None:
        payload: TahuPayload = None
        if "/STATE/" not in msg.topic:
            payload = tahu.Payload()
            payload.ParseFromString(msg.payload)
        m = Message(msg.topic, payload, bytes(msg.payload))
        with self.cond:
            if m.kind in ("NBIRTH", "DBIRTH") and payload is not None:
                self.aliases[m.device or ""] = {x.alias: x.name for x in payload.metrics if x.HasField("alias")}
            self.messages.append(m)
            self.cond.notify_all()

    def wait(self, pred: Callable[[Message], bool], after: int = 0, timeout: float = WAIT) -> tuple[int, Message]:
        """The first message from index ``after`` on that matches; fails after ``timeout`` (an observable)."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for i in range(after, len(self.messages)):
                    if pred(self.messages[i]):
                        return i, self.messages[i]
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = [(m.kind, m.device) for m in self.messages[after:]][-20:]
                    raise AssertionError(f"no matching message within {timeout} s; last seen {seen}")
                self.cond.wait(left)

    def values(self, m: Message) -> dict[str, object]:
        """Metric name -> value of a BIRTH or DATA (aliases resolved through the last BIRTH)."""
        names = self.aliases.get(m.device or "", {})
        out: dict[str, object] = {}
        assert m.payload is not None
        for x in m.payload.metrics:
            name = x.name or names.get(x.alias, f"alias {x.alias}")
            which = x.WhichOneof("value")
            out[name] = None if x.is_null else getattr(x, which) if which else None
        return out

    def send(
        self, kind: str, device: str | None, metrics: Sequence[tuple[str, int, str, object]], ts: int | None = None
    ) -> None:
        """An NCMD/DCMD by metric name: (name, datatype, value field, value)."""
        payload = tahu.Payload()
        payload.timestamp = ts if ts is not None else int(time.time() * 1000)
        for name, datatype, fld, value in metrics:
            metric = payload.metrics.add(name=name, datatype=datatype, timestamp=payload.timestamp)
            setattr(metric, fld, value)
        topic = f"spBv1.0/{self.group}/{kind}/{self.node}" + (f"/{device}" if device else "")
        self.client.publish(topic, payload.SerializeToString(), qos=0).wait_for_publish(5)


@pytest.fixture
def host_factory() -> Iterator[Callable[..., Host]]:
    hosts: list[Host] = []

    def make(port: int, *, ca: str | None = None, username: str | None = None, password: str | None = None) -> Host:
        client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"host-{uuid.uuid4().hex[:8]}")
        host = Host(client)
        subscribed = threading.Event()
        client.on_message = host.on_message
        client.on_connect = lambda c, *_: c.subscribe("spBv1.0/#", qos=1)
        client.on_subscribe = lambda *_: subscribed.set()
        if username:
            client.username_pw_set(username, password)
        if ca:
            client.tls_set(ca_certs=ca)
        client.connect("127.0.0.1", port, 30)
        client.loop_start()
        assert subscribed.wait(WAIT), "host application could not subscribe"
        hosts.append(host)
        return host

    yield make
    for host in hosts:
        host.client.disconnect()
        host.client.loop_stop()


@dataclass
class Line:
    sim: ModbusRtuSimulator
    starters: dict[int, SimulatedStarter]
    frames: list[bytes]
    port: str


@pytest.fixture
def line() -> Iterator[Line]:
    """One Modbus RTU line with two JJR5000 (units 2 and 3) on a pseudo-terminal; every received frame kept."""
    profile = get_profile("jjr5000")
    starters = {2: SimulatedStarter(profile), 3: SimulatedStarter(profile)}
    frames: list[bytes] = []
    sim = ModbusRtuSimulator(starters, pty=True, trace=lambda kind, data: frames.append(data) if kind == "rx" else None)
    sim.start()
    try:
        port = sim.client_urls()[2].split("://", 1)[1].split("?", 1)[0]
        yield Line(sim, starters, frames, port)
    finally:
        sim.close()


@pytest.fixture
def fleet_toml(tmp_path: Path, line: Line) -> Path:
    """A fleet file for the line: pump (unit 2) may be started, stopped and have ramp_time written; fan nothing."""
    port = line.port
    path = tmp_path / "fleet.toml"
    path.write_text(
        f"""
[poll]
period = 0.1
max_backoff = 0.3

[[bus]]
name = "line-1"
url = "modbus-rtu://{port}?timeout=0.15"

  [[bus.device]]
  name = "pump"
  model = "jjr5000"
  address = 2
  measurements = ["phase_a_current"]
  parameters = ["ramp_time"]
  remote = {{ commands = ["start", "stop"], write = ["ramp_time"] }}

  [[bus.device]]
  name = "fan"
  model = "jjr5000"
  address = 3
  measurements = ["phase_a_current"]
""",
        encoding="utf-8",
    )
    return path


@dataclass
class Serve:
    process: subprocess.Popen[bytes]
    log: Path

    def output(self) -> str:
        return self.log.read_text(encoding="utf-8", errors="replace")

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(10)


@pytest.fixture
def serve(tmp_path: Path, _audit_log_in_tmp: Path) -> Iterator[Callable[..., Serve]]:
    running: list[Serve] = []

    def start(*args: str, env: dict[str, str] | None = None) -> Serve:
        log = tmp_path / f"serve-{len(running)}.log"
        environ = dict(os.environ, **(env or {}))
        with log.open("wb") as out:
            process = subprocess.Popen(
                [sys.executable, "-m", "starterbus.cli.main", "serve", *args, "-v"],
                stdout=out,
                stderr=subprocess.STDOUT,
                env=environ,
            )
        s = Serve(process, log)
        running.append(s)
        return s

    yield start
    for s in running:
        if s.process.poll() is None:
            s.process.terminate()
            try:
                s.process.wait(10)
            except subprocess.TimeoutExpired:
                s.kill()


@dataclass
class TlsBroker:
    broker: Mosquitto
    ca: Path
    username: str
    password: str


@pytest.fixture
def tls_broker() -> Iterator[TlsBroker]:
    """mosquitto with only a TLS listener and a password file (mosquitto_passwd); no anonymous clients.

    The files live in a directory of their own under /tmp: mosquitto started as root reads them as the
    mosquitto user, which cannot enter pytest's private tmp_path."""
    binary = mosquitto_binary()
    passwd_tool = shutil.which("mosquitto_passwd")
    if binary is None or passwd_tool is None:
        pytest.skip("mosquitto is not installed (apt-get install mosquitto)")
    files = Path(tempfile.mkdtemp(prefix="starterbus-tls-"))
    files.chmod(0o755)
    ca, cert, key = write_certificates(files)
    passwd = files / "passwd"
    subprocess.run([passwd_tool, "-c", "-b", str(passwd), "edge", "s3cret pass"], check=True, capture_output=True)
    passwd.chmod(0o644)
    port = free_port()
    extra = (
        f"listener {port} 127.0.0.1\ncafile {ca}\ncertfile {cert}\nkeyfile {key}\n"
        f"allow_anonymous false\npassword_file {passwd}\n"
    )
    try:
        b = start_mosquitto(port, extra, listener=False)
        try:
            yield TlsBroker(b, ca, "edge", "s3cret pass")
        finally:
            b.close()
    finally:
        shutil.rmtree(files, ignore_errors=True)


class Proxy:
    """A TCP forwarder between serve and the broker: ``cut()`` makes the broker unreachable for serve alone
    (open connections dropped, new ones refused) while the host application stays connected; ``resume()``."""

    def __init__(self, target_port: int) -> None:
        self.target = target_port
        self.port = free_port()
        self._server: socket.socket | None = None
        self._conns: list[socket.socket] = []
        self._lock = threading.Lock()
        self.resume()

    def resume(self) -> None:
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
                upstream = socket.create_connection(("127.0.0.1", self.target))
            except OSError:  # the broker is away: the client sees its connection closed, as a dead broker does
                client.close()
                continue
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

    def cut(self) -> None:
        if self._server is not None:
            try:
                self._server.shutdown(socket.SHUT_RDWR)  # wakes the thread blocked in accept()
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


@pytest.fixture
def proxy(broker: Mosquitto) -> Iterator[Proxy]:
    p = Proxy(broker.port)
    try:
        yield p
    finally:
        p.cut()
