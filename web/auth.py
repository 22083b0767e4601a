"""Who may act on the web pages: operators of the users file (the OPC UA one), logged in by password.

Passwords are verified in one worker thread (PBKDF2, about 0.1 s; never on the event loop), with the same work
for an unknown user name (a dummy hash), throttled per source address and per user name
(:mod:`starterbus.ops.throttle`), and a refusal is answered no sooner than ``refusal_delay`` after it arrived.
A login gives a random session id (the cookie: HttpOnly, SameSite=Strict, Secure under TLS) and a CSRF token
that every state-changing request must carry in the ``X-CSRF-Token`` header. Sessions live in memory: a
restart logs everybody out.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import secrets
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from starterbus.ops.throttle import Throttle, ThrottlePolicy
from starterbus.ops.users import PasswordCheck, Role, UserEntry

security_log = logging.getLogger("starterbus.web.security")

COOKIE = "starterbus_session"


@dataclass(frozen=True)
class AuthPolicy:
    throttle: ThrottlePolicy = field(default_factory=ThrottlePolicy)
    refusal_delay: float = 1.0  # a refused login is answered no sooner than this after it arrived
    max_pending: int = 8  # logins waiting for the worker thread at most; more are refused
    session_seconds: float = 8 * 3600.0  # a session ends this long after the login
    idle_seconds: float = 3600.0  # ... or after this long without a request


@dataclass
class Session:
    id: str
    user: str
    role: Role
    csrf: str
    created: float
    seen: float

    @property
    def operator(self) -> bool:
        return self.role is Role.OPERATOR


class LoginRefused(Exception):
    """A login that did not succeed; the reason is for the log, never for the client."""


class Auth:
    def __init__(
        self,
        users: Mapping[str, UserEntry],
        policy: AuthPolicy | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.users = dict(users)
        self.policy = policy or AuthPolicy()
        self.clock = clock
        self.throttle = Throttle(self.policy.throttle, clock)
        self.sessions: dict[str, Session] = {}
        self._pending = 0
        self._executor: ThreadPoolExecutor | None = None
        self._check = PasswordCheck(self.users)

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    async def login(self, address: str, username: str, password: str) -> Session:
        """A new session for a right password; :class:`LoginRefused` otherwise (after ``refusal_delay``)."""
        arrived = self.clock()
        keys = (f"address {address}", f"user {username!r}")
        try:
            block = self.throttle.blocked(keys)
            if block is not None:
                raise LoginRefused(f"{'locked' if block.locked else 'backing off'} ({block.key})")
            if self._pending >= self.policy.max_pending:
                raise LoginRefused("busy")
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="web-login")
            self._pending += 1
            try:
                ok = await asyncio.get_running_loop().run_in_executor(self._executor, self._verify, username, password)
            finally:
                self._pending -= 1
            if not ok:
                failures = self.throttle.failed(keys)
                worst = max(failures, key=lambda f: (f.locked, f.seconds))
                raise LoginRefused(
                    f"{'unknown user' if username not in self.users else 'wrong password'} "
                    f"({worst.failures} in a row on {worst.key}; refused unchecked for {worst.seconds:.0f} s)"
                )
        except LoginRefused as exc:
            security_log.warning("web login refused: user %r from %s: %s", username, address, exc)
            await asyncio.sleep(max(0.0, arrived + self.policy.refusal_delay - self.clock()))
            raise
        self.throttle.succeeded(keys)
        entry = self.users[username]
        now = self.clock()
        session = Session(secrets.token_urlsafe(32), username, entry.role, secrets.token_urlsafe(32), now, now)
        self.sessions[session.id] = session
        security_log.info("web login accepted: user %r from %s (%s)", username, address, entry.role.value)
        return session

    def _verify(self, username: str, password: str) -> bool:  # the worker thread
        return self._check.verify(username, password) is not None

    def session(self, session_id: str | None) -> Session | None:
        """The live session of a cookie (None: no cookie, unknown, or expired)."""
        if not session_id:
            return None
        session = self.sessions.get(session_id)
        if session is None:
            return None
        now = self.clock()
        policy = self.policy
        if now - session.created > policy.session_seconds or now - session.seen > policy.idle_seconds:
            del self.sessions[session_id]
            return None
        session.seen = now
        return session

    def logout(self, session_id: str | None) -> None:
        if session_id:
            self.sessions.pop(session_id, None)

    @staticmethod
    def csrf_ok(session: Session, token: str | None) -> bool:
        return token is not None and hmac.compare_digest(session.csrf.encode(), token.encode())
