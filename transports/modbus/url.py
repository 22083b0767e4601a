"""Device URL -> typed settings of a Modbus RTU device.

``modbus-rtu:///dev/ttyUSB0?unit=2&baudrate=9600&parity=E&stopbits=1&timeout=0.3&retries=2`` (serial port or
pty path), ``modbus-rtu://COM3?unit=2`` (a Windows COM port), ``modbus-rtu+tcp://HOST:PORT?unit=2`` (RTU frames
passed through a serial device server), and pyserial's URL handlers: ``modbus-rtu+rfc2217://HOST:PORT?unit=2``
(``rfc2217://HOST:PORT``) and ``modbus-rtu+socket://HOST:PORT?unit=2`` (``socket://HOST:PORT``).
Every parameter is documented in ``docs/modbus.md``; unknown ones are errors.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from starterbus.core import ConfigurationError, DeviceUrl, Profile, connect_timeout
from starterbus.transports.modbus.codec.messages import BROADCAST, MAX_UNIT
from starterbus.transports.modbus.codec.timing import silent_interval
from starterbus.transports.modbus.driver.link import Link, PySerialLink, SerialSettings, TcpConnect, com_port
from starterbus.transports.modbus.master.exchange import TransactionPolicy
from starterbus.transports.modbus.settings import modbus_settings

URL_PARAMETERS = (
    "unit", "baudrate", "parity", "stopbits", "bytesize", "timeout", "retries", "retry_writes", "silence",
    "turnaround", "quarantine", "io", "wire_check",
)  # fmt: skip
DEFAULT_TIMEOUT = 0.5
DEFAULT_RETRIES = 2
DEFAULT_TURNAROUND = 0.1
VARIANTS = ("", "tcp", "rfc2217", "socket")
PYSERIAL_URL_VARIANTS = ("rfc2217", "socket")  # variant = the pyserial URL scheme
IO_CHOICES = ("auto", "posix", "pyserial")
WIRE_CHECK_CHOICES = {"auto": None, "on": True, "off": False}


@dataclass(frozen=True, slots=True)
class ModbusRtuConfig:
    """Everything a URL says about one Modbus RTU device."""

    variant: str  # "" (serial port / pty / COM port), "tcp", or a pyserial URL scheme (rfc2217, socket)
    path: str  # serial port path or COM port name ("" otherwise)
    host: str
    port: int
    unit: int
    serial: SerialSettings
    policy: TransactionPolicy
    io: str = "posix"  # serial ports: "posix" (select + os.read on the descriptor) or "pyserial"

    @property
    def line_key(self) -> tuple[str, str, int]:
        """What identifies the physical line, for sharing it between devices of one process."""
        if self.variant:
            return (self.variant, self.host, self.port)
        return ("serial", self.path if com_port(self.path) else os.path.realpath(self.path), 0)

    @property
    def target(self) -> str:
        if self.variant == "tcp":
            return f"{self.host}:{self.port}"
        if self.variant:
            return f"{self.variant}://{self.host}:{self.port}"
        return self.path

    def connect(self) -> Link:
        """Open the port or connection: the POSIX fast path where it applies, else pyserial."""
        if self.variant == "tcp":
            return Link.connect_tcp(self.host, self.port, self.connect_timeout)
        if self.variant:
            return PySerialLink.open(self.target, self.serial, url=True)
        if self.io == "pyserial":
            return PySerialLink.open(self.path, self.serial)
        return Link.open_serial(self.path, self.serial)

    def start_connect(self) -> TcpConnect:
        """A connection to a serial device server (``+tcp``), made without blocking (the I/O loop's reconnect)."""
        return TcpConnect(self.host, self.port, self.connect_timeout)

    @property
    def connect_timeout(self) -> float:
        """How long a connection to a serial device server may take: the device's timeout, at least 1 s."""
        return connect_timeout(self.policy.timeout)

    @property
    def broadcast(self) -> bool:
        return self.unit == BROADCAST

    @classmethod
    def from_url(cls, url: DeviceUrl, profile: Profile) -> ModbusRtuConfig:
        url.check_known(URL_PARAMETERS)
        if url.variant not in VARIANTS:
            raise ConfigurationError(
                f"{url.text}: unknown variant {url.scheme!r} (use modbus-rtu:///dev/ttyUSB0, modbus-rtu://COM3, "
                "modbus-rtu+tcp://HOST:PORT, modbus-rtu+rfc2217://HOST:PORT or modbus-rtu+socket://HOST:PORT)"
            )
        path, host, port = "", "", 0
        if url.variant:
            host, port = url.host_port()
            if url.path not in ("", "/"):
                raise ConfigurationError(f"{url.text}: a {url.scheme} URL has no path (got {url.path!r})")
        else:
            path = serial_path(url)
        io = url.get_str("io", "auto", IO_CHOICES)
        if io != "auto" and url.variant:
            raise ConfigurationError(f"{url.text}: io: applies to serial ports only (not {url.scheme})")
        if io == "auto":
            io = "posix" if os.name == "posix" else "pyserial"

        unit = url.get_int("unit", None, 0, MAX_UNIT) if "unit" in url.query else None
        if unit is None:
            raise ConfigurationError(
                f"{url.text}: unit: required URL parameter missing (the slave address, e.g. unit=2)"
            )
        settings = modbus_settings(profile)
        lo, hi = settings.unit_ids
        if unit != BROADCAST and not lo <= unit <= hi:
            raise ConfigurationError(
                f"{url.text}: unit: {unit} is not a {profile.display_name} slave address: "
                f"{profile.display_name} slave addresses are {max(lo, 1)}..{hi} (0 = broadcast)"
            )

        baud_choices = settings.baudrates
        default_baud = settings.default_baudrate
        baudrate = url.get_int("baudrate", default_baud, 1, 10_000_000)
        if baud_choices and baudrate not in baud_choices:
            raise ConfigurationError(
                f"{url.text}: baudrate: {profile.display_name} speaks "
                f"{', '.join(map(str, baud_choices))} baud, not {baudrate}"
            )
        parity = url.get_str("parity", "N").upper()
        if parity not in ("N", "E", "O"):
            raise ConfigurationError(f"{url.text}: parity: {parity!r} is not N, E or O (none, even, odd)")
        stopbits = url.get_int("stopbits", 1, 1, 2)
        bytesize = url.get_int("bytesize", 8, 8, 8)
        silence = url.get_float("silence", silent_interval(baudrate), 0.0, 1.0)
        wire_check = WIRE_CHECK_CHOICES[url.get_str("wire_check", "auto", WIRE_CHECK_CHOICES)]
        timeout = url.get_float("timeout", DEFAULT_TIMEOUT, 0.001, 60.0)
        quarantine = url.get_float("quarantine", timeout, 0.0, 600.0)
        if quarantine < timeout:
            raise ConfigurationError(
                f"{url.text}: quarantine: {quarantine:g} s is shorter than the response timeout {timeout:g} s "
                "(a late answer could still arrive after it)"
            )
        policy = TransactionPolicy(
            timeout=timeout,
            retries=url.get_int("retries", DEFAULT_RETRIES, 0, 10),
            retry_writes=url.get_bool("retry_writes", False),
            turnaround=url.get_float("turnaround", DEFAULT_TURNAROUND, 0.0, 10.0),
            quarantine=quarantine,
        )
        return cls(
            variant=url.variant,
            path=path,
            host=host,
            port=port,
            unit=unit,
            serial=SerialSettings(baudrate, parity, stopbits, bytesize, silence, wire_check),
            policy=policy,
            io=io,
        )


def serial_path(url: DeviceUrl) -> str:
    """The port of a serial URL: a path (three slashes) or a Windows COM port (``modbus-rtu://COM3``,
    ``modbus-rtu:///COM3``)."""
    if url.host:
        name = com_port(url.host)
        if name is None or url.port is not None or url.path not in ("", "/"):
            raise ConfigurationError(
                f"{url.text}: a serial URL has no host; write three slashes (modbus-rtu:///dev/ttyUSB0) "
                "or a COM port (modbus-rtu://COM3)"
            )
        return name
    name = com_port(url.path)
    if name is not None:
        return name
    if not url.path or url.path == "/":
        raise ConfigurationError(f"{url.text}: no serial port path (e.g. modbus-rtu:///dev/ttyUSB0?unit=2)")
    return url.path
