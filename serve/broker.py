"""Where and how to reach the broker: the URL, TLS files, and credentials from the environment or a file.

Credentials never come from argv (other users see it in ``ps``) and are never logged: ``describe()`` shows the
broker without them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from starterbus.core.errors import ConfigurationError
from starterbus.core.textinput import read_text_file

USERNAME_ENV = "STARTERBUS_MQTT_USERNAME"
PASSWORD_ENV = "STARTERBUS_MQTT_PASSWORD"


@dataclass(frozen=True, slots=True)
class BrokerOptions:
    host: str
    port: int
    tls: bool = False
    ca_file: str | None = None
    cert_file: str | None = None
    key_file: str | None = None
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    client_id: str = ""
    keepalive: int = 10

    def describe(self) -> str:
        scheme = "mqtts" if self.tls else "mqtt"
        user = f"{self.username}@" if self.username else ""
        return f"{scheme}://{user}{self.host}:{self.port}"


def parse_broker_url(url: str) -> tuple[str, int, bool]:
    """``mqtt://HOST[:PORT]`` (1883) or ``mqtts://HOST[:PORT]`` (8883)."""
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
        raise ConfigurationError(f"broker URL {url!r}: expected mqtt://HOST[:PORT] or mqtts://HOST[:PORT]")
    if parts.username or parts.password:
        raise ConfigurationError(
            f"broker URL: put no credentials in the URL (argv is visible to every user); use ${USERNAME_ENV}/"
            f"${PASSWORD_ENV} or --credentials FILE"
        )
    tls = parts.scheme == "mqtts"
    try:
        port = parts.port or (8883 if tls else 1883)
    except ValueError:
        raise ConfigurationError(f"broker URL {url!r}: bad port") from None
    return parts.hostname, port, tls


def load_credentials(path: str | None) -> tuple[str | None, str | None]:
    """From a file (first line the user name, second the password), else from the environment."""
    if path is not None:
        lines = read_text_file(path, "credentials file").splitlines()
        if not lines or not lines[0].strip():
            raise ConfigurationError(f"credentials file {path}: first line must be the user name")
        return lines[0].strip(), (lines[1] if len(lines) > 1 else None)
    return os.environ.get(USERNAME_ENV) or None, os.environ.get(PASSWORD_ENV) or None
