"""What ``serve --http`` was asked for: the address, the operators, TLS, the history the pages read."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from starterbus.core.errors import ConfigurationError
from starterbus.ops.users import UserEntry
from starterbus.web.auth import AuthPolicy


@dataclass(frozen=True)
class WebSettings:
    host: str = "127.0.0.1"
    port: int = 8080
    users: Mapping[str, UserEntry] = field(default_factory=dict)
    cert: str | None = None  # TLS certificate chain (PEM) and its key
    key: str | None = None
    allow_plaintext_commands: bool = False  # logins and actions without TLS (a trial on a trusted network)
    behind_proxy: bool = False  # trust X-Forwarded-Proto from a reverse proxy on this host (loopback)
    history: Path | None = None  # the history database the device pages read (serve --record)
    interval: float = 0.5  # how often changed rows go to the pages, s
    logins: AuthPolicy = field(default_factory=AuthPolicy)  # throttling, refusal delay, session lifetimes

    def check(self) -> None:
        if bool(self.cert) != bool(self.key):
            raise ConfigurationError("--http-cert and --http-key go together (a certificate chain and its key)")
        for path in (self.cert, self.key):
            if path and not Path(path).is_file():
                raise ConfigurationError(f"{path}: no such file (--http-cert/--http-key)")

    @property
    def tls(self) -> bool:
        return bool(self.cert)
