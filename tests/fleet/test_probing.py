"""Offline devices are probed (one attempt, short timeout, backoff with jitter, a bounded share of the line)."""

from __future__ import annotations

import random
from typing import TYPE_CHECKING

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.fleet.probing import JITTER, ProbeBudget, ProbeSettings, backoff
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

if TYPE_CHECKING:
    from starterbus.tests.fleet.conftest import Samples


def test_backoff_doubles_up_to_the_ceiling_with_jitter_below_it() -> None:
    rng = random.Random(7)
    for failures, nominal in ((1, 0.2), (2, 0.4), (3, 0.8), (4, 1.6), (9, 5.0), (60, 5.0)):
        drawn = [backoff(failures, 0.2, 5.0, rng) for _ in range(50)]
        assert all(nominal * (1 - JITTER) <= d <= nominal for d in drawn)
        assert len(set(drawn)) > 1, "devices that failed together do not probe in step"


@given(
    share=st.floats(0.01, 1.0),
    probes=st.lists(st.floats(0.001, 0.5), min_size=1, max_size=60),
    gaps=st.lists(st.floats(0.0, 0.3), min_size=60, max_size=60),
)
def test_probes_never_take_more_than_their_share_of_the_line(
    share: float, probes: list[float], gaps: list[float]
) -> None:
    burst = 0.1
    budget = ProbeBudget(share, burst, now=0.0)
    now = 0.0
    for took, gap in zip(probes, gaps, strict=False):
        deferrals = 0
        while (wait := budget.wait(now)) > 0:  # the worker defers a probe until the budget allows it
            now += wait
            deferrals += 1
        assert deferrals <= 2, "one deferral pays the debt back (a second only for rounding)"
        budget.spend(took, now + took)
        now += took + gap  # the live devices' polls in between
    assert budget.spent <= share * now + burst + max(probes) + 1e-9


def test_probe_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="share"):
        ProbeSettings(0.1, 0.0)
    with pytest.raises(ValueError, match="timeout"):
        ProbeSettings(-1.0)
    assert ProbeSettings(0.05).timeout_for(0.1) == pytest.approx(0.3), "a device seen slow gets a longer probe"
    assert ProbeSettings(None).timeout_for(0.1) is None


TALLIES = ("transactions", "requests", "timeouts")


def test_an_offline_device_is_probed_once_per_attempt_with_the_probe_timeout(samples: Samples) -> None:
    live = SimulatedStarter(get_profile("jjr5000"))
    dead = SimulatedStarter(get_profile("ssd1"))
    with ModbusRtuSimulator({1: live}, pty=True, baudrate=19200) as sim:
        base = sim.url(1).split("?")[0]
        config = parse_fleet(
            "[poll]\nperiod = 0.05\nmax_backoff = 0.2\n"
            f'[[bus]]\nname = "rtu"\nurl = "{base}?baudrate=19200&timeout=0.1&retries=2"\n'
            '[[bus.device]]\nname = "live"\nmodel = "jjr5000"\naddress = 1\n'
            '[[bus.device]]\nname = "dead"\nmodel = "ssd1"\naddress = 3\n'
        )

        def dead_probes(ss: list[Sample]) -> list[Sample]:
            return [s for s in ss if s.device == "dead" and s.probe]

        poller = FleetPoller(config, samples, probing=ProbeSettings(timeout=0.02, share=1.0), rng=random.Random(1))
        with poller:
            samples.wait_for(lambda ss: len(dead_probes(ss)) >= 3)
            first = next(s for s in samples.snapshot() if s.device == "dead")
            assert not first.online and not first.probe
            assert first.wire is not None and first.wire.requests == 3, "the first failure is a normal poll"
            assert "within 0.1 s" in (first.error or "")
            for probe in dead_probes(samples.snapshot())[:3]:
                assert not probe.online and probe.wire is not None
                assert (probe.wire.requests, probe.wire.retries, probe.wire.timeouts) == (1, 0, 1)
                assert "within 0.02 s" in (probe.error or ""), probe.error
            sim.starters[3] = dead  # the unit comes back
            mark = samples.mark()
            samples.wait_for(lambda ss: any(s.device == "dead" and s.online for s in ss[mark:]))
            back = next(s for s in samples.of("dead", mark) if s.online)
            assert back.probe and back.status is not None
            mark = samples.mark()
            samples.wait_for(lambda ss: any(s.device == "dead" and not s.probe for s in ss[mark:]))
        assert all(s.online for s in samples.list if s.device == "live")
        stats = poller.line_stats()["rtu"]
        assert stats.probes == len(dead_probes(samples.list))
        # a poll under way at the stop is cancelled: what it sent is in the line's counters and in no sample
        # (a status read of "live", up to three attempts, or a probe of "dead": one)
        wires = [s.wire for s in samples.list if s.wire is not None]
        unsampled = {k: getattr(stats.wire, k) - sum(getattr(w, k) for w in wires) for k in TALLIES}
        assert unsampled["transactions"] in (0, 1) and 0 <= unsampled["timeouts"] <= 2, unsampled
        assert unsampled["requests"] <= 3 * unsampled["transactions"] and unsampled["requests"] >= 0, unsampled
