"""The ``profibus-pkw`` URL: its parameters, checked against the model, as :class:`LinkSettings`.

URL forms (the part after ``+`` picks the channel)::

    profibus-pkw+sim://[NAME]?ppo=1            in-process simulated slave (NAME: attach_slave(); none: private)
    profibus-pkw+gateway://HOST:PORT?ppo=1&out=0&in=0&unit=1&cycle=0.01
                                                Modbus TCP gateway / PLC showing the DP words as registers

Common parameters: ``ppo`` (1 or 3, default 1), ``cycle`` (s between DP exchanges; 0 = on demand, no thread),
``timeout`` (PKW time limit, s), ``max_cycles`` (PKW cycle limit; default: as many DP cycles as ``timeout``
lasts, at least 100), ``hold`` (exchanges per command word),
``pulse`` (minimum s per command word), ``station`` (the DP address, for messages; checked against the model),
``stale_cycles`` / ``stale_time`` (how many exchanges / seconds old an input may be; sim 0/0, gateway 1/0),
``inherited`` (how many tasks an earlier session may have left for the slave to answer; default 2).
Sim only: ``latency`` (exchanges before a private slave's PKW response shows). Gateway only: ``out``, ``in``
(register offsets of the output and input words), ``unit`` (Modbus unit id), ``in_fc`` (3 or 4: how inputs
are read).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from starterbus.core import ConfigurationError, DeviceUrl, Profile
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.master.freshness import DEFAULT_INHERITED
from starterbus.transports.profibus_pkw.master.handshake import MAX_INHERITED, Limits
from starterbus.transports.profibus_pkw.settings import profibus_settings

VARIANTS = ("sim", "gateway")
_COMMON = (
    "ppo",
    "cycle",
    "timeout",
    "max_cycles",
    "hold",
    "pulse",
    "station",
    "stale_cycles",
    "stale_time",
    "inherited",
)
_SIM = (*_COMMON, "latency")
_GATEWAY = (*_COMMON, "out", "in", "unit", "in_fc")


#: the PKW cycle limit when the URL gives none, at least: with a DP cycle, as many exchanges as ``timeout`` lasts
MIN_MAX_CYCLES = 100
#: the largest cycle limit, given or derived
MAX_CYCLES = 1_000_000


def default_max_cycles(timeout: float, cycle: float) -> int:
    """The cycle limit of a URL that gives ``timeout`` and no ``max_cycles``: enough exchanges for the whole time
    limit at the DP cycle (a slow slave gets the time the URL gives it), never fewer than 100 nor more than the
    URL may give."""
    if cycle <= 0:  # exchanges back to back: the time limit alone is no count
        return MIN_MAX_CYCLES
    return min(MAX_CYCLES, max(MIN_MAX_CYCLES, math.ceil(timeout / cycle) + 2))  # + the clear and the task cycle


@dataclass(frozen=True, slots=True)
class LinkSettings:
    """A ``profibus-pkw`` URL, checked and typed."""

    variant: str
    ppo: Ppo
    cycle: float
    limits: Limits
    hold: int
    pulse: float
    station: int | None = None
    name: str = ""  # sim: attached slave name
    latency: int = 0  # sim: private slave latency
    host: str = ""
    port: int = 502
    out: int = 0
    inp: int = 0
    unit: int = 1
    in_fc: int = 3

    @classmethod
    def from_url(cls, url: DeviceUrl, profile: Profile) -> LinkSettings:
        if url.variant not in VARIANTS:
            raise ConfigurationError(
                f"{url.text}: choose a channel: profibus-pkw+sim://[NAME]?ppo=1 or "
                "profibus-pkw+gateway://HOST:PORT?ppo=1&out=0&in=0&unit=1"
            )
        url.check_known(_SIM if url.variant == "sim" else _GATEWAY)
        number = url.get_int("ppo", 1)
        if number not in (1, 3):
            raise ConfigurationError(f"{url.text}: ppo: {number} is not 1 (PPO1, 'type I') or 3 (PPO3, 'type III')")
        ppo = Ppo(number)
        settings = profibus_settings(profile)
        offered = settings.ppo
        if ppo.value not in offered:
            raise ConfigurationError(
                f"{url.text}: ppo: {number}: {profile.display_name} does not offer {ppo.name} over Profibus "
                f"(it offers: {', '.join(f'ppo={n} ({Ppo(n).name})' for n in offered) or 'none'})"
            )
        station = url.get_int("station", 0, 0, 127) if "station" in url.query else None
        stations = settings.stations
        if station is not None and not stations[0] <= station <= stations[1]:
            raise ConfigurationError(
                f"{url.text}: station: {station} is outside {profile.display_name}'s range {stations[0]}..{stations[1]}"
            )
        gateway = url.variant == "gateway"
        cycle = url.get_float("cycle", 0.01, 0.0, 10.0)
        # How old an input may be (docs/profibus.md, "Stale answers"): the in-process slave's is always current;
        # a gateway's image may lag, and a faulty one may show an older image again.
        timeout = url.get_float("timeout", 2.0, 0.001, 600.0)
        limits = Limits(
            url.get_int("max_cycles", default_max_cycles(timeout, cycle), 2, MAX_CYCLES),
            timeout,
            url.get_int("stale_cycles", 1 if gateway else 0, 0, 10_000),
            url.get_float("stale_time", 0.0, 0.0, 60.0),
            verify_start=True,  # a task an earlier session left on the slave must not answer our first one
            inherited=url.get_int("inherited", DEFAULT_INHERITED, 0, MAX_INHERITED),
        )
        hold = url.get_int("hold", 3, 1, 1000)
        pulse = url.get_float("pulse", 0.05 if gateway else 0.0, 0.0, 10.0)
        if not gateway:
            name = url.host or url.path.strip("/")
            latency = url.get_int("latency", 0, 0, 10_000)
            return cls(url.variant, ppo, cycle, limits, hold, pulse, station, name=name, latency=latency)
        host, port = url.host_port(502)
        return cls(
            url.variant,
            ppo,
            cycle,
            limits,
            hold,
            pulse,
            station,
            host=host,
            port=port,
            out=url.get_int("out", 0, 0, 0xFFFF),
            inp=url.get_int("in", 0, 0, 0xFFFF),
            unit=url.get_int("unit", 1, 0, 255),
            in_fc=url.get_int("in_fc", 3, 3, 4),
        )
