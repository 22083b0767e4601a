"""Device URLs: ``SCHEME://HOST:PORT/PATH?key=value``, where the scheme is a transport's entry-point name.

A scheme may carry a variant after ``+`` (``modbus-rtu+tcp``, ``profibus-pkw+gateway``); the part before the
``+`` selects the plugin, the variant is the plugin's business. Query values are read through typed getters
that name the URL and the parameter on error; unknown parameters are errors, not silently ignored.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from urllib.parse import parse_qsl, unquote, urlsplit

from starterbus.core.errors import ConfigurationError


@dataclass(frozen=True, slots=True)
class DeviceUrl:
    text: str
    scheme: str
    transport: str
    variant: str
    host: str
    port: int | None
    path: str
    query: Mapping[str, str]

    @classmethod
    def parse(cls, text: str) -> DeviceUrl:
        if "://" not in text:
            raise ConfigurationError(
                f"{text!r} is not a device URL (expected TRANSPORT://WHERE?PARAM=VALUE; "
                "`starterbus transports` lists the transports and their URL forms)"
            )
        try:
            parts = urlsplit(text)
            host = parts.hostname or ""
        except ValueError as exc:  # bad IPv6 brackets, characters that NFKC-normalise into URL syntax
            raise ConfigurationError(f"{text!r}: invalid host: {exc}") from None
        try:
            port = parts.port
        except ValueError:
            raise ConfigurationError(f"{text!r}: invalid port (0-65535)") from None
        scheme = parts.scheme.lower()
        if not scheme:
            raise ConfigurationError(f"{text!r}: no transport before :// (`starterbus transports` lists them)")
        transport, _, variant = scheme.partition("+")
        pairs = parse_qsl(parts.query, keep_blank_values=True, strict_parsing=False)
        query: dict[str, str] = {}
        for key, value in pairs:
            if key in query:
                raise ConfigurationError(f"{text}: parameter {key!r} given twice")
            query[key] = value
        return cls(
            text=text,
            scheme=scheme,
            transport=transport,
            variant=variant,
            host=host,
            port=port,
            path=unquote(parts.path),
            query=query,
        )

    def _fail(self, name: str, message: str) -> ConfigurationError:
        return ConfigurationError(f"{self.text}: {name}: {message}")

    def check_known(self, names: Iterable[str]) -> None:
        allowed = set(names)
        unknown = sorted(set(self.query) - allowed)
        if unknown:
            raise self._fail(", ".join(unknown), f"unknown URL parameter (known: {', '.join(sorted(allowed))})")

    def get_str(self, name: str, default: str | None = None, choices: Iterable[str] | None = None) -> str:
        value = self.query.get(name, default)
        if value is None:
            raise self._fail(name, "required URL parameter missing")
        if choices is not None:
            options = list(choices)
            if value not in options:
                raise self._fail(name, f"{value!r} is not one of {', '.join(options)}")
        return value

    def get_int(self, name: str, default: int | None = None, lo: int | None = None, hi: int | None = None) -> int:
        text = self.query.get(name)
        if text is None:
            if default is None:
                raise self._fail(name, "required URL parameter missing")
            return default
        try:
            value = int(text, 0)
        except ValueError:
            raise self._fail(name, f"{text!r} is not an integer") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self._fail(name, f"{value} is outside {lo}..{hi}")
        return value

    def get_float(self, name: str, default: float, lo: float | None = None, hi: float | None = None) -> float:
        text = self.query.get(name)
        if text is None:
            return default
        try:
            value = float(text)
        except ValueError:
            raise self._fail(name, f"{text!r} is not a number") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self._fail(name, f"{value} is outside {lo}..{hi}")
        return value

    def get_bool(self, name: str, default: bool) -> bool:
        text = self.query.get(name)
        if text is None:
            return default
        lowered = text.lower()
        if lowered in ("1", "true", "yes", "on"):
            return True
        if lowered in ("0", "false", "no", "off"):
            return False
        raise self._fail(name, f"{text!r} is not a boolean (1/0, true/false)")

    def host_port(self, default_port: int | None = None) -> tuple[str, int]:
        if not self.host:
            raise self._fail("host", "this URL needs HOST:PORT")
        port = self.port if self.port is not None else default_port
        if port is None:
            raise self._fail("port", "this URL needs HOST:PORT")
        return self.host, port

    def __str__(self) -> str:
        return self.text
