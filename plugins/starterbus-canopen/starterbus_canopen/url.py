"""``canopen://INTERFACE/CHANNEL?node=N&...``: the URL of one CANopen device, parsed and validated."""

from __future__ import annotations

from dataclasses import dataclass

from starterbus.core import ConfigurationError, DeviceUrl, Profile
from starterbus_canopen.od import MASTER_NODE_DEFAULT
from starterbus_canopen.settings import CanopenSettings

URL_PARAMETERS = ("node", "bitrate", "heartbeat", "master", "timeout", "max_age", "cycle")
BITRATES = (10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)


@dataclass(frozen=True, slots=True)
class CanopenUrl:
    """Where the device is and how the master behaves towards it.

    ``heartbeat``: the master's heartbeat period, s (0: none); ``cycle``: RPDO1 repetition period, s;
    ``max_age``: the oldest TPDO1 a status read uses, s (older: SDO); ``timeout``: SDO response timeout, s.
    """

    interface: str
    channel: str
    node: int
    bitrate: int | None
    heartbeat: float
    master: int
    timeout: float
    max_age: float
    cycle: float

    @classmethod
    def parse(cls, url: DeviceUrl, profile: Profile | None = None) -> CanopenUrl:
        url.check_known(URL_PARAMETERS)
        interface, channel = url.host, url.path.strip("/")
        if not interface or not channel or "/" in channel:
            raise ConfigurationError(
                f"{url.text}: expected canopen://INTERFACE/CHANNEL?node=N (e.g. canopen://virtual/bus0?node=5, "
                "canopen://socketcan/can0?node=5)"
            )
        lo, hi = CanopenSettings.of(profile).node_ids if profile is not None else (1, 127)
        node = url.get_int("node", None, lo, hi)
        bitrate = url.get_int("bitrate", 0, 0, 1_000_000) or None
        if bitrate is not None and bitrate not in BITRATES:
            raise ConfigurationError(
                f"{url.text}: bitrate: {bitrate} is not a CiA 301 bit rate ({', '.join(map(str, BITRATES))})"
            )
        master = url.get_int("master", MASTER_NODE_DEFAULT, 1, 127)
        if master == node:
            raise ConfigurationError(f"{url.text}: master: {master} is the device's own node id")
        heartbeat = url.get_int("heartbeat", 100, 0, 65535) / 1000.0
        return cls(
            interface=interface,
            channel=channel,
            node=node,
            bitrate=bitrate,
            heartbeat=heartbeat,
            master=master,
            timeout=url.get_float("timeout", 0.5, 0.01, 60.0),
            max_age=url.get_float("max_age", 0.5, 0.0, 3600.0),
            cycle=url.get_int("cycle", 100, 1, 65535) / 1000.0,
        )
