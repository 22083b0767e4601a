"""PKW buses of simulated slaves in a fleet (issue 29, step 6): their polls are tasks on the scheduler (the
station's start_poll), so no bus gets a thread of its own and no station a cycle thread."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller
from starterbus.tests.fleet.conftest import Samples
from starterbus.transports.profibus_pkw.driver.channels import attach_slave, detach_slave


@pytest.fixture
def starters() -> Iterator[dict[str, SimulatedStarter]]:
    made = {f"fleet-pkw-{n}": SimulatedStarter(get_profile("jjr8000"), values={"ramp_time": 10 + n}) for n in (1, 2)}
    for name, starter in made.items():
        attach_slave(name, starter)
    try:
        yield made
    finally:
        for name in made:
            detach_slave(name)


@pytest.mark.parametrize("cycle", ["0", "0.002"])
def test_pkw_buses_are_polled_without_a_thread_per_bus(starters: dict[str, SimulatedStarter], cycle: str) -> None:
    text = "[poll]\nperiod = 0.001\n"
    for name in starters:
        text += (
            f'[[bus]]\nname = "{name}"\nurl = "profibus-pkw+sim://{name}?ppo=1&cycle={cycle}"\n'
            f'[[bus.device]]\nname = "{name}-dev"\nmodel = "jjr8000"\naddress = 2\nparameters = ["ramp_time"]\n'
        )
    samples = Samples()
    threads: list[set[str]] = []
    samples.hooks.append(lambda _: threads.append({t.name for t in threading.enumerate()}))
    poller = FleetPoller(parse_fleet(text), samples, rounds=3)
    poller.start()
    poller.join(30.0)
    assert not poller.running
    assert all(w.thread.ident is None for w in poller.workers), "no bus got a thread of its own"
    assert not any(name.startswith("profibus-pkw cycle") for seen in threads for name in seen)
    for n, name in enumerate(starters, start=1):
        polls = samples.of(f"{name}-dev")
        assert len(polls) == 3 and all(p.online and p.error is None for p in polls), polls
        assert all(p.values["ramp_time"].raw == 10 + n for p in polls)
        assert all(p.status is not None and not p.status.running for p in polls)
