"""The ``devicenet://`` URL: its parameters checked against the model (see :mod:`.transport` for the table)."""

from __future__ import annotations

import math

from starterbus.core import ConfigurationError, DeviceUrl, Profile
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.ids import MAX_MAC
from starterbus.transports.devicenet.master.link import LinkConfig, ScannerConfig
from starterbus.transports.devicenet.settings import devicenet_settings

NAME = "devicenet"
URL_PARAMETERS = (
    "mac",
    "master_mac",
    "bitrate",
    "assemblies",
    "epr",
    "period",
    "poll",
    "dup_mac_wait",
    "timeout",
    "settle",
    "control",
)

MIN_INTERVAL = 0.005  # s: the fastest scan a ``period`` asks for (bus load)
MAX_INTERVAL = 1.0  # s: the slowest; with EPR = 2 x interval the slave's watchdog fires after 8 s of silence
MIN_EPR_MS = 100  # the shortest expected packet rate a ``period`` sets (watchdog 400 ms: scheduling jitter)
EPR_FACTOR = 2


def timing_for_period(period: float) -> tuple[float, int]:
    """Scan interval (s) and expected packet rate (ms) for a caller that needs fresh inputs every ``period`` s."""
    interval = min(max(period, MIN_INTERVAL), MAX_INTERVAL)
    epr_ms = max(MIN_EPR_MS, 10 * math.ceil(EPR_FACTOR * interval * 100 - 1e-9))
    return interval, epr_ms


def parse_url(url: DeviceUrl, profile: Profile) -> tuple[ScannerConfig, LinkConfig]:
    """Validate a ``devicenet://`` URL against the profile; every problem is a ConfigurationError."""
    url.check_known(URL_PARAMETERS)
    interface = url.host
    channel = url.path.lstrip("/")
    if not interface or not channel:
        raise ConfigurationError(
            f"{url.text}: expected devicenet://INTERFACE/CHANNEL?mac=N (e.g. devicenet://virtual/bus0?mac=5, "
            "devicenet://socketcan/can0?mac=5, devicenet://remote/127.0.0.1:54701?mac=5)"
        )
    settings = devicenet_settings(profile)
    lo, hi = settings.mac_ids
    mac = url.get_int("mac", lo=lo, hi=hi)
    master_mac = url.get_int("master_mac", 0, lo=0, hi=MAX_MAC)
    if master_mac == mac:
        raise ConfigurationError(f"{url.text}: master_mac and mac are both {mac}")
    bitrates = settings.bitrates
    bitrate = url.get_int("bitrate", 500000)
    if bitrate not in bitrates:
        raise ConfigurationError(f"{url.text}: bitrate: {bitrate} is not one of {', '.join(map(str, bitrates))}")
    assemblies = url.get_str("assemblies", "auto", choices=("auto", "basic", "extended"))
    if "period" in url.query:
        if "poll" in url.query:
            raise ConfigurationError(f"{url.text}: give period (seconds) or poll (ms), not both")
        interval, derived_epr = timing_for_period(url.get_float("period", 1.0, lo=0.0, hi=86400.0))
        poll = interval * 1000.0
        epr = url.get_int("epr", derived_epr, lo=0, hi=0xFFFF)
    else:
        epr = url.get_int("epr", 100, lo=0, hi=0xFFFF)
        poll = url.get_float("poll", 20.0, lo=0.0, hi=60000.0)
    if epr and poll > epr:
        raise ConfigurationError(
            f"{url.text}: poll period {poll:g} ms exceeds the expected packet rate {epr} ms "
            "(the slave would time the connection out)"
        )
    scanner = ScannerConfig(
        interface=interface,
        channel=channel,
        master_mac=master_mac,
        bitrate=bitrate,
        poll_period=poll / 1000.0,
        dup_mac_wait=url.get_float("dup_mac_wait", 1.0, lo=0.0, hi=10.0),
        timeout=url.get_float("timeout", 1.0, lo=0.01, hi=60.0),
    )
    link = LinkConfig(
        mac=mac,
        assemblies=assemblies,
        epr_ms=epr,
        settle=url.get_int("settle", 2, lo=1, hi=50),
        interval=poll / 1000.0,
        io=False,
        input_instances=(settings.instances(AssemblySet.BASIC)[0], settings.instances(AssemblySet.EXTENDED)[0]),
        product=profile.display_name,
        sets=", ".join(f"{s.value} {'/'.join(map(str, settings.instances(s)))}" for s in AssemblySet),
    )
    return scanner, link
