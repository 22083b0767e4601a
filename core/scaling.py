"""Raw words to engineering values: ``raw`` x the scale, rounded to the scale's decimal places.

A poll scales every value it reads, and rounding a float to some places (``round(x, n)``) is slow, while the
words a device answers repeat: the values met so far are kept, per scale and raw word, and looked up.
"""

from __future__ import annotations

import functools
import math

__all__ = ["decimals", "engineering"]

#: values kept per scale (emptied when full), and scales kept (a handful: a profile has a few)
VALUES_KEPT = 4096
SCALES_KEPT = 64


@functools.lru_cache(maxsize=64)
def decimals(step: float) -> int:
    """Decimal places of a step such as 0.1 (1) or 0.01 (2); 0 for a step of 1 or more."""
    return max(0, round(-math.log10(step))) if 0 < step < 1 else 0


class _Scaled(dict[int, float]):
    """One scale's engineering values met so far, by raw word."""

    __slots__ = ("factor", "places")

    def __init__(self, factor: float) -> None:
        super().__init__()
        self.factor = factor
        self.places = decimals(factor)

    def __missing__(self, raw: int) -> float:
        if len(self) >= VALUES_KEPT:
            self.clear()
        value = self[raw] = round(raw * self.factor, self.places)
        return value


class _Scales(dict[float, _Scaled]):
    def __missing__(self, factor: float) -> _Scaled:
        if len(self) >= SCALES_KEPT:
            self.clear()
        table = self[factor] = _Scaled(factor)
        return table


#: scale -> its values met so far (``SCALED[factor][raw]``: the engineering value of ``raw``, for a factor not 1)
SCALED = _Scales()


def engineering(raw: int, factor: float) -> float | int:
    """``raw`` x ``factor``, rounded to the factor's decimal places (``raw`` itself for a factor of 1)."""
    return raw if factor == 1 else SCALED[factor][raw]
