"""serve over TLS with a password file: guarded DCMDs (refused out of range with nothing sent, a start executed
and read back, a stale command refused), Rebirth on NCMD, DDEATH and DBIRTH as a device leaves and returns,
and the Prometheus endpoint read with prometheus-client's own parser."""

from __future__ import annotations

import shutil
import subprocess
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from prometheus_client.parser import text_string_to_metric_families

from starterbus.serve.embedded import free_port

if TYPE_CHECKING:  # conftest is not importable at run time (pytest's importlib mode)
    from starterbus.tests.serve.conftest import Host, Line, Message, Serve, TlsBroker

BOOLEAN, INT32 = 11, 3
LAST = "Device Control/Last Command"


def is_(kind: str, device: str | None = None) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind and (device is None or m.device == device)


def last_command(host: Host, device: str, text: str) -> Callable[[Message], bool]:
    return lambda m: is_("DDATA", device)(m) and text in str(host.values(m).get(LAST, ""))


def writes(frames: list[bytes]) -> list[bytes]:
    return [f for f in frames if len(f) > 1 and f[1] in (0x06, 0x10)]  # Modbus write functions


def test_guarded_commands_rebirth_ddeath_and_prometheus_over_tls(
    tls_broker: TlsBroker,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    b = tls_broker
    host = host_factory(b.broker.port, ca=str(b.ca), username=b.username, password=b.password)
    metrics_port = free_port()
    node = serve(
        str(fleet_toml),
        "--mqtt", f"mqtts://127.0.0.1:{b.broker.port}", "--ca-file", str(b.ca),
        "--group", "g1", "--node", "n1", "--state-file", str(tmp_path / "state.json"),
        "--metrics", f"127.0.0.1:{metrics_port}",
        env={"STARTERBUS_MQTT_USERNAME": b.username, "STARTERBUS_MQTT_PASSWORD": b.password},
    )  # fmt: skip
    i, nbirth = host.wait(is_("NBIRTH"))
    for device in ("pump", "fan"):
        host.wait(is_("DBIRTH", device), after=i)
    assert b.password not in node.output()  # never logged

    # out of range: refused by validation, reported, and no write frame reached the line
    frames_before = len(line.frames)
    host.send("DCMD", "pump", [("Parameters/ramp_time", INT32, "int_value", 500)])
    _, refused = host.wait(last_command(host, "pump", "refused"))
    assert "out of range" in str(host.values(refused)[LAST])
    assert writes(line.frames[frames_before:]) == [] and line.starters[2].params["ramp_time"] == 10

    # a command older than --command-max-age (10 s) is refused, never executed late
    host.send(
        "DCMD", "pump", [("Device Control/Start", BOOLEAN, "boolean_value", True)], ts=int(time.time() * 1000) - 60_000
    )
    host.wait(last_command(host, "pump", "s old (limit 10 s)"))
    assert line.starters[2].phase.value != "starting"

    # allowed start: through the guarded path, read back, reported; the state change arrives as DDATA
    host.send("DCMD", "pump", [("Device Control/Start", BOOLEAN, "boolean_value", True)])
    _, done = host.wait(last_command(host, "pump", "start: ok"))
    assert line.starters[2].phase.value in ("starting", "running")
    host.wait(lambda m: is_("DDATA", "pump")(m) and host.values(m).get("Status/State") in ("starting", "running"))
    assert "reached starting" in str(host.values(done)[LAST]) or "reached running" in str(host.values(done)[LAST])

    # Rebirth: NBIRTH (seq 0, same bdSeq) then every DBIRTH, in the same session
    k = len(host.messages)
    host.send("NCMD", None, [("Node Control/Rebirth", BOOLEAN, "boolean_value", True)])
    k, reborn = host.wait(is_("NBIRTH"), after=k)
    assert reborn.payload.seq == 0 and not any(m.kind == "NDEATH" for m in host.messages[i:])
    bd = {x.name: x.long_value for x in nbirth.payload.metrics}["bdSeq"]
    assert {x.name: x.long_value for x in reborn.payload.metrics}["bdSeq"] == bd
    for device in ("pump", "fan"):
        host.wait(is_("DBIRTH", device), after=k)

    # the fan stops answering: DDEATH; it answers again: DBIRTH
    fan = line.sim.starters.pop(3)
    k, _ = host.wait(is_("DDEATH", "fan"), after=k)
    line.sim.starters[3] = fan
    host.wait(is_("DBIRTH", "fan"), after=k)

    # Prometheus, parsed by prometheus-client
    text = urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=5).read().decode()
    families = {f.name: f for f in text_string_to_metric_families(text)}
    online = {s.labels["device"]: s.value for s in families["starterbus_device_online"].samples}
    assert set(online) == {"pump", "fan"}
    states = {
        s.labels["state"]: s.value for s in families["starterbus_device_state"].samples if s.labels["device"] == "pump"
    }
    assert states["starting"] + states["running"] == 1.0
    currents = families["starterbus_device_value_amperes"].samples
    assert any(s.labels == {"device": "pump", "key": "phase_a_current"} for s in currents)
    assert families["starterbus_line_transactions"].samples[0].value > 0
    if "starterbus_line_requests" in families:  # a poller that counts its wire (FleetPoller.line_stats)
        assert (
            families["starterbus_line_requests"].samples[0].value
            >= families["starterbus_line_transactions"].samples[0].value
        )
        assert 0 < families["starterbus_line_utilisation_ratio"].samples[0].value <= 1
    assert families["starterbus_serve_commands_refused"].samples[0].value == 2
    promtool = shutil.which("promtool")  # Prometheus's own check, where installed (tests/serve/test_promtool.py)
    if promtool is not None:
        checked = subprocess.run(
            [promtool, "check", "metrics"], check=False, input=text, capture_output=True, text=True
        )
        assert (checked.returncode, checked.stdout + checked.stderr) == (0, "")
