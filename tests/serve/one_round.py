"""A stand-in for the fleet in serve's socket tests: one sample of every device, then nothing until the stop."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.fleet.config import DeviceConfig
from starterbus.fleet.sample import Sample

PROFILE = get_profile("jjr5000")


class OneRound:
    """A stand-in for the fleet: one sample of every device, then nothing until the stop."""

    def __init__(self, configs: list[DeviceConfig]) -> None:
        self.configs = configs

    def subscribe(self) -> OneRound:
        return self

    def __aiter__(self) -> AsyncIterator[Sample]:
        return self._samples()

    async def _samples(self) -> AsyncIterator[Sample]:
        status = decode_status_word(0x2200, PROFILE.faults)
        point = PROFILE.point("phase_a_current")
        for c in self.configs:
            values = {point.key: Value.from_raw(point, 5)}
            yield Sample(c.name, "l1", "jjr5000", time.time(), True, status, values, None, 0)
        await asyncio.Event().wait()

    def drain(self) -> list[Sample]:
        return []

    def close(self) -> None:
        pass
