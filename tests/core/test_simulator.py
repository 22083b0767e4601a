"""The shared simulated soft starter: state machine on a manual clock, control word, faults, write rules."""

from __future__ import annotations

import threading

import pytest

from starterbus.core.control_log import LOG_SIZE
from starterbus.core.errors import Refusal, SimulatorRefusal
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import decode_status_word


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def starter_for(profile: Profile, clock: ManualClock, **values: int) -> SimulatedStarter:
    return SimulatedStarter(profile, clock, load=0.8, values=values)


def status(starter: SimulatedStarter) -> int:
    return starter.status_word()


def test_full_cycle_with_currents(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock, motor_rated_current=100, current_limit=300, ramp_time=8, soft_stop_time=4)
    decoded = decode_status_word(status(sim), jjr5000.faults, bit12_is_mains_voltage=True)
    assert decoded.ready and not decoded.running and decoded.mains_voltage
    sim.write_control_word(0x0009)
    assert phase(sim) is Phase.STARTING
    clock.advance(1.0)  # a quarter of the ramp is 2 s: half-way up to 3 x 100 A
    assert sim.current() == pytest.approx(150.0)
    clock.advance(1.0)
    assert sim.current() == pytest.approx(300.0)
    clock.advance(5.9)
    assert phase(sim) is Phase.STARTING
    assert sim.current() <= 300.0
    clock.advance(0.2)
    assert phase(sim) is Phase.RUNNING
    assert sim.current() == pytest.approx(80.0)
    word = status(sim)
    assert word & (1 << 9) and not word & (1 << 8) and not word & (1 << 13)
    sim.write_control_word(0x0008)
    assert phase(sim) is Phase.STOPPING
    clock.advance(2.0)
    assert sim.current() == pytest.approx(40.0)
    clock.advance(2.0)
    assert phase(sim) is Phase.STOPPED
    assert sim.start_count == 1
    phase_a = jjr5000.point("phase_a_current")
    assert sim.read(phase_a) == 0
    assert sim.read(jjr5000.point("max_start_current")) == 3000  # 300.0 A in 0.1 A
    assert sim.read(jjr5000.point("max_run_current")) == 800


def test_fault_stops_motor_and_reset_needs_new_start(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.write_control_word(0x0009, cyclic=True)
    clock.advance(1.0)
    sim.inject_fault(6)
    decoded = decode_status_word(status(sim), jjr8000.faults)
    assert decoded.fault and decoded.fault_code == 6
    assert decoded.fault_text == jjr8000.faults.text(6)
    assert sim.current() == 0
    sim.write_control_word(0x000D, cyclic=True)  # reset while start bit still held
    assert phase(sim) is Phase.STOPPED
    sim.write_control_word(0x0009, cyclic=True)
    assert phase(sim) is Phase.STOPPED, "a held start bit must not restart after a fault reset"
    sim.write_control_word(0x0008, cyclic=True)
    sim.write_control_word(0x0009, cyclic=True)
    assert phase(sim) is Phase.STARTING


def test_unknown_fault_code_decodes_as_unknown(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.inject_fault(63)
    decoded = decode_status_word(status(sim), jjr8000.faults)
    assert decoded.fault_code == 63
    assert decoded.fault_text == "unknown fault 63"


def test_jjr8000_needs_bus_control_bit(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.write_control_word(0x0001)
    assert phase(sim) is Phase.STOPPED
    sim.write_control_word(0x0009)
    assert phase(sim) is Phase.STARTING


def test_jjr5000_starts_without_bus_control_bit(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock)
    sim.write_control_word(0x0001)
    assert phase(sim) is Phase.STARTING


@pytest.mark.parametrize(("model", "protect"), [("jjr5000", "0x0147"), ("ssd1", "0x0125")])
def test_parameter_modify_zero_refuses_writes(model: str, protect: str, clock: ManualClock) -> None:
    from starterbus.core.registry import get_profile

    profile = get_profile(model)
    sim = SimulatedStarter(profile, clock)
    limit = profile.point("current_limit")
    sim.write(limit, 380)
    assert sim.read(limit) == 380
    sim.write(profile.point(protect), 0)
    with pytest.raises(SimulatorRefusal) as info:
        sim.write(limit, 400)
    assert info.value.reason is Refusal.WRITE_PROTECTED
    assert sim.read(limit) == 380
    sim.write(profile.point(protect), 1)  # the switch itself stays writable
    sim.write(limit, 400)
    assert sim.read(limit) == 400


def test_out_of_range_and_read_only_refused(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock)
    with pytest.raises(SimulatorRefusal) as info:
        sim.write(jjr5000.point("current_limit"), 149)
    assert info.value.reason is Refusal.OUT_OF_RANGE
    with pytest.raises(SimulatorRefusal) as info:
        sim.write(jjr5000.point("status_word"), 1)
    assert info.value.reason is Refusal.READ_ONLY


def test_jjr8000_locked_while_running(jjr8000: Profile, clock: ManualClock) -> None:
    locked = sorted(jjr8000.control.locked_while_running)
    assert locked, "the JJR8000 profile must name parameters that cannot change while running"
    point = jjr8000.point(locked[0])
    sim = starter_for(jjr8000, clock)
    sim.write_control_word(0x0009)
    with pytest.raises(SimulatorRefusal) as info:
        sim.write(point, sim.read(point))
    assert info.value.reason is Refusal.WHILE_RUNNING


def test_point_at_unknown_address(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock)
    from starterbus.core.model import Kind

    assert sim.point_at("modbus-rtu", Kind.PARAMETER, 0x0103).key == "current_limit"
    with pytest.raises(SimulatorRefusal) as info:
        sim.point_at("modbus-rtu", Kind.PARAMETER, 0x0107)
    assert info.value.reason is Refusal.NOT_AVAILABLE


def test_command_lost_soft_stops(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.write_control_word(0x0009, cyclic=True)
    clock.advance(60)
    assert phase(sim) is Phase.RUNNING
    sim.command_lost()
    assert phase(sim) in (Phase.STOPPING, Phase.STOPPED)


# -- the record of control outputs (core/control_log.py) ---------------------------------------------------------


def test_keypad_start_and_stop_are_not_control_outputs(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.start()
    clock.advance(60)
    sim.soft_stop()
    sim.command_lost()  # no run command held: nothing to drop
    assert sim.control_writes == [] and sim.control_writes_total == 0


def test_one_off_writes_always_count(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock)
    clock.advance(3)
    now = clock.now
    sim.write_control_word(0x0000, source="Modbus FC06 unit 2")  # a level: a soft stop for a JJR5000
    sim.write_control_word(0x0000)
    [first, second] = sim.control_writes
    assert (first.time, first.word, first.cyclic, first.source, first.lost) == (
        now,
        0,
        False,
        "Modbus FC06 unit 2",
        False,
    )
    assert "0x0000" in first.describe() and "one-off from Modbus FC06 unit 2" in first.describe()
    assert second.source == "" and sim.control_writes_total == 2


def test_cyclic_no_operation_does_not_count(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.start()
    for _ in range(5):  # a DP master (gateway) sends STW 0x0000 on every cycle while it only reads
        sim.write_control_word(0x0000, cyclic=True, source="Profibus PPO1 STW")
    assert sim.control_writes == [] and phase(sim) is Phase.STARTING


@pytest.mark.parametrize("word", [0x0001, 0x0004, 0x0008, 0x0009])
def test_cyclic_command_bits_count_once_while_held(jjr8000: Profile, clock: ManualClock, word: int) -> None:
    sim = starter_for(jjr8000, clock)
    for _ in range(3):
        sim.write_control_word(word, cyclic=True, source="DeviceNet poll")
    [record] = sim.control_writes
    assert record.word == word and record.cyclic and record.source == "DeviceNet poll"


def test_cyclic_stop_after_run_counts(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock)
    sim.write_control_word(0x0001, cyclic=True)
    sim.write_control_word(0x0000, cyclic=True)  # the run bit falls: a soft stop, not "no operation"
    assert [w.word for w in sim.control_writes] == [0x0001, 0x0000]
    assert phase(sim) in (Phase.STOPPING, Phase.STOPPED)


def test_a_dropped_run_command_is_recorded(jjr8000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr8000, clock)
    sim.write_control_word(0x0009, cyclic=True)
    mark = sim.control_writes_total
    sim.command_lost("CANopen master heartbeat lost")
    [record] = sim.control_writes_since(mark)
    assert record.lost and record.word == 0x0008 and "heartbeat lost" in record.describe()


def test_the_record_is_bounded_and_counts_everything(jjr5000: Profile, clock: ManualClock) -> None:
    sim = starter_for(jjr5000, clock)

    def master() -> None:
        for _ in range(200):
            sim.write_control_word(0x0008)

    threads = [threading.Thread(target=master) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sim.control_writes_total == 800 and len(sim.control_writes) == LOG_SIZE
    mark = sim.control_writes_total
    assert sim.control_writes_since(mark) == []
    sim.write_control_word(0x0009)
    assert [w.word for w in sim.control_writes_since(mark)] == [0x0009]
