"""No worker dies quietly: each thread or task of ``poll``, ``serve`` and ``opcua`` made to fail in turn is either
contained (logged, counted, resumed after a backoff) or stops the whole service with one line and exit 1."""

from __future__ import annotations

import asyncio
import re
import socket
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from starterbus.aio import AsyncFleet
from starterbus.cli.main import main
from starterbus.core.sharing import leases
from starterbus.core.supervision import Backoff, ServiceFailed, Supervisor, describe
from starterbus.fleet.bus_worker import BusWorker
from starterbus.fleet.mux import Multiplexer, Waiter
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.sample import Sample

if TYPE_CHECKING:
    from starterbus.tests.fleet.conftest import Lines, Samples

FAST = Backoff(first=0.01, longest=0.05)


def fails_once(original: Callable[..., Any], when: Callable[..., bool], exc: Exception) -> Callable[..., Any]:
    """``original``, except that its first call for which ``when(*args)`` holds raises ``exc``."""
    raised: list[Exception] = []

    def patched(*args: Any, **kwargs: Any) -> Any:
        if not raised and when(*args):
            raised.append(exc)
            raise exc
        return original(*args, **kwargs)

    return patched


def no_leases_left(lines: Lines) -> bool:
    return not [key for key in leases() if any(sim.client_path in key for sim in lines.sims)]


# -- the supervisor itself ------------------------------------------------------------------------------------


def test_contained_failures_are_counted_and_paced_and_a_fatal_one_is_kept_and_told_once() -> None:
    now = [0.0]
    supervisor = Supervisor(Backoff(first=0.5, longest=2.0, calm=60.0), clock=lambda: now[0])
    assert [supervisor.contain("w", ValueError("x")) for _ in range(4)] == [0.5, 1.0, 2.0, 2.0]
    now[0] = 100.0  # a minute without failing: from the start again
    assert supervisor.contain("w", ValueError("x")) == 0.5
    told: list[ServiceFailed] = []
    supervisor.on_fatal(told.append)
    try:
        raise KeyError("k")
    except KeyError as exc:
        first = supervisor.fail("v", exc)
    supervisor.fail("u", RuntimeError("later"))
    assert told == [first] and supervisor.failure is first and supervisor.stopping.is_set()
    assert supervisor.failures == {"w": 5, "v": 1, "u": 1}
    text = str(first)
    # the path relative to the package where the test file lies inside it (a source checkout), else its name
    assert "\n" not in text and re.match(r"v failed: KeyError: 'k' \(at (tests/fleet/)?test_supervision\.py:", text)
    with pytest.raises(ServiceFailed, match="^v failed"):
        supervisor.check()
    late: list[ServiceFailed] = []
    supervisor.on_fatal(late.append)  # registered after the failure: told at once
    assert late == [first]
    assert describe(ServiceFailed("x", ValueError("y"))) == "x failed: ValueError: y; the service stopped"


# -- the poller's threads ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("multiplex", [True, False])
def test_a_failing_sink_is_contained_for_its_bus_which_resumes(
    lines: Lines, samples: Samples, multiplex: bool, caplog: pytest.LogCaptureFixture
) -> None:
    failures: list[Sample] = []

    def fail_twice_on_line0(sample: Sample) -> None:
        if sample.bus == "line0" and len(failures) < 2:
            failures.append(sample)
            raise ValueError("on_sample failed")

    samples.hooks.append(fail_twice_on_line0)
    supervisor = Supervisor(FAST)
    poller = FleetPoller(lines.fleet(buses=2), samples, multiplex=multiplex, supervisor=supervisor)
    with poller:
        samples.wait_for(lambda ss: sum(s.bus == "line0" for s in ss) >= 6)  # line0 back after two failures
        still_polling = poller.running
    assert still_polling and poller.failure is None
    assert supervisor.failures == {"bus-line0": 2}
    assert any(s.bus == "line1" for s in samples.list), "the other bus went on"
    logged = [r.getMessage() for r in caplog.records if r.name == "starterbus.service"]
    assert len(logged) == 2 and all(m.startswith("bus-line0: ValueError: on_sample failed (at ") for m in logged)
    assert not poller.running and no_leases_left(lines)
    limit = poller.submit("b0u1", lambda d: d.read_value("current_limit").raw).result(0)
    assert limit == lines.starter("b0u1").params["current_limit"], "a job after the end runs at once"


@pytest.mark.parametrize("multiplex", [True, False])
def test_a_defect_in_a_poll_is_contained_and_the_bus_reopens_its_devices(
    lines: Lines, samples: Samples, monkeypatch: pytest.MonkeyPatch, multiplex: bool
) -> None:
    boom = RuntimeError("a defect in the bookkeeping")
    monkeypatch.setattr(
        BusWorker, "end", fails_once(BusWorker.end, lambda worker, *_: worker.bus.name == "line1", boom)
    )
    supervisor = Supervisor(FAST)
    poller = FleetPoller(lines.fleet(buses=2), samples, multiplex=multiplex, supervisor=supervisor)
    with poller:
        samples.wait_for(lambda ss: bool(supervisor.failures) and sum(s.bus == "line1" for s in ss) >= 6)
    assert supervisor.failures == {"bus-line1": 1} and poller.failure is None
    line1 = [s for s in samples.list if s.bus == "line1"]
    assert all(s.online for s in line1), "the bus started afresh: its devices reopened and answering"


def broken_selector(monkeypatch: pytest.MonkeyPatch, at_call: int) -> None:
    calls = [0]
    original = Waiter.wait

    def wait(self: Waiter[Any], timeout: float) -> list[Any]:
        calls[0] += 1
        if calls[0] == at_call:
            raise RuntimeError("the selector broke")
        return original(self, timeout)

    monkeypatch.setattr(Waiter, "wait", wait)


def test_the_multiplexer_failing_stops_the_poller_with_one_line(
    lines: Lines, samples: Samples, monkeypatch: pytest.MonkeyPatch
) -> None:
    broken_selector(monkeypatch, at_call=20)
    supervisor = Supervisor(FAST)
    poller = FleetPoller(lines.fleet(buses=2), samples, supervisor=supervisor).start()
    poller.join(30.0)
    assert not poller.running, "a fatal failure stops every bus"
    assert poller.failure is not None and poller.failure.worker == "starterbus-io"
    assert str(poller.failure).startswith("starterbus-io failed: RuntimeError: the selector broke (at ")
    assert supervisor.failures == {"starterbus-io": 1}
    assert no_leases_left(lines)


def test_a_jobs_thread_failing_stops_the_poller(
    lines: Lines, samples: Samples, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(Multiplexer, "_jobs", lambda self, bus: (_ for _ in ()).throw(RuntimeError("job runner")))
    supervisor = Supervisor(FAST)
    poller = FleetPoller(lines.fleet(buses=1), samples, supervisor=supervisor).start()
    samples.wait_for(lambda ss: len(ss) >= 3)
    future = poller.submit("b0u1", lambda d: d.read_value("current_limit").raw)
    poller.join(30.0)
    assert not poller.running and poller.failure is not None and poller.failure.worker == "jobs-line0"
    assert future.result(5) == lines.starter("b0u1").params["current_limit"], "the queued job ran at the end"


def test_poll_exits_1_with_one_line_when_a_worker_fails_for_good(
    lines: Lines, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    broken_selector(monkeypatch, at_call=20)
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(
        f'[poll]\nperiod = 0.05\n[[bus]]\nname = "line0"\nurl = "{lines.base(0)}?baudrate=19200&timeout=0.5"\n'
        '[[bus.device]]\nname = "b0u1"\nmodel = "jjr5000"\naddress = 1\n',
        encoding="utf-8",
    )
    code = main(["poll", str(fleet), "--json", "--duration", "60"])
    captured = capsys.readouterr()
    assert code == 1
    err = captured.err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("starterbus: error: starterbus-io failed: RuntimeError: the selector broke")
    assert '"device": "b0u1"' in captured.out, "it polled until then"


# -- serve's and opcua's tasks ----------------------------------------------------------------------------------


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_failing_edge_node_task_stops_serve_and_the_poller(lines: Lines, monkeypatch: pytest.MonkeyPatch) -> None:
    from starterbus.serve.actions import SessionOptions
    from starterbus.serve.broker import BrokerOptions
    from starterbus.serve.driver import EdgeNodeDriver
    from starterbus.serve.session import EdgeSession

    def broken(self: EdgeSession, sample: Sample, now: float) -> list[object]:
        raise KeyError("a defect in the session")

    monkeypatch.setattr(EdgeSession, "on_sample", broken)
    config = lines.fleet(buses=1)

    async def run() -> tuple[Supervisor, FleetPoller | None, BaseException | None]:
        supervisor = Supervisor(FAST)
        async with AsyncFleet(config, supervisor=supervisor) as fleet:
            session = EdgeSession.for_fleet(config, SessionOptions("g", "n"))
            broker = BrokerOptions("127.0.0.1", closed_port(), client_id="test")  # nobody there: it retries
            driver = EdgeNodeDriver(fleet, session, broker, retry_delay=0.05)
            stop = asyncio.Event()
            try:
                await asyncio.wait_for(driver.run(stop), 30.0)
            except ServiceFailed as exc:
                return supervisor, fleet.poller, exc
            return supervisor, fleet.poller, None

    supervisor, poller, raised = asyncio.run(run())
    assert isinstance(raised, ServiceFailed) and raised.worker == "serve-samples"
    assert supervisor.failure is raised
    assert str(raised).startswith("serve-samples failed: KeyError: 'a defect in the session' (at ")
    assert poller is not None and poller.stopping.is_set(), "the poller is told to stop too"


def test_opcua_exits_1_with_one_line_when_its_sample_pump_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("asyncua")
    from starterbus.opcua.server import OpcUaServer

    async def broken(self: OpcUaServer) -> None:
        async for _sample in self.fleet.samples():
            raise ValueError("cannot map a sample")

    monkeypatch.setattr(OpcUaServer, "_serve_samples", broken)
    endpoint = f"opc.tcp://127.0.0.1:{closed_port()}/starterbus"
    args = ["opcua", "--demo", "--anonymous", "--endpoint", endpoint, "--pki", str(tmp_path / "pki")]
    code = main([*args, "--duration", "60", "--json"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("starterbus")]
    assert code == 1
    assert len(err) == 1 and err[0].startswith("starterbus: error: opcua-samples failed: ValueError: cannot map")
