"""Value entry as a user types it: a number with its own unit (``350%``, ``30s``, ``3.5x``) and near-miss keys.

Units convert only inside one family (``%`` and ``x In`` are both ratios: 350 % = 3.5 x In; ``ms``, ``s``,
``min`` and ``h`` are times); anything else must match the point's unit exactly. Errors are
:class:`ValidationError` naming the point.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from starterbus.core.errors import ValidationError

#: unit family -> normalised unit -> factor to the family's base unit
_FAMILIES: dict[str, dict[str, float]] = {
    "ratio": {
        "%": 0.01,
        "%in": 0.01,
        "%ie": 0.01,
        "x": 1.0,
        "xin": 1.0,
        "xie": 1.0,
        "×": 1.0,
        "×in": 1.0,
        "×ie": 1.0,
        "倍": 1.0,
    },
    "time": {"ms": 0.001, "s": 1.0, "sec": 1.0, "秒": 1.0, "min": 60.0, "分": 60.0, "h": 3600.0, "小时": 3600.0},
    "current": {"ma": 0.001, "a": 1.0, "ka": 1000.0},
}
_NUMBER_RE = re.compile(r"([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(.*)", re.DOTALL)


def _norm(unit: str) -> str:
    return "".join(unit.split()).casefold()


def _family(unit: str) -> tuple[str, float] | None:
    norm = _norm(unit)
    for family, units in _FAMILIES.items():
        if norm in units:
            return family, units[norm]
    return None


def split_quantity(text: str) -> tuple[float, str] | None:
    """``"350 %"`` -> (350.0, "%"); ``"0x1F"`` -> (31.0, ""); None when the text does not start with a number."""
    cleaned = text.strip()
    if re.fullmatch(r"0[xX][0-9a-fA-F]+", cleaned):
        return float(int(cleaned, 16)), ""
    match = _NUMBER_RE.fullmatch(cleaned)
    if match is None:
        return None
    try:
        number = float(match.group(1))
    except ValueError:  # pragma: no cover - the pattern only matches float syntax
        return None
    return number, match.group(2).strip()


def convert_unit(number: float, unit: str, target: str, what: str) -> float:
    """``number`` in ``unit`` expressed in ``target`` (the point's unit); ValidationError when they differ in kind."""
    if not unit or _norm(unit) == _norm(target):
        return number
    if not target:
        raise ValidationError(f"{what}: has no unit, but {unit!r} was given")
    have, want = _family(unit), _family(target)
    if have is None or want is None or have[0] != want[0]:
        raise ValidationError(f"{what}: {number:g} {unit} is not in {target} (the unit of this point)")
    return number * have[1] / want[1]


def alternative_reading(number: float, target: str) -> tuple[float, str] | None:
    """For a bare number out of range on a ratio point: the same number read as % (or as x), for a hint."""
    fam = _family(target)
    if fam is None or fam[0] != "ratio":
        return None
    other = "%" if fam[1] == 1.0 else "x"
    return convert_unit(number, other, target, ""), other


def edit_distance(a: str, b: str) -> int:
    """Levenshtein distance (insert, delete, substitute: 1 each)."""
    previous = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        current = [i]
        for j, cb in enumerate(b, 1):
            current.append(min(previous[j] + 1, current[j - 1] + 1, previous[j - 1] + (ca != cb)))
        previous = current
    return previous[-1]


def nearest(word: str, candidates: Iterable[str], limit: int = 3) -> list[str]:
    """Up to ``limit`` candidates closest to ``word`` by edit distance (prefix matches first), close ones only."""
    wanted = word.strip().casefold()[:64]
    if not wanted:
        return []
    budget = max(2, len(wanted) // 3)
    scored: list[tuple[int, str]] = []
    for candidate in candidates:
        folded = candidate.casefold()
        if folded.startswith(wanted) and len(wanted) >= 3:
            scored.append((0, candidate))
            continue
        distance = edit_distance(wanted, folded[: len(wanted) + budget + 1])
        if distance <= budget:
            scored.append((distance, candidate))
    scored.sort()
    return [c for _, c in scored[:limit]]
