"""Stale PKW answers through the cycle driver: the simulated slave (slow, ordered) behind fault-injecting
channels that lag, jitter or replay the input image (issue 11, item 2; docs/profibus.md, "Stale answers")."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import pytest

from starterbus.core.errors import ConfigurationError, TimeoutError
from starterbus.core.model import Kind as PointKind
from starterbus.core.profile import Profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.url import DeviceUrl
from starterbus.transports.profibus_pkw.codec.codes import TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import PkwRequest, pkw_request
from starterbus.transports.profibus_pkw.driver.channels import Channel, SimChannel, Snapshot
from starterbus.transports.profibus_pkw.driver.link import CyclicLink
from starterbus.transports.profibus_pkw.master.handshake import Limits, PkwEngine
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave
from starterbus.transports.profibus_pkw.url import LinkSettings

READ_P3 = pkw_request(TaskCode.READ_PARAMETER, 3)
READ_M3 = pkw_request(TaskCode.READ_MEASUREMENT, 3)
WRITE_P3 = pkw_request(TaskCode.WRITE_PARAMETER, 3, 20)


class StaleInputChannel(Channel):
    """Wraps a channel; returns the input of ``lag(k)`` exchanges ago (``replay_after_clear``: after an input
    showing "no response", the next exchange returns the input before it once, as the issue's gateway did)."""

    def __init__(
        self, inner: Channel, lag: Callable[[int], int] = lambda k: 0, *, replay_after_clear: bool = False
    ) -> None:
        self.inner = inner
        self.ppo = inner.ppo
        self.lag = lag
        self.replay_after_clear = replay_after_clear
        self.history: list[tuple[int, ...]] = []
        self.returned: list[tuple[int, ...]] = []
        self.replays = 0

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        self.history.append(self.inner.exchange(out_words))
        k = len(self.history) - 1
        words = self.history[max(0, k - self.lag(k))]
        last = self.returned[-2:]
        if self.replay_after_clear and len(last) == 2 and last[1][0] == 0 and last[0][0] != 0:
            words = last[0]
            self.replays += 1
        self.returned.append(words)
        return words

    def snapshot(self) -> Snapshot:
        return self.inner.snapshot()


def starter_link(
    profile: Profile, limits: Limits, *, latency: int = 0, wrap: Callable[[Channel], Channel] = lambda c: c
) -> tuple[CyclicLink, SimulatedDpSlave, SimulatedStarter]:
    starter = SimulatedStarter(profile, values={"ramp_time": 12})
    slave = SimulatedDpSlave(starter, latency=latency)
    link = CyclicLink(wrap(SimChannel(slave)), PkwEngine(limits=limits), cycle=0)
    link.open()
    return link, slave, starter


@pytest.mark.parametrize("task", [READ_P3, READ_M3, WRITE_P3], ids=["read-p3", "read-m3", "write-p3"])
def test_after_a_timed_out_read_the_next_task_gets_its_own_answer(jjr8000: Profile, task: PkwRequest) -> None:
    # The simulated slave answers 40 exchanges late (in order); the read of p3 gives up after 30.
    link, slave, starter = starter_link(jjr8000, Limits(max_cycles=30, timeout=100), latency=40)
    try:
        with pytest.raises(TimeoutError):
            link.pkw(READ_P3)
        slave.latency = 0  # from now on prompt; the old read's answer (12) still shows first
        p3 = starter.point_at("profibus-pkw", PointKind.PARAMETER, 3)
        starter.write(p3, 15)
        job = link.pkw(task)
        assert job.response is not None
        expected = {READ_P3: 15, READ_M3: 0, WRITE_P3: 20}[task]  # m3 of a stopped motor: 0 A
        assert job.response.pwe == expected and job.fences == 1
        if task == WRITE_P3:
            assert starter.read(p3) == 20
    finally:
        link.close()


@pytest.mark.parametrize("verify_start", [True, False])
def test_a_task_left_by_an_earlier_session_does_not_answer_the_next_sessions_first(
    jjr8000: Profile, verify_start: bool
) -> None:
    # Session 1 gives up on a read of p3 and dies; the slave (40 exchanges late) is still working on it.
    first, slave, _ = starter_link(jjr8000, Limits(max_cycles=30, timeout=100), latency=40)
    with pytest.raises(TimeoutError):
        first.pkw(READ_P3)
    slave.latency = 20  # still slow: the old answer shows on its own for a while
    # Session 2's first task, m3 (INDL 3 too). The transport builds its engine with verify_start: the task waits
    # for the start chain (three fence reads on INDLs of their own, inherited=2). Without it, the old answer (12)
    # is taken for m3 (0 A): the reason for the rule.
    limits = Limits(max_cycles=100, timeout=100, verify_start=verify_start)
    second = CyclicLink(SimChannel(slave), PkwEngine(limits=limits), cycle=0)
    second.open()
    try:
        job = second.pkw(READ_M3)
        assert job.response is not None
        assert (job.response.pwe, job.fences) == ((0, 3) if verify_start else (12, 0))
    finally:
        second.close()
        first.close()


def test_a_replaying_gateway_never_lends_p3_to_m3(jjr8000: Profile) -> None:
    replaying: list[StaleInputChannel] = []

    def wrap(channel: Channel) -> Channel:
        replaying.append(StaleInputChannel(channel, replay_after_clear=True))
        return replaying[0]

    link, _, _ = starter_link(jjr8000, Limits(max_cycles=30, timeout=100, stale_cycles=1), wrap=wrap)
    try:
        for _ in range(20):
            p3, m3 = link.pkw(READ_P3), link.pkw(READ_M3)
            assert p3.response is not None and p3.response.pwe == 12
            assert m3.response is not None and m3.response.pwe == 0
        assert replaying[0].replays >= 20  # the gateway did replay the p3 answer
    finally:
        link.close()


def test_a_jittering_gateway_within_the_margin(jjr8000: Profile) -> None:
    lags = [0, 2, 1, 0, 2, 2, 0, 1]
    link, _, starter = starter_link(
        jjr8000,
        Limits(max_cycles=40, timeout=100, stale_cycles=2),
        wrap=lambda c: StaleInputChannel(c, lambda k: lags[k % len(lags)]),
    )
    p3 = starter.point_at("profibus-pkw", PointKind.PARAMETER, 3)
    try:
        for value in range(13, 33):
            starter.write(p3, value)  # every read must see the value of its own moment
            read = link.pkw(READ_P3)
            assert read.response is not None and read.response.pwe == value
            m3 = link.pkw(READ_M3)
            assert m3.response is not None and m3.response.pwe == 0
    finally:
        link.close()


def test_the_gateway_url_carries_the_margin(jjr8000: Profile) -> None:
    gateway = LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+gateway://127.0.0.1:1502"), jjr8000)
    assert (gateway.limits.stale_cycles, gateway.limits.stale_time, gateway.limits.verify_start) == (1, 0.0, True)
    sim = LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+sim://?stale_cycles=3&stale_time=0.02"), jjr8000)
    assert (sim.limits.stale_cycles, sim.limits.stale_time) == (3, 0.02)
    assert (gateway.limits.inherited, sim.limits.inherited) == (2, 2)
    assert LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+sim://?inherited=0"), jjr8000).limits.inherited == 0
    with pytest.raises(ConfigurationError, match="inherited"):
        LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+sim://?inherited=255"), jjr8000)
