"""The device's own fault history decoded with the profile's fault table.

A point holds a fault code when the profile gives it the ``last_fault_code`` role, or its key names an older
entry of the same history (``fault_2_code`` .. ``fault_N_code``, JJR8000 appendix 2). Such a value reads as
``6: motor overload`` wherever it is shown (reads, backups, history), like the status word's fault code.
"""

from __future__ import annotations

import re

from starterbus.core.model import PointDef, Value
from starterbus.core.profile import Profile

_HISTORY_KEY = re.compile(r"(?:last_)?fault(?:_\d+)?_code")


def is_fault_code(profile: Profile, point: PointDef) -> bool:
    """Whether ``point`` holds a code of the profile's fault table (not an enum, not a bit field)."""
    if point.enum is not None or point.bits:
        return False
    return profile.roles.get("last_fault_code") == point.key or bool(_HISTORY_KEY.fullmatch(point.key))


def fault_text(profile: Profile, code: int) -> str:
    """``6: motor overload``; 0 is an empty history slot."""
    if code == 0:
        return "0: no fault recorded"
    return f"{code}: {profile.faults.text(code)}"


def value_text(profile: Profile, value: Value) -> str:
    """The human form of a value, fault codes decoded with the profile's fault table."""
    if is_fault_code(profile, value.point):
        return fault_text(profile, value.raw)
    return value.text()
