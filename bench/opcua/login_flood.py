"""Bench: a wrong-password flood on ``serve --demo --opcua`` and what a good OPC UA session and Sparkplug feel of it.

Run: ``python bench/opcua/login_flood.py [--seconds 30] [--flooders 4] [--max-attempts 500]``

Everything on loopback. ``starterbus serve --demo --opcua`` runs as its own process (a local mosquitto, a users
file with the default 600,000 PBKDF2 iterations, this bench's client certificate trusted). Two phases of
``--seconds`` each, side by side:

* quiet: one good session (a read-only user, Basic256Sha256 SignAndEncrypt) reads a status variable every 20 ms;
  a paho subscriber takes each DDATA's latency (receive time minus the metric's timestamp, the poll's time);
* flood: the same, while ``--flooders`` asyncua clients (one process each) connect with a wrong password for an
  existing operator in a loop, each bounded by ``--max-attempts`` and the phase's time.

Goals (issue 27): under the flood, reads p50 < 10 ms and publishing p50 < 20 ms. The server's login counters
(``starterbus_opcua_logins_total`` from its ``--metrics``) are printed at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import multiprocessing
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from paho.mqtt.enums import CallbackAPIVersion

from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.users import Role, UserEntry, dump_users, hash_password
from starterbus.serve.embedded import free_port, start_mosquitto
from starterbus.serve.schema import Payload

CLIENT_URI = "urn:starterbus:bench-client"
SERVE = "import sys; from starterbus.cli.main import main; sys.exit(main(sys.argv[1:]))"


class Subscriber:
    """DDATA latencies (ms) of the Sparkplug node, tagged with the phase running when each arrived."""

    def __init__(self, port: int) -> None:
        self.phase = ""
        self.latency: dict[str, list[float]] = {}
        ready = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-flood-sub")
        self.client.on_message = self._on_message
        self.client.on_connect = lambda c, *a: c.subscribe("spBv1.0/bench/DDATA/#")
        self.client.on_subscribe = lambda *a: ready.set()
        self.client.connect("127.0.0.1", port, 30)
        self.client.loop_start()
        if not ready.wait(10):
            raise RuntimeError("the subscriber did not subscribe")

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        now = time.time() * 1000
        payload = Payload()
        payload.ParseFromString(msg.payload)
        if self.phase and payload.metrics:
            self.latency.setdefault(self.phase, []).append(now - payload.metrics[0].timestamp)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def _client(url: str, cert: Path, key: Path, user: str, password: str) -> Client:
    client = Client(url, timeout=10)
    client.application_uri = CLIENT_URI
    client.set_user(user)
    client.set_password(password)
    return client


def flood(url: str, cert: str, key: str, seconds: float, max_attempts: int, done: Any) -> None:
    """One flooding client (a process of its own): wrong passwords for an existing operator, in a loop."""

    logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # every refusal would print a ServiceFault

    async def run() -> int:
        end = time.monotonic() + seconds
        attempts = 0
        while time.monotonic() < end and attempts < max_attempts:
            client = _client(url, Path(cert), Path(key), "operator", "not-the-password")
            await client.set_security(SecurityPolicyBasic256Sha256, cert, key, mode=ua.MessageSecurityMode.Sign)
            try:
                async with client:
                    pass
            except Exception:
                pass
            attempts += 1
        return attempts

    done.put(asyncio.run(run()))


async def reads(url: str, cert: Path, key: Path, seconds: float) -> list[float]:
    client = _client(url, cert, key, "viewer", "viewer-password")
    await client.set_security(
        SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.SignAndEncrypt
    )
    latencies = []
    async with client:
        idx = await client.get_namespace_index("urn:starterbus:fleet")
        node = client.get_node(ua.NodeId("conveyor.Status.State", idx))
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            start = time.perf_counter()
            await node.read_data_value(raise_on_bad_status=False)
            latencies.append((time.perf_counter() - start) * 1000)
            await asyncio.sleep(0.02)
    return latencies


def summary(values: list[float]) -> str:
    if not values:
        return "no samples"
    return f"p50 {statistics.median(values):7.2f} ms  max {max(values):7.1f} ms  (n={len(values)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0] if __doc__ else None)
    ap.add_argument("--seconds", type=float, default=30.0, help="length of each phase")
    ap.add_argument("--flooders", type=int, default=4)
    ap.add_argument("--max-attempts", type=int, default=500, help="per flooding client")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="starterbus-flood-"))
    users = {
        "operator": UserEntry("operator", Role.OPERATOR, hash_password("operator-password")),
        "viewer": UserEntry("viewer", Role.READ_ONLY, hash_password("viewer-password")),
    }
    (tmp / "users.toml").write_text(dump_users(users), encoding="utf-8")
    cert, key = ensure_certificate(tmp / "client", CLIENT_URI)
    (tmp / "pki" / "trusted").mkdir(parents=True)
    shutil.copy(cert, tmp / "pki" / "trusted" / "bench-client.der")
    broker = start_mosquitto()
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/bench"
    serve = subprocess.Popen(
        [
            sys.executable, "-c", SERVE, "serve", "--demo", "--mqtt", f"mqtt://127.0.0.1:{broker.port}",
            "--group", "bench", "--node", "n1", "--state-file", str(tmp / "state.json"),
            "--opcua", endpoint, "--opcua-users", str(tmp / "users.toml"), "--opcua-pki", str(tmp / "pki"),
            "--metrics", "127.0.0.1:0", "--json",
        ],
        stdout=subprocess.PIPE,
        stderr=(tmp / "serve.log").open("w"),  # one log line per refused login
        text=True,
    )  # fmt: skip
    assert serve.stdout is not None
    subscriber = None
    try:
        line = serve.stdout.readline()
        if not line:
            raise SystemExit("serve did not start:\n" + (tmp / "serve.log").read_text()[-3000:])
        ready = json.loads(line)
        url, metrics = ready["opcua"], ready["metrics"]
        subscriber = Subscriber(broker.port)
        results: dict[str, list[float]] = {}
        subscriber.phase = "quiet"
        results["quiet"] = asyncio.run(reads(url, cert, key, args.seconds))
        subscriber.phase = "flood"
        done: Any = multiprocessing.Queue()
        bounds = (args.seconds, args.max_attempts)
        flooders = [
            multiprocessing.Process(target=flood, args=(url, str(cert), str(key), *bounds, done))
            for _ in range(args.flooders)
        ]
        for p in flooders:
            p.start()
        results["flood"] = asyncio.run(reads(url, cert, key, args.seconds))
        attempts = sum(done.get(timeout=60) for _ in flooders)
        for p in flooders:
            p.join(10)
        subscriber.phase = ""
        scrape = urllib.request.urlopen(metrics, timeout=10).read().decode()
    finally:
        if subscriber is not None:
            subscriber.close()
        serve.terminate()
        serve.wait(30)
        broker.close()
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"serve --demo --opcua, {args.seconds:g} s per phase, {args.flooders} flooding clients ({attempts} attempts)")
    for phase in ("quiet", "flood"):
        print(f"  {phase:5}  OPC UA read   {summary(results[phase])}")
        print(f"  {phase:5}  Sparkplug     {summary(subscriber.latency.get(phase, []))}")
    print("  goals under the flood: read p50 < 10 ms, publishing p50 < 20 ms")
    for line in scrape.splitlines():
        if line.startswith(("starterbus_opcua_logins_total", "starterbus_opcua_login_lockouts_total")):
            print("  " + line)


if __name__ == "__main__":
    main()
