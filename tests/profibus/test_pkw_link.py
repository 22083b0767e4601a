"""The cycle driver: PZD every exchange, PKW jobs to their end, command words held, failures typed."""

from __future__ import annotations

import threading
from collections.abc import Sequence

import pytest

from starterbus.core.errors import TimeoutError, TransportError
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.transports.profibus_pkw.codec.codes import Ppo, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import pkw_request
from starterbus.transports.profibus_pkw.driver.channels import Channel, SimChannel, Snapshot
from starterbus.transports.profibus_pkw.driver.link import CyclicLink
from starterbus.transports.profibus_pkw.master.handshake import Limits, PkwEngine
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

READ_P3 = pkw_request(TaskCode.READ_PARAMETER, 3)


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def sent_word(word: int | None) -> int:
    """A word the link did send (not None: None leaves the previous output in force)."""
    assert word is not None, "no word sent"
    return word


class RecordingChannel(Channel):
    """A third-party style channel: delegates to a simulated slave and records what was sent."""

    def __init__(self, slave: SimulatedDpSlave, *, clock: ManualClock | None = None, hide_outputs: bool = False):
        self.inner = SimChannel(slave)
        self.ppo = slave.ppo
        self.sent: list[tuple[int | None, ...]] = []
        self.failing = False
        self.clock = clock
        self.hide_outputs = hide_outputs
        self.closed = False

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        if self.clock is not None:
            self.clock.advance(0.01)
        if self.failing:
            raise TransportError("cable pulled")
        self.sent.append(tuple(out_words))
        return self.inner.exchange(out_words)

    def snapshot(self) -> Snapshot:
        snap = self.inner.snapshot()
        return Snapshot(None, snap.inputs) if self.hide_outputs else snap

    def close(self) -> None:
        self.closed = True

    def stws(self) -> list[int]:
        return [sent_word(w[2] if self.ppo is Ppo.PPO1 else w[0]) for w in self.sent if w[-1] is not None]


def make(
    profile: Profile, ppo: Ppo = Ppo.PPO1, *, latency: int = 0, cycle: float = 0.0, limits: Limits | None = None,
    hold: int = 3, pulse: float = 0.0, starter: SimulatedStarter | None = None, clock: ManualClock | None = None,
    hide_outputs: bool = False,
) -> tuple[CyclicLink, RecordingChannel, SimulatedStarter]:  # fmt: skip
    starter = starter or SimulatedStarter(profile)
    channel = RecordingChannel(SimulatedDpSlave(starter, ppo, latency=latency), clock=clock, hide_outputs=hide_outputs)
    engine = PkwEngine(profile.transport_settings("profibus-pkw")["errors"], limits or Limits())
    kwargs = {"clock": clock} if clock is not None else {}
    link = CyclicLink(channel, engine, cycle=cycle, hold=hold, pulse=pulse, **kwargs)  # type: ignore[arg-type]
    return link, channel, starter


def test_on_demand_read_takes_two_exchanges(jjr8000: Profile) -> None:
    link, channel, _ = make(jjr8000)
    assert link.open() is None  # a new slave: no outputs to adopt, the control word is left alone
    job = link.pkw(READ_P3, "read p3")
    assert job.response is not None and job.response.pwe == 12 and job.cycles == 2
    assert channel.sent == [(0, 0, None, None), (0x0103, 0, None, None)]
    job = link.pkw(READ_P3)  # the same task again: clear, then task (the slave latches per change)
    assert job.cycles == 2 and channel.sent[-2:] == [(0, 0, None, None), (0x0103, 0, None, None)]
    link.send_control([0x0008])
    job = link.pkw(READ_P3)
    assert channel.sent[-2:] == [(0, 0, 8, 0), (0x0103, 0, 8, 0)]  # after a command: the word goes out
    link.close()
    assert channel.closed and channel.sent[-1][:2] == (0, 0)  # "no task" left in the output area


def test_background_cycles_read_and_status(jjr5000: Profile) -> None:
    link, _channel, starter = make(jjr5000, cycle=0.002)
    link.open()
    try:
        assert link.running
        job = link.pkw(pkw_request(TaskCode.READ_MEASUREMENT, 1))
        assert job.response is not None and job.response.pwe == starter.status_word()
        link.send_control([0x0009])
        words = link.inputs()
        assert words[2] & 0x0100  # starting, seen in an exchange after the command
        assert link.stats().exchanges >= 3 and link.stats().failures == 0
    finally:
        link.close()
    assert not link.running


@pytest.mark.parametrize("cycle", [0.0, 0.002])
def test_start_is_not_delayed_by_a_stuck_pkw_task(jjr8000: Profile, cycle: float) -> None:
    # The slave never shows a PKW response (latency beyond any limit): the job waits, PZD goes on.
    # its time limit (2 s) only has to outlast the start: 0.3 s did not always on a loaded machine
    link, channel, starter = make(jjr8000, latency=10**6, cycle=cycle, limits=Limits(max_cycles=10**6, timeout=2.0))
    link.open()
    outcome: list[BaseException] = []
    reader = threading.Thread(target=lambda: _catch(outcome, lambda: link.pkw(READ_P3)))
    try:
        reader.start()
        while not any(w[0] == 0x0103 for w in channel.sent[-5:]):  # the task is in the output area
            threading.Event().wait(0.001)
        link.send_control([0x0009])
        assert phase(starter) is Phase.STARTING  # started while the PKW task is pending
        assert reader.is_alive()
        starts = [w for w in channel.sent if w[2] == 0x0009]
        assert starts and all(w[0] in (0, 0x0103) for w in starts)
    finally:
        reader.join(15)
        link.close()
    assert len(outcome) == 1 and isinstance(outcome[0], TimeoutError)


def _catch(outcome: list[BaseException], fn: object) -> None:
    try:
        fn()  # type: ignore[operator]
    except BaseException as exc:
        outcome.append(exc)


def test_reset_pulse_is_held_for_hold_exchanges_then_released(jjr5000: Profile) -> None:
    link, channel, starter = make(jjr5000, hold=3)
    link.open()
    starter.inject_fault(5)
    link.send_control([0x000C, 0x0008])
    assert channel.stws() == [0x000C] * 3 + [0x0008] * 3
    assert phase(starter) is Phase.STOPPED and link.control == 0x0008
    link.inputs()
    assert channel.stws()[-1] == 0x0008  # the last word stays in force


def test_pulse_time_holds_a_word_longer_than_hold_exchanges(jjr5000: Profile) -> None:
    clock = ManualClock()  # advanced 10 ms per exchange by the channel
    link, channel, _ = make(jjr5000, hold=1, pulse=0.05, clock=clock)
    link.open()
    link.send_control([0x000C, 0x0008])
    stws = channel.stws()
    assert stws.count(0x000C) >= 5 and stws[-1] == 0x0008
    assert stws == sorted(stws, reverse=True)  # all reset words first


def test_open_adopts_the_control_word_in_force(jjr8000: Profile) -> None:
    starter = SimulatedStarter(jjr8000)
    first = SimulatedDpSlave(starter, Ppo.PPO1)
    first.exchange((0, 0, 0x0009, 0))  # another master started the motor
    assert phase(starter) is Phase.STARTING
    channel = RecordingChannel(first)
    link = CyclicLink(channel, PkwEngine(), cycle=0.0)
    assert link.open() == 0x0009
    link.inputs()
    assert channel.stws() == [0x0009] and phase(starter) is Phase.STARTING


def test_open_leaves_an_unknown_control_word_alone(jjr8000: Profile) -> None:
    # A monitoring session must not change the control word another master holds, nor create an edge for it.
    starter = SimulatedStarter(jjr8000)
    starter.write_control_word(0x0009)  # another master (Modbus, keypad...) started the motor
    link, channel, _ = make(jjr8000, starter=starter, hide_outputs=True)
    assert link.open() is None and link.control is None and link.motor_running()
    link.inputs()
    link.pkw(READ_P3)
    assert all(w[2] is None for w in channel.sent)
    assert starter.control_word == 0x0009 and phase(starter) is Phase.STARTING
    starter.write_control_word(0x0008)  # the other master stops it: our link does not restart it
    link.inputs()
    assert phase(starter) is Phase.STOPPING
    link.close()


def test_a_failing_channel_gives_typed_errors_and_recovers(jjr8000: Profile) -> None:
    link, channel, _ = make(jjr8000, limits=Limits(max_cycles=10, timeout=0.5))
    link.open()
    channel.failing = True
    with pytest.raises(TransportError, match="cable pulled"):
        link.pkw(READ_P3)
    with pytest.raises(TransportError, match="cable pulled"):
        link.inputs()
    with pytest.raises(TimeoutError, match="cable pulled"):
        link.send_control([0x0009], timeout=0.05)
    assert link.stats().failures >= 3 and "cable pulled" in str(link.stats().last_error)
    channel.failing = False
    assert link.pkw(READ_P3).response is not None
    link.close()


def test_ppo3_link_has_no_pkw(jjr5000: Profile) -> None:
    link, channel, starter = make(jjr5000, Ppo.PPO3)
    link.open()
    with pytest.raises(ValueError, match="PPO3"):
        link.pkw(READ_P3)
    link.send_control([0x0009])
    assert channel.sent[-1] == (0x0009, 0) and phase(starter) is Phase.STARTING
    link.close()


def test_bad_settings_and_words(jjr5000: Profile) -> None:
    with pytest.raises(ValueError):
        make(jjr5000, hold=0)
    link, _, _ = make(jjr5000)
    link.open()
    with pytest.raises(ValueError):
        link.send_control([0x10000])
    link.send_control([])  # nothing to do
