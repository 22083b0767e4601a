"""Device URL -> typed settings of a Modbus RTU device.

``modbus-rtu:///dev/ttyUSB0?unit=2&baudrate=9600&parity=E&stopbits=1&timeout=0.3&retries=2`` (serial port or
pty path) and ``modbus-rtu+tcp://HOST:PORT?unit=2`` (RTU frames passed through a serial device server).
Every parameter is documented in ``docs/modbus.md``; unknown ones are errors.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from starterbus.core.errors import ConfigurationError
from starterbus.core.profile import Profile
from starterbus.core.url import DeviceUrl
from starterbus.transports.modbus.frames import BROADCAST, MAX_UNIT
from starterbus.transports.modbus.line import SerialSettings, TransactionPolicy
from starterbus.transports.modbus.slave import TRANSPORT
from starterbus.transports.modbus.timing import silent_interval

URL_PARAMETERS = (
    "unit", "baudrate", "parity", "stopbits", "bytesize", "timeout", "retries", "retry_writes", "silence",
    "turnaround",
)  # fmt: skip
DEFAULT_TIMEOUT = 0.5
DEFAULT_RETRIES = 2
DEFAULT_TURNAROUND = 0.1
VARIANTS = ("", "tcp")


@dataclass(frozen=True, slots=True)
class ModbusRtuConfig:
    """Everything a URL says about one Modbus RTU device."""

    variant: str  # "" (serial port / pty) or "tcp"
    path: str  # serial port path ("" for tcp)
    host: str
    port: int
    unit: int
    serial: SerialSettings
    policy: TransactionPolicy

    @property
    def line_key(self) -> tuple[str, str, int]:
        """What identifies the physical line, for sharing it between devices of one process."""
        if self.variant == "tcp":
            return ("tcp", self.host, self.port)
        return ("serial", os.path.realpath(self.path), 0)

    @property
    def target(self) -> str:
        return f"{self.host}:{self.port}" if self.variant == "tcp" else self.path

    @property
    def broadcast(self) -> bool:
        return self.unit == BROADCAST

    @classmethod
    def from_url(cls, url: DeviceUrl, profile: Profile) -> ModbusRtuConfig:
        url.check_known(URL_PARAMETERS)
        if url.variant not in VARIANTS:
            raise ConfigurationError(
                f"{url.text}: unknown variant {url.scheme!r} (use modbus-rtu:///dev/ttyUSB0 or modbus-rtu+tcp://HOST:PORT)"
            )
        settings = profile.transport_settings(TRANSPORT)
        path, host, port = "", "", 0
        if url.variant == "tcp":
            host, port = url.host_port()
            if url.path not in ("", "/"):
                raise ConfigurationError(f"{url.text}: a modbus-rtu+tcp URL has no path (got {url.path!r})")
        else:
            if url.host:
                raise ConfigurationError(
                    f"{url.text}: a serial URL has no host; write three slashes: modbus-rtu:///dev/ttyUSB0"
                )
            path = url.path
            if not path or path == "/":
                raise ConfigurationError(f"{url.text}: no serial port path (e.g. modbus-rtu:///dev/ttyUSB0?unit=2)")

        unit = url.get_int("unit", None, 0, MAX_UNIT) if "unit" in url.query else None
        if unit is None:
            raise ConfigurationError(
                f"{url.text}: unit: required URL parameter missing (the slave address, e.g. unit=2)"
            )
        lo, hi = settings.get("unit_ids", [0, MAX_UNIT])
        if unit != BROADCAST and not lo <= unit <= hi:
            raise ConfigurationError(
                f"{url.text}: unit: {profile.display_name} slave addresses are {max(lo, 1)}..{hi} (0 = broadcast)"
            )

        baud_choices = [int(b) for b in settings.get("baudrates", [])]
        default_baud = int(settings.get("default_baudrate", 9600))
        baudrate = url.get_int("baudrate", default_baud, 1, 10_000_000)
        if baud_choices and baudrate not in baud_choices:
            raise ConfigurationError(
                f"{url.text}: baudrate: {profile.display_name} speaks "
                f"{', '.join(map(str, baud_choices))} baud, not {baudrate}"
            )
        parity = url.get_str("parity", "N").upper()
        if parity not in ("N", "E", "O"):
            raise ConfigurationError(f"{url.text}: parity: {parity!r} is not N, E or O")
        stopbits = url.get_int("stopbits", 1, 1, 2)
        bytesize = url.get_int("bytesize", 8, 8, 8)
        silence = url.get_float("silence", silent_interval(baudrate), 0.0, 1.0)
        policy = TransactionPolicy(
            timeout=url.get_float("timeout", DEFAULT_TIMEOUT, 0.001, 60.0),
            retries=url.get_int("retries", DEFAULT_RETRIES, 0, 10),
            retry_writes=url.get_bool("retry_writes", False),
            turnaround=url.get_float("turnaround", DEFAULT_TURNAROUND, 0.0, 10.0),
        )
        return cls(
            variant=url.variant,
            path=path,
            host=host,
            port=port,
            unit=unit,
            serial=SerialSettings(baudrate, parity, stopbits, bytesize, silence),
            policy=policy,
        )
