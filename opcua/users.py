"""OPC UA users: the user manager and the role rules over the users file (:mod:`starterbus.ops.users`).

```toml
# starterbus OPC UA users (add or change one with `starterbus opcua-user USERS.toml NAME --role ROLE`)
[users.alice]
role = "operator"      # operator: read, subscribe, write enabled parameters, call Start/Stop/Reset
password = "pbkdf2-sha256$200000$<salt, base64>$<hash, base64>"

[users.scada]
role = "read-only"     # read, browse and subscribe only
password = "pbkdf2-sha256$..."
```

Passwords are never stored or passed in clear. asyncua asks the user manager synchronously on the event loop;
the server's :class:`~starterbus.opcua.logins.LoginGuard` has verified the password in a worker thread by then
(about 0.1 s of PBKDF2 at the default 600,000 iterations), so the user manager only reads its verdict.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from asyncua import ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole

from starterbus.ops.users import (
    DEFAULT_ITERATIONS,
    SCHEME,
    Role,
    UserEntry,
    dump_users,
    hash_password,
    load_users,
    parse_users,
    verify_password,
)

if TYPE_CHECKING:
    from starterbus.opcua.logins import LoginGuard


class UserManager:
    """asyncua's user manager: users of the file by password; anonymous (read-only) only when enabled.

    With a ``guard`` (the server's), the password was verified off the loop and throttled before asyncua asks;
    without one, :meth:`get_user` verifies here, synchronously.
    """

    def __init__(
        self, users: Mapping[str, UserEntry], *, anonymous: bool = False, guard: LoginGuard | None = None
    ) -> None:
        self.users = dict(users)
        self.anonymous = anonymous
        self.guard = guard

    def get_user(
        self, iserver: object, username: str | None = None, password: str | None = None, certificate: object = None
    ) -> User | None:
        if username is None:
            return User(role=UserRole.Anonymous) if self.anonymous else None
        if self.guard is not None:
            return self.guard.decide(username, password)
        entry = self.users.get(username)
        if entry is None or password is None or not verify_password(password, entry.password_hash):
            return None
        # never UserRole.Admin: asyncua lets an Admin write past the AccessLevel
        return User(role=UserRole.User, name=entry.name)

    def role(self, user: User | None) -> Role | None:
        """The starterbus role of a session's user (None: anonymous)."""
        if user is None or user.name is None:
            return None
        entry = self.users.get(user.name)
        return entry.role if entry is not None else None


_READ_TYPES = {ua.NodeId(t) for t in USER_TYPES} - {
    ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary),
    ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary),
}
_OPERATOR_TYPES = {ua.NodeId(t) for t in USER_TYPES}


class RoleRuleset(PermissionRuleset):
    """Per-request rules: operators may write and call; read-only users and anonymous sessions may not.

    A refused request gets a ServiceFault with BadUserAccessDenied (asyncua checks before decoding the body).
    """

    def __init__(self, users: UserManager) -> None:
        self.users = users

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: object) -> bool:
        if user.role is UserRole.User and self.users.role(user) is Role.OPERATOR:
            return action_type_id in _OPERATOR_TYPES
        return action_type_id in _READ_TYPES


__all__ = [
    "DEFAULT_ITERATIONS",
    "SCHEME",
    "Role",
    "RoleRuleset",
    "UserEntry",
    "UserManager",
    "dump_users",
    "hash_password",
    "load_users",
    "parse_users",
    "verify_password",
]
