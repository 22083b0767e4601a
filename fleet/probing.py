"""How an offline device is probed without starving the live devices on its line.

An offline device costs its line only probes: one attempt (no retries) with a short timeout
(:meth:`Transport.probe_policy <starterbus.core.transport.Transport.probe_policy>`), spread out by exponential
backoff with jitter (so that devices that went offline together do not probe in step), and all probes of a
line together never take more than a bounded share of its time (:class:`ProbeBudget`, a token bucket
refilled with line time). Pure: times are passed in, randomness is an injected ``random.Random``.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

#: a probe waits at most this long for an answer unless the device was seen answering slower
DEFAULT_PROBE_TIMEOUT = 0.1
#: the share of a line's time that probes of offline devices may take, all together
DEFAULT_PROBE_SHARE = 0.1
#: a backoff is drawn uniformly from [1 - JITTER, 1] times its nominal value
JITTER = 0.25
#: a probe's timeout is at least this many times the slowest request time the device showed while online
SLOW_ANSWER_MARGIN = 3.0


@dataclass(frozen=True, slots=True)
class ProbeSettings:
    """``timeout``: a probe's answer timeout (None: probe with the transport's own policy, retries included,
    which is the behaviour before probes existed); ``share``: the bound on the line's time spent probing."""

    timeout: float | None = DEFAULT_PROBE_TIMEOUT
    share: float = DEFAULT_PROBE_SHARE

    def __post_init__(self) -> None:
        if self.timeout is not None and self.timeout <= 0:
            raise ValueError(f"probe timeout {self.timeout!r} must be positive")
        if not 0 < self.share <= 1:
            raise ValueError(f"probe share {self.share!r} must be in (0, 1]")

    def timeout_for(self, slowest_request: float) -> float | None:
        """The probe timeout for a device whose slowest request while online took ``slowest_request`` s."""
        if self.timeout is None:
            return None
        return max(self.timeout, SLOW_ANSWER_MARGIN * slowest_request)


def backoff(failures: int, period: float, max_backoff: float, rng: random.Random) -> float:
    """Seconds until the next probe after ``failures`` failed polls in a row: period, 2x, 4x ... up to
    ``max_backoff``, each drawn from the last ``JITTER`` of its value."""
    nominal = min(period * 2.0 ** max(0, failures - 1), max_backoff)
    return nominal * rng.uniform(1.0 - JITTER, 1.0)


class ProbeBudget:
    """A token bucket of line time: probes spend what they took, the bucket refills at ``share`` s per second.

    A probe may start while the bucket is not empty, so it can go into debt by one probe at most; the next one
    then waits until the debt is paid back. Over any window of ``T`` seconds probes take at most
    ``share x T + burst + one probe``.
    """

    def __init__(self, share: float, burst: float, now: float) -> None:
        self.share = share
        self.burst = burst
        self.tokens = burst
        self.at = now
        self.spent = 0.0  # every probe's time so far, for statistics

    def _refill(self, now: float) -> None:
        if now > self.at:
            self.tokens = min(self.burst, self.tokens + (now - self.at) * self.share)
            self.at = now

    def wait(self, now: float) -> float:
        """Seconds until a probe may start; 0 when it may start now."""
        self._refill(now)
        return 0.0 if self.tokens > 0 else -self.tokens / self.share + 1e-9

    def spend(self, seconds: float, now: float) -> None:
        self._refill(now)
        self.tokens -= seconds
        self.spent += seconds
