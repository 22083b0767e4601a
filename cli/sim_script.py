"""Rehearsal scripts for ``starterbus simulate --script FILE``: timed events on the simulated starters.

One event per line, ``AT UNIT ACTION [ARG]``; ``#`` starts a comment::

    2.0   2  fault 6      # at 2 s, unit 2 trips with fault 6 (motor overload)
    10    2  clear        # the fault condition goes away (a reset is still needed, as on the device)
    12    3  start        # a local start, as from the keypad
    20    3  stop
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from starterbus.core.errors import ConfigurationError
from starterbus.core.simulator import SimulatedStarter

ACTIONS = ("fault", "clear", "start", "stop")


@dataclass(frozen=True, slots=True)
class Event:
    at: float
    unit: int
    action: str
    code: int | None = None

    def apply(self, starters: Mapping[int, SimulatedStarter]) -> str:
        starter = starters[self.unit]
        if self.action == "fault" and self.code is not None:
            starter.inject_fault(self.code)
            return f"unit {self.unit}: fault {self.code} ({starter.profile.faults.text(self.code)})"
        if self.action == "clear":
            starter.fault_reset()
            return f"unit {self.unit}: fault cleared"
        if self.action == "start":
            starter.start("script")
            return f"unit {self.unit}: started"
        starter.soft_stop("script")
        return f"unit {self.unit}: soft stop"


def parse_script(text: str, source: str, units: set[int]) -> list[Event]:
    events = []
    for n, line in enumerate(text.splitlines(), 1):
        body = line.split("#", 1)[0].split()
        if not body:
            continue

        def fail(why: str, line: str = line, n: int = n) -> ConfigurationError:
            return ConfigurationError(f"{source}:{n}: {why}: {line.strip()!r}")

        if len(body) not in (3, 4):
            raise fail("expected AT UNIT ACTION [ARG]")
        try:
            at, unit = float(body[0]), int(body[1])
        except ValueError:
            raise fail("AT is seconds and UNIT a number") from None
        if not math.isfinite(at) or at < 0:
            raise fail("AT must be zero or more seconds")
        if unit not in units:
            raise fail(f"unit {unit} is not simulated (units: {', '.join(map(str, sorted(units)))})")
        action = body[2].lower()
        if action not in ACTIONS:
            raise fail(f"unknown action {body[2]!r} (one of {', '.join(ACTIONS)})")
        code = None
        if action == "fault":
            if len(body) != 4 or not body[3].isdigit():
                raise fail("fault needs a fault code")
            code = int(body[3])
        elif len(body) == 4:
            raise fail(f"{action} takes no argument")
        events.append(Event(at, unit, action, code))
    return sorted(events, key=lambda e: e.at)
