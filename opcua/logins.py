"""OPC UA logins that cannot be abused: checked off the event loop, throttled, the same work for every user name.

asyncua asks the user manager synchronously inside ActivateSession (on the event loop). The server's message
processor (:mod:`starterbus.opcua.processor`) therefore calls :meth:`LoginGuard.precheck` first, which decrypts the
user token and verifies the password in a worker thread (one at a time: one core at most, whatever the flood) and
leaves the verdict in a context variable; asyncua's synchronous path then only reads it (:meth:`LoginGuard.decide`,
from the user manager). An unknown user name costs the same PBKDF2 (a dummy hash with the users' iterations), so
timing tells nothing. Failures are throttled per source address and per user name
(:mod:`starterbus.ops.throttle`); a refused login is answered no sooner than ``refusal_delay`` after it arrived
(costs no CPU, slows a client that loops).
Security events go to the ``starterbus.opcua.security`` logger; counts to :class:`LoginCollector`.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from asyncua.crypto.permission_rules import User, UserRole
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from starterbus.ops.throttle import Throttle, ThrottlePolicy
from starterbus.ops.users import PasswordCheck, UserEntry

security_log = logging.getLogger("starterbus.opcua.security")

#: outcomes of a login: accepted, or why it was refused
OUTCOMES = ("accepted", "wrong_password", "unknown_user", "backoff", "locked", "busy")


@dataclass(frozen=True)
class LoginPolicy:
    throttle: ThrottlePolicy = field(default_factory=ThrottlePolicy)
    refusal_delay: float = 1.0  # a refused login is answered no sooner than this after it arrived
    max_pending: int = 8  # logins waiting for the worker thread at most; more are refused ("busy")


@dataclass(frozen=True, slots=True)
class Precheck:
    """The verdict on one ActivateSession's user token, reached before asyncua's synchronous path runs."""

    username: str
    password: str | None  # None: refused unchecked (throttled, busy)
    user: User | None  # None: refused
    outcome: str  # one of OUTCOMES
    address: str
    arrived: float


#: the verdict of the ActivateSession being served in this task (set by the processor, read by the user manager)
PRECHECK: contextvars.ContextVar[Precheck | None] = contextvars.ContextVar("starterbus_opcua_login", default=None)

Decrypt = Callable[[], tuple[str, str]]


class LoginGuard:
    def __init__(
        self,
        users: Mapping[str, UserEntry],
        policy: LoginPolicy | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.users = dict(users)
        self.policy = policy or LoginPolicy()
        self.clock = clock
        self.throttle = Throttle(self.policy.throttle, clock)
        self.outcomes: Counter[str] = Counter()
        self.lockouts = 0
        self.checked_off_loop = 0  # verifications in the worker thread
        self.checked_on_loop = 0  # verifications asyncua asked for without a precheck (should stay 0)
        self._pending = 0
        self._executor: ThreadPoolExecutor | None = None
        self._check = PasswordCheck(self.users)

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    # -- before asyncua's synchronous path (on the loop, the hashing in the worker) -------------------------------

    async def precheck(self, address: str, username: str, decrypt: Decrypt) -> Precheck:
        """The verdict for a user-name token; ``decrypt`` (run in the worker) returns (name, password)."""
        arrived = self.clock()
        block = self.throttle.blocked(_keys(address, username))
        if block is not None:
            return Precheck(username, None, None, "locked" if block.locked else "backoff", address, arrived)
        if self._pending >= self.policy.max_pending:
            return Precheck(username, None, None, "busy", address, arrived)
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="opcua-login")
        self._pending += 1
        try:
            loop = asyncio.get_running_loop()
            name, password, user = await loop.run_in_executor(self._executor, self._decrypt_and_verify, decrypt)
        finally:
            self._pending -= 1
        self.checked_off_loop += 1
        return Precheck(name, password, user, _outcome(user, name in self.users), address, arrived)

    def _decrypt_and_verify(self, decrypt: Decrypt) -> tuple[str, str, User | None]:
        name, password = decrypt()
        return name, password, self._verify(name, password)

    def _verify(self, name: str, password: str | None) -> User | None:
        entry = self._check.verify(name, password)
        if entry is None:
            return None
        return User(role=UserRole.User, name=entry.name)  # never Admin: asyncua lets an Admin write past AccessLevel

    async def tarpit(self, check: Precheck) -> None:
        """Hold a refusal until ``refusal_delay`` after the attempt arrived."""
        if check.user is None:
            await asyncio.sleep(max(0.0, check.arrived + self.policy.refusal_delay - self.clock()))

    # -- inside asyncua's synchronous ActivateSession (from the user manager) -------------------------------------

    def decide(self, username: str, password: str | None) -> User | None:
        """The user for this ActivateSession: the precheck's verdict, recorded (counted, throttled, logged)."""
        check = PRECHECK.get()
        if check is None or check.username != username or (check.password not in (None, password)):
            # not prechecked (an asyncua that no longer goes through our processor): correct, but on the loop
            if self.checked_on_loop == 0:
                security_log.warning("OPC UA login checked on the event loop: the login processor was bypassed")
            self.checked_on_loop += 1
            user = self._verify(username, password)
            check = Precheck(username, password, user, _outcome(user, username in self.users), "?", self.clock())
        self._record(check)
        return check.user

    def _record(self, check: Precheck) -> None:
        self.outcomes[check.outcome] += 1
        keys = _keys(check.address, check.username)
        who = f"user {check.username!r} from {check.address}"
        if check.user is not None:
            self.throttle.succeeded(keys)
            security_log.info("OPC UA login accepted: %s", who)
            return
        if check.password is None:  # refused unchecked: counted; logged when the key was locked or backing off
            security_log.info("OPC UA login refused unchecked (%s): %s", check.outcome, who)
            return
        failures = self.throttle.failed(keys)
        worst = max(failures, key=lambda f: (f.locked, f.seconds))
        reason = "unknown user" if check.outcome == "unknown_user" else "wrong password"
        security_log.warning(
            "OPC UA login refused: %s: %s (%d in a row on %s; refused unchecked for %.0f s)",
            who, reason, worst.failures, worst.key, worst.seconds,
        )  # fmt: skip
        for failure in failures:
            if failure.locked and failure.failures == self.throttle.policy.lockout_after:
                self.lockouts += 1
                security_log.warning(
                    "OPC UA logins locked out for %s: %d failures in a row; locked for %.0f s",
                    failure.key, failure.failures, failure.seconds,
                )  # fmt: skip


def _keys(address: str, username: str) -> tuple[str, ...]:
    return (f"address {address}", f"user {username!r}") if address != "?" else (f"user {username!r}",)


def _outcome(user: User | None, known: bool) -> str:
    if user is not None:
        return "accepted"
    return "wrong_password" if known else "unknown_user"


class LoginCollector(Collector):
    """Prometheus series of the OPC UA logins; ``source()`` gives the guard (None before the server started)."""

    def __init__(self, source: Callable[[], LoginGuard | None]) -> None:
        self.source = source

    def collect(self) -> Iterator[Metric]:
        guard = self.source()
        if guard is None:
            return
        logins = CounterMetricFamily(
            "starterbus_opcua_logins", "OPC UA logins by outcome (accepted, or why refused)", labels=["outcome"]
        )
        for outcome in OUTCOMES:
            logins.add_metric([outcome], float(guard.outcomes[outcome]))
        yield logins
        yield CounterMetricFamily(
            "starterbus_opcua_login_lockouts", "source addresses and user names locked out", value=float(guard.lockouts)
        )
        yield GaugeMetricFamily(
            "starterbus_opcua_login_locked_keys",
            "source addresses and user names locked out now",
            value=float(guard.throttle.locked_keys()),
        )
