"""The simulated DP slave answers like the manuals: response codes and error numbers per model, PZD, latching."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from starterbus.core.errors import ConfigurationError, DecodeError, Refusal
from starterbus.core.profile import Profile, load_profile_text
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.transports.profibus_pkw.codec.codes import Ppo, ResponseCode
from starterbus.transports.profibus_pkw.settings import UNSUPPORTED_TASK
from starterbus.transports.profibus_pkw.slave import (
    REFUSAL_ANSWERS,
    PkwAnswer,
    SimulatedDpSlave,
    refusal_answers,
)

if TYPE_CHECKING:
    from starterbus.tests.profibus.conftest import RunningStarter

BUS = 0x0008  # control word: bus control, no start


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def pkw(slave: SimulatedDpSlave, ind: int, pwe: int = 0, stw: int = BUS) -> tuple[int, int]:
    """One exchange with a task; returns the PKW words the slave shows (after a clear exchange before it)."""
    slave.exchange((0, 0, stw, 0))
    words = slave.exchange((ind, pwe, stw, 0))
    return words[0], words[1]


# (model, running, values, request IND, PWE) -> (response IND, PWE): the answers
# docs/manuals.md#3-profibus-dp-pkw-and-pzd-telegrams defines.
CASES = [
    # JJR5000: errors 1 illegal function, 2 illegal address, 3 illegal value, 4 parameter modify forbidden
    ("5000 read p 0x0100", "jjr5000", False, {}, 0x0100, 0, 0x0100, 390),
    ("5000 read undefined 0x0107", "jjr5000", False, {}, 0x0107, 0, 0x0307, 2),
    ("5000 read meas undefined 0x07", "jjr5000", False, {}, 0x0307, 0, 0x0307, 2),
    ("5000 write in range", "jjr5000", False, {}, 0x0203, 380, 0x0103, 380),
    ("5000 write below range", "jjr5000", False, {}, 0x0203, 149, 0x0303, 3),
    ("5000 write enum not in table", "jjr5000", False, {}, 0x0204, 3, 0x0304, 3),
    ("5000 write undefined", "jjr5000", False, {}, 0x0207, 1, 0x0307, 2),
    ("5000 write while modify=0", "jjr5000", False, {"parameter_modify": 0}, 0x0203, 380, 0x0303, 4),
    ("5000 release modify lock", "jjr5000", False, {"parameter_modify": 0}, 0x0247, 1, 0x0147, 1),
    ("5000 write while running (allowed)", "jjr5000", True, {}, 0x0203, 380, 0x0103, 380),
    ("5000 unknown task 4", "jjr5000", False, {}, 0x0403, 0, 0x0303, 1),
    ("5000 unknown task FF", "jjr5000", False, {}, 0xFF03, 0, 0x0303, 1),
    # JJR8000: errors 0 not available, 1 cannot be modified, 2 out of limits, 3 while running, 4 not supported
    ("8000 read p7", "jjr8000", False, {}, 0x0107, 0, 0x0107, 350),
    ("8000 read undefined p19", "jjr8000", False, {}, 0x0113, 0, 0x0313, 0),
    ("8000 read meas undefined m13", "jjr8000", False, {}, 0x030D, 0, 0x030D, 0),
    ("8000 write out of limits", "jjr8000", False, {}, 0x0207, 501, 0x0307, 2),
    ("8000 write undefined p19", "jjr8000", False, {}, 0x0213, 1, 0x0313, 0),
    ("8000 write locked while running", "jjr8000", True, {}, 0x0207, 400, 0x0307, 3),
    ("8000 write unlocked while running", "jjr8000", True, {}, 0x020E, 1, 0x010E, 1),
    ("8000 unknown task 9", "jjr8000", False, {}, 0x0907, 0, 0x0307, 4),
]


@pytest.mark.parametrize(
    ("model", "running", "values", "ind", "pwe", "answer_ind", "answer_pwe"),
    [c[1:] for c in CASES],
    ids=[c[0] for c in CASES],
)
def test_answers(
    model: str,
    running: bool,
    values: dict[str, int],
    ind: int,
    pwe: int,
    answer_ind: int,
    answer_pwe: int,
    profiles: dict[str, Profile],
    clock: ManualClock,
    running_starter: RunningStarter,
) -> None:
    profile = profiles[model]
    starter = running_starter(profile, clock, **values) if running else SimulatedStarter(profile, clock, values=values)
    slave = SimulatedDpSlave(starter, Ppo.PPO1)
    stw = 0x0009 if running else BUS
    assert pkw(slave, ind, pwe, stw) == (answer_ind, answer_pwe)


def test_writes_take_effect_once_and_reads_see_them(profiles: dict[str, Profile], clock: ManualClock) -> None:
    starter = SimulatedStarter(profiles["jjr8000"], clock)
    slave = SimulatedDpSlave(starter, Ppo.PPO1)
    assert pkw(slave, 0x0203, 20) == (0x0103, 20)
    assert starter.params["ramp_time"] == 20
    executed = slave.tasks_executed
    for _ in range(5):  # the master repeats the task: the slave does not execute it again
        slave.exchange((0x0203, 20, BUS, 0))
    assert slave.tasks_executed == executed
    assert pkw(slave, 0x0103) == (0x0103, 20)


def test_task_zero_is_answered_with_no_response(profiles: dict[str, Profile]) -> None:
    slave = SimulatedDpSlave(SimulatedStarter(profiles["jjr5000"]), Ppo.PPO1)
    slave.exchange((0x0100, 0, BUS, 0))
    assert slave.exchange((0, 0, BUS, 0))[:2] == (0, 0)


def test_latency_delays_every_new_pkw_response(profiles: dict[str, Profile]) -> None:
    slave = SimulatedDpSlave(SimulatedStarter(profiles["jjr8000"]), Ppo.PPO1, latency=2)
    seen = [slave.exchange((0x0103, 0, BUS, 0))[:2] for _ in range(4)]
    assert seen == [(0, 0), (0, 0), (0x0103, 12), (0x0103, 12)]
    seen = [slave.exchange((0, 0, BUS, 0))[:2] for _ in range(3)]
    assert seen == [(0x0103, 12), (0x0103, 12), (0, 0)]


def test_pzd_drives_the_starter_every_exchange(profiles: dict[str, Profile], clock: ManualClock) -> None:
    starter = SimulatedStarter(profiles["jjr8000"], clock, load=0.5)
    slave = SimulatedDpSlave(starter, Ppo.PPO3)
    zsw, act = slave.exchange((0x0001, 0))  # JJR8000 ignores commands without bit 3
    assert phase(starter) is Phase.STOPPED and act == 0
    zsw, act = slave.exchange((0x0009, 0))
    assert phase(starter) is Phase.STARTING and zsw & 0x0100 and zsw & 0x4000
    clock.advance(600)
    zsw, act = slave.exchange((0x0009, 0))
    assert zsw & 0x0200 and act == round(starter.current() * 10)
    starter.inject_fault(6)
    zsw, _ = slave.exchange((0x0009, 0))
    assert zsw & 0x8000 and zsw & 0x3F == 6
    zsw, _ = slave.exchange((0x000D, 0))  # reset pulse (bit 2) with the start bit held
    assert not zsw & 0x8000 and phase(starter) is Phase.STOPPED  # a held start bit does not restart
    assert slave.inputs() == (starter.status_word(), 0)


def test_wrong_output_words_are_refused(profiles: dict[str, Profile]) -> None:
    slave = SimulatedDpSlave(SimulatedStarter(profiles["jjr5000"]), Ppo.PPO1, name="s1")
    with pytest.raises(DecodeError, match="expects 4"):
        slave.exchange((0, 0))
    with pytest.raises(DecodeError):
        slave.exchange((0, 0, 0x10000, 0))


def test_the_model_must_offer_the_ppo_type(profiles: dict[str, Profile]) -> None:
    text = Path(profiles["jjr5000"].source).read_text(encoding="utf-8").replace("ppo = [1, 3]", "ppo = [1]")
    only1 = load_profile_text(text, "only-ppo1.toml")
    with pytest.raises(ConfigurationError, match="PPO3"):
        SimulatedDpSlave(SimulatedStarter(only1), Ppo.PPO3)
    with pytest.raises(ValueError):
        SimulatedDpSlave(SimulatedStarter(only1), Ppo.PPO1, latency=-1)


def _custom(profile: Profile, name: str, extra: str = "", read_only: str = "") -> Profile:
    text = Path(profile.source).read_text(encoding="utf-8")
    text = re.sub(r'(?m)^name = "jjr\d+"$', f'name = "{name}"', text, count=1)
    if read_only:
        text = re.sub(rf'(key = "{read_only}"\n(?:[^\[]*?\n)*?)access = "rw"', r'\1access = "r"', text, count=1)
    if extra:
        text = text.replace("[transports.profibus-pkw]\n", "[transports.profibus-pkw]\n" + extra, 1)
    return load_profile_text(text, f"{name}.toml")


def test_a_read_only_parameter_answers_response_2(profiles: dict[str, Profile]) -> None:
    profile = _custom(profiles["jjr5000"], "custom5000", read_only="ramp_time")
    assert not profile.point("ramp_time").writable
    slave = SimulatedDpSlave(SimulatedStarter(profile), Ppo.PPO1)
    assert pkw(slave, 0x0201, 20) == (0x0201, 0)
    assert slave.answers[Refusal.READ_ONLY].response is ResponseCode.NO_WRITE_PERMISSION


def test_keyword_fallback_reproduces_the_jjr8000_table(profiles: dict[str, Profile]) -> None:
    custom = _custom(profiles["jjr8000"], "custom8000")
    assert refusal_answers(custom) == dict(REFUSAL_ANSWERS["jjr8000"])


def test_a_profile_can_state_its_refusal_answers(profiles: dict[str, Profile]) -> None:
    extra = 'refusals = { out_of_range = 7, read_only = "response 2", unsupported_task = 9 }\n'
    custom = _custom(profiles["jjr8000"], "custom8000b", extra=extra)
    answers = refusal_answers(custom)
    assert answers[Refusal.OUT_OF_RANGE] == PkwAnswer(ResponseCode.CANNOT_EXECUTE, 7)
    assert answers[UNSUPPORTED_TASK] == PkwAnswer(ResponseCode.CANNOT_EXECUTE, 9)
    assert answers[Refusal.READ_ONLY] == PkwAnswer(ResponseCode.NO_WRITE_PERMISSION)
    # a bad refusal table fails when the profile loads (the plugin's check_settings), naming the key
    with pytest.raises(ConfigurationError, match="refusals.sometimes: unknown refusal"):
        _custom(profiles["jjr8000"], "custom8000c", extra="refusals = { sometimes = 1 }\n")
    with pytest.raises(ConfigurationError, match="refusals.read_only: 'maybe' is not an error number"):
        _custom(profiles["jjr8000"], "custom8000d", extra='refusals = { read_only = "maybe" }\n')
