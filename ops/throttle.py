"""Failed-login throttling per key (an address, a user name): exponential backoff, then a lockout (OPC UA, web).

After the n-th failure in a row on a key, attempts on that key are refused unchecked for
``min(backoff_base * 2**(n-1), backoff_max)`` seconds; the ``lockout_after``-th failure locks the key for
``lockout_seconds``. A success clears the key; failures older than ``forget_after`` are forgotten. Pure state with an
injected clock, used on the event loop only (no locks).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ThrottlePolicy:
    backoff_base: float = 1.0  # seconds refused after the first failure; doubled after each further one
    backoff_max: float = 60.0
    lockout_after: int = 10  # failures in a row on one key before it is locked
    lockout_seconds: float = 900.0
    forget_after: float = 900.0  # a key without a failure for this long starts again from zero
    max_keys: int = 10_000  # keys remembered at most (the oldest are forgotten first)


@dataclass(slots=True)
class _KeyState:
    failures: int = 0
    last_failure: float = 0.0
    blocked_until: float = 0.0
    locked: bool = False


@dataclass(frozen=True, slots=True)
class Block:
    """Why a login is refused unchecked: the key, ``locked`` (else backing off) and the seconds left."""

    key: str
    locked: bool
    seconds: float


@dataclass(frozen=True, slots=True)
class Failure:
    """A failure's consequence for one key: failures in a row, the seconds it is now refused, locked or not."""

    key: str
    failures: int
    seconds: float
    locked: bool


class Throttle:
    def __init__(self, policy: ThrottlePolicy | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.policy = policy or ThrottlePolicy()
        self.clock = clock
        self._keys: dict[str, _KeyState] = {}

    def blocked(self, keys: Iterable[str]) -> Block | None:
        """The longest block among ``keys`` (a lockout before a backoff), or None when an attempt may be checked."""
        now = self.clock()
        worst: Block | None = None
        for key in keys:
            state = self._keys.get(key)
            if state is None or state.blocked_until <= now:
                continue
            block = Block(key, state.locked, state.blocked_until - now)
            if worst is None or (block.locked, block.seconds) > (worst.locked, worst.seconds):
                worst = block
        return worst

    def failed(self, keys: Iterable[str]) -> list[Failure]:
        now = self.clock()
        policy = self.policy
        out = []
        for key in keys:
            state = self._keys.pop(key, None) or _KeyState()
            if now - state.last_failure > policy.forget_after or (state.locked and state.blocked_until <= now):
                state = _KeyState()  # forgotten, or a lockout served: start again
            state.failures += 1
            state.last_failure = now
            if state.failures >= policy.lockout_after:
                state.locked, seconds = True, policy.lockout_seconds
            else:
                seconds = min(policy.backoff_base * 2 ** (state.failures - 1), policy.backoff_max)
            state.blocked_until = now + seconds
            self._keys[key] = state  # re-inserted: the dict's order is the age of the last failure
            out.append(Failure(key, state.failures, seconds, state.locked))
        self._trim(now)
        return out

    def succeeded(self, keys: Iterable[str]) -> None:
        for key in keys:
            self._keys.pop(key, None)

    def locked_keys(self) -> int:
        now = self.clock()
        return sum(1 for s in self._keys.values() if s.locked and s.blocked_until > now)

    def _trim(self, now: float) -> None:
        if len(self._keys) <= self.policy.max_keys:
            return
        for key, state in list(self._keys.items()):
            if state.blocked_until <= now and now - state.last_failure > self.policy.forget_after:
                del self._keys[key]
        while len(self._keys) > self.policy.max_keys:
            del self._keys[next(iter(self._keys))]
