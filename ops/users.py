"""The users file shared by the OPC UA server and the web dashboard: roles and PBKDF2 password hashes.

```toml
# starterbus users (add or change one with `starterbus opcua-user USERS.toml NAME --role ROLE`)
[users.alice]
role = "operator"      # operator: read, write enabled parameters, start/stop/reset (OPC UA methods, web)
password = "pbkdf2-sha256$600000$<salt, base64>$<hash, base64>"

[users.scada]
role = "read-only"     # read, browse and subscribe only
password = "pbkdf2-sha256$..."
```

Passwords are never stored or passed in clear. A check costs about 0.1 s of PBKDF2 at the default 600,000
iterations: servers verify in a worker thread, never on their event loop.
"""

from __future__ import annotations

import base64
import enum
import hashlib
import hmac
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError
from starterbus.core.textinput import read_text_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCHEME = "pbkdf2-sha256"
DEFAULT_ITERATIONS = 600_000  # OWASP 2023 for PBKDF2-HMAC-SHA256


class Role(str, enum.Enum):
    READ_ONLY = "read-only"
    OPERATOR = "operator"


@dataclass(frozen=True, slots=True)
class UserEntry:
    name: str
    role: Role
    password_hash: str


def hash_password(password: str, *, iterations: int = DEFAULT_ITERATIONS, salt: bytes | None = None) -> str:
    """``pbkdf2-sha256$ITERATIONS$SALT$HASH`` (base64, no padding) for a users file."""
    salt = os.urandom(16) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    return f"{SCHEME}${iterations}${_b64(salt)}${_b64(digest)}"


def verify_password(password: str, encoded: str) -> bool:
    try:
        scheme, iterations, salt, digest = encoded.split("$")
        if scheme != SCHEME:
            return False
        expected = base64.b64decode(_pad(digest))
        actual = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), base64.b64decode(_pad(salt)), int(iterations))
    except ValueError:
        return False
    return hmac.compare_digest(actual, expected)


class PasswordCheck:
    """The users' passwords, checked with the same work for an unknown name (a dummy hash at the users' highest
    iteration count), so the time a refusal takes does not tell which names exist. Blocking: call it off the
    event loop."""

    def __init__(self, users: Mapping[str, UserEntry]) -> None:
        self.users = dict(users)
        iterations = [_iterations(u.password_hash) for u in self.users.values()]
        self._dummy = hash_password("not a password of anybody", iterations=max(iterations, default=DEFAULT_ITERATIONS))

    def verify(self, name: str, password: str | None) -> UserEntry | None:
        """The user ``name`` if ``password`` is theirs, else None."""
        entry = self.users.get(name)
        ok = verify_password(password or "", entry.password_hash if entry is not None else self._dummy)
        return entry if ok and entry is not None and password is not None else None


def _iterations(encoded: str) -> int:
    try:
        return int(encoded.split("$")[1])
    except (IndexError, ValueError):
        return DEFAULT_ITERATIONS


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii").rstrip("=")


def _pad(text: str) -> str:
    return text + "=" * (-len(text) % 4)


def load_users(path: str | Path) -> dict[str, UserEntry]:
    """Read a users file; errors name the file and the user."""
    path = Path(path)
    try:
        data = tomllib.loads(read_text_file(path, "users file"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigurationError(f"{path}: {exc}") from exc
    return parse_users(data, str(path))


def parse_users(data: Mapping[str, Any], source: str) -> dict[str, UserEntry]:
    unknown = set(data) - {"users"}
    if unknown:
        raise ConfigurationError(f"{source}: unknown setting {sorted(unknown)[0]!r} (only [users.NAME] tables)")
    table = data.get("users", {})
    if not isinstance(table, Mapping):
        raise ConfigurationError(f"{source}: users must be tables [users.NAME]")
    users: dict[str, UserEntry] = {}
    roles = ", ".join(r.value for r in Role)
    for name, entry in table.items():
        where = f"{source}: users.{name}"
        if not isinstance(entry, Mapping):
            raise ConfigurationError(f"{where}: must be a table with role and password")
        for key in sorted(set(entry) - {"role", "password"}):
            raise ConfigurationError(f"{where}.{key}: unknown setting (known: password, role)")
        try:
            role = Role(entry.get("role"))
        except ValueError:
            raise ConfigurationError(f"{where}.role: {entry.get('role')!r} is not one of {roles}") from None
        encoded = entry.get("password")
        if not isinstance(encoded, str) or not encoded.startswith(SCHEME + "$") or encoded.count("$") != 3:
            raise ConfigurationError(
                f"{where}.password: not a {SCHEME} hash (set it with `starterbus opcua-user FILE {name}`; "
                "clear-text passwords are not accepted)"
            )
        users[name] = UserEntry(name, role, encoded)
    return users


def dump_users(users: Mapping[str, UserEntry]) -> str:
    lines = ["# starterbus OPC UA users (`starterbus opcua-user FILE NAME --role ROLE` adds or changes one)"]
    for entry in users.values():
        lines += ["", f"[users.{_toml_key(entry.name)}]", f'role = "{entry.role.value}"']
        lines.append(f'password = "{entry.password_hash}"')
    return "\n".join(lines) + "\n"


def _toml_key(name: str) -> str:
    if name.replace("-", "").replace("_", "").isalnum() and name.isascii():
        return name
    return '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'
