"""The one time form of everything starterbus prints as JSON or writes to a file: ISO 8601 in UTC with
milliseconds and the zone, ``2026-11-26T14:33:11.123+00:00``.

UTC so that logs sort as text and compare across sites and daylight-saving changes; the zone is always written,
so no reader has to guess. Tables for people show local time; the wire keeps what its protocol requires
(Sparkplug: ms since the epoch; OPC UA: DateTime).
"""

from __future__ import annotations

import time
from datetime import datetime, timezone


def iso_time(epoch: float | None = None) -> str:
    """``epoch`` (seconds since 1970, default now) as ``2026-11-26T14:33:11.123+00:00``."""
    when = time.time() if epoch is None else epoch
    return datetime.fromtimestamp(when, timezone.utc).isoformat(timespec="milliseconds")


def parse_iso_time(text: str) -> float:
    """Seconds since the epoch of an ISO 8601 time with its zone: this module's form, and the forms earlier
    versions wrote (``...Z``, ``+0000``). A time without a zone is local time. Raises ``ValueError``."""
    text = text.strip()
    if text.endswith(("Z", "z")):
        text = text[:-1] + "+00:00"
    elif len(text) > 5 and text[-5] in "+-" and text[-4:].isdigit() and "T" in text:
        text = f"{text[:-2]}:{text[-2:]}"  # +0100 -> +01:00 (Python 3.10's fromisoformat wants the colon)
    return datetime.fromisoformat(text).timestamp()


__all__ = ["iso_time", "parse_iso_time"]
