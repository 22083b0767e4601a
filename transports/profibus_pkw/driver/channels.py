"""Channels: how the 4 (PPO1) or 2 (PPO3) words of one DP slave are exchanged once.

A :class:`Channel` knows nothing of PKW or PZD: :meth:`Channel.exchange` writes the master's output words and
returns the slave's input words. Two channels are built in:

- :class:`SimChannel` (``profibus-pkw+sim://NAME``): an in-process :class:`SimulatedDpSlave`, either attached
  under a name with :func:`attach_slave` (so a test or a demo can hold the :class:`SimulatedStarter`) or a private
  one per transport when the URL names none;
- :class:`GatewayChannel` (``profibus-pkw+gateway://HOST:PORT?out=0&in=0&unit=1``): a Profibus master gateway or
  PLC that shows the slave's output words as Modbus TCP holding registers (written with FC16) and its input
  words as holding registers (FC03) or input registers (FC04). One Modbus TCP connection per gateway is shared
  by every station mapped on it and by ``modbus-tcp`` devices at the same ``HOST:PORT`` (:data:`GATEWAYS`,
  ``modbus``'s pool of connections), on the process's scheduler: a
  station's cycle is a driver there (:meth:`Channel.driver`, ``gateway.py``), no thread and no blocking call.

A third channel (a DP master card, pyprofibus) implements the same three methods; see docs/profibus.md. Its
exchange is called by a :class:`LocalDriver` (:meth:`Channel.driver`'s default) on a loop of its own.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

from starterbus.core import (
    ConfigurationError,
    Driver,
    LocalDriver,
    Scheduler,
    SimulatedStarter,
    StarterbusError,
    TransportError,
    connect_timeout,
)
from starterbus.transports.modbus.driver.tcp_line import CONNECTIONS, MbapConnection, connection_key
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.driver.gateway import GatewayStation, StationDriver
from starterbus.transports.profibus_pkw.driver.station_lock import hold_station, release_station
from starterbus.transports.profibus_pkw.master.station import DpIn, DpOut, StationEngine
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

Clock = Callable[[], float]
ErrorOf = Callable[[Exception], StarterbusError]

__all__ = [
    "GATEWAYS",
    "Channel",
    "GatewayChannel",
    "SimChannel",
    "Snapshot",
    "attach_slave",
    "attached_slaves",
    "detach_slave",
    "get_slave",
]


@dataclass(frozen=True, slots=True)
class Snapshot:
    """What a channel can tell without writing: the output words as the slave last got them (if known)
    and the input words now."""

    outputs: tuple[int, ...] | None
    inputs: tuple[int, ...]


class Channel(ABC):
    """One DP slave's data exchange. Called by one cycle driver at a time (the driver serialises)."""

    ppo: Ppo
    #: the exchange is an in-process call that never blocks (a simulated slave): the link runs on the process's
    #: scheduler; otherwise on a loop of its own per :meth:`loop_key`, so a blocking call delays no other medium
    in_process: bool = False
    #: an exchange not ended by then failed (a peer that dropped it); a channel whose own timeouts decide says more
    reply_within: float = 1.0

    def loop_key(self) -> Hashable:
        """Channels with the same key share one loop (their exchanges take turns): by default one per type."""
        return (type(self).__module__, type(self).__qualname__)

    def scheduler(self) -> Scheduler | None:
        """The loop the channel's medium runs on, if it has one (the link's station runs there); None: the link
        chooses (``link.py``: ``loop_for``)."""
        return None

    def driver(
        self, name: str, make_engine: Callable[[], StationEngine], clock: Clock, error: ErrorOf
    ) -> Driver[StationEngine]:
        """The driver of a station on this channel: by default :meth:`exchange` called in the loop, once per DP
        exchange (``clock``: the loop's; ``error``: a failure of the call as a starterbus error)."""

        def exchange(unit: DpOut) -> DpIn:
            return unit[0], self.exchange(unit[1])

        return LocalDriver(name, make_engine, exchange, clock=clock, error=error)

    @abstractmethod
    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        """Send the output words, return the input words (``ppo.words`` each). Raise :class:`TransportError`.

        A ``None`` word means "leave this output word as it is": the driver is passive on PZD until its first
        command (see :meth:`snapshot`). A channel that must always send whole telegrams substitutes the last
        value it sent, and must then report its outputs in :meth:`snapshot` (so the driver is never passive).
        """

    @abstractmethod
    def snapshot(self) -> Snapshot:
        """Read the current input words (and the output words if the channel can) WITHOUT writing anything.

        The driver calls it once on open: with the outputs known it repeats the control word in force; with
        ``outputs`` None it leaves the control word alone (``None`` words) until a command is given.
        """

    def close(self) -> None:
        """Release the channel (the slave keeps its state; a gateway keeps sending its output image)."""

    def describe(self) -> str:
        return type(self).__name__


# -- in-process simulated slaves -------------------------------------------------------------------------------

_slaves: dict[str, SimulatedDpSlave] = {}
_slaves_lock = threading.Lock()


def attach_slave(
    name: str, starter: SimulatedStarter | SimulatedDpSlave, ppo: Ppo | int = Ppo.PPO1, *, latency: int = 0
) -> SimulatedDpSlave:
    """Make a simulated starter reachable as ``profibus-pkw+sim://NAME?ppo=N`` in this process.

    Pass a :class:`SimulatedStarter` (wrapped in a new :class:`SimulatedDpSlave` of the given PPO type) or a
    ready slave. A name can be attached once; :func:`detach_slave` frees it.
    """
    if not name or not name.replace("-", "").replace("_", "").replace(".", "").isalnum():
        raise ConfigurationError(f"{name!r} is not a slave name (letters, digits, '-', '_', '.')")
    slave = starter if isinstance(starter, SimulatedDpSlave) else SimulatedDpSlave(starter, ppo, latency=latency)
    slave.name = name
    with _slaves_lock:
        if name.lower() in _slaves:
            raise ConfigurationError(f"a simulated DP slave named {name!r} is already attached")
        _slaves[name.lower()] = slave
    return slave


def detach_slave(name: str) -> None:
    with _slaves_lock:
        _slaves.pop(name.lower(), None)


def get_slave(name: str) -> SimulatedDpSlave:
    with _slaves_lock:
        slave = _slaves.get(name.lower())
        known = ", ".join(sorted(_slaves)) or "none"
    if slave is None:
        raise ConfigurationError(
            f"no simulated DP slave named {name!r} in this process (attached: {known}; "
            "use attach_slave(), or profibus-pkw+sim:// without a name for a private one)"
        )
    return slave


def attached_slaves() -> list[str]:
    with _slaves_lock:
        return sorted(_slaves)


class SimChannel(Channel):
    """Exchange with an in-process :class:`SimulatedDpSlave` (no I/O; each call is one DP cycle)."""

    in_process = True

    def __init__(self, slave: SimulatedDpSlave) -> None:
        self.slave = slave
        self.ppo = slave.ppo

    def driver(
        self, name: str, make_engine: Callable[[], StationEngine], clock: Clock, error: ErrorOf
    ) -> Driver[StationEngine]:
        """:meth:`Channel.driver`'s, calling the slave without this channel's :meth:`exchange` in between (unless a
        subclass has its own)."""
        if type(self).exchange is not SimChannel.exchange:
            return super().driver(name, make_engine, clock, error)
        slave_exchange = self.slave.exchange

        def exchange(unit: DpOut) -> DpIn:
            return unit[0], slave_exchange(unit[1])

        return LocalDriver(name, make_engine, exchange, clock=clock, error=error)

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        return self.slave.exchange(out_words)

    def snapshot(self) -> Snapshot:
        return Snapshot(self.slave.outputs, self.slave.inputs())

    def describe(self) -> str:
        return f"simulated {self.ppo.name} slave {self.slave.name or '(private)'}"


# -- Modbus TCP gateway --------------------------------------------------------------------------------------

#: one connection per (host, port) in this process, on the process's scheduler, shared with ``modbus-tcp`` devices
GATEWAYS = CONNECTIONS


class GatewayChannel(Channel):
    """A station mapped on a Modbus TCP gateway: outputs at register ``out``, inputs at ``inp`` (FC03 or FC04)."""

    def __init__(
        self,
        host: str,
        port: int,
        ppo: Ppo,
        *,
        out: int = 0,
        inp: int = 0,
        unit: int = 1,
        input_function: int = 3,
        timeout: float = 1.0,
    ) -> None:
        if input_function not in (3, 4):
            raise ConfigurationError(f"inputs are read with FC03 or FC04, not FC{input_function:02d}")
        for name, address in (("out", out), ("in", inp)):
            if not 0 <= address <= 0xFFFF - ppo.words + 1:
                raise ConfigurationError(f"gateway register offset {name}={address} is not a register address")
        self.host, self.port, self.ppo = host, port, ppo
        self.out, self.inp, self.unit, self.input_function = out, inp, unit, input_function
        self._key = connection_key(host, port)
        self.reply_within = 2 * timeout + 1.0  # an FC16 and a read, each with its timeout: the connection decides
        self._station = hold_station(host, port, unit, out, f"station at gateway {host}:{port} unit {unit} out={out}")
        try:
            self._conn = GATEWAYS.acquire(
                self._key, lambda: MbapConnection(host, port, 1, connect_timeout(timeout), connect=False)
            )
        except BaseException:
            release_station(self._station)
            raise
        if self._conn.outstanding != 1:
            GATEWAYS.release(self._key)
            release_station(self._station)
            raise ConfigurationError(
                f"{self._conn.name} is already open in this process with outstanding={self._conn.outstanding} "
                "(modbus-tcp): a gateway's stations need one transaction at a time (outstanding=1), and one "
                "connection has one setting"
            )
        self.gateway = GatewayStation(
            self._conn, ppo.words, out=out, inp=inp, unit=unit, input_function=input_function, timeout=timeout
        )
        self._closed = False

    @property
    def outputs_readable(self) -> bool:
        """Can the output area be read back? Not when it shares its registers with the input area."""
        if self.input_function == 4:
            return True
        n = self.ppo.words
        return self.out + n <= self.inp or self.inp + n <= self.out

    def scheduler(self) -> Scheduler:
        return self._conn.loop

    def driver(
        self, name: str, make_engine: Callable[[], StationEngine], clock: Clock, error: ErrorOf
    ) -> Driver[StationEngine]:
        """The station's cycle on the gateway's connection (the stations of a gateway take turns on it)."""
        return StationDriver(name, make_engine, self.gateway)

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        return self.gateway.exchange(out_words, "exchange")

    def snapshot(self) -> Snapshot:
        inputs = self.gateway.read_now(self.gateway.read, "read the inputs")
        outputs = (
            self.gateway.read_now(self.gateway.read_outputs(), "read the outputs") if self.outputs_readable else None
        )
        return Snapshot(outputs, inputs)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            GATEWAYS.release(self._key)
            release_station(self._station)

    def describe(self) -> str:
        fc = "FC04 input" if self.input_function == 4 else "FC03 holding"
        return (
            f"{self.ppo.name} via gateway {self.host}:{self.port} unit {self.unit}: outputs at holding register "
            f"{self.out}, inputs at {fc} register {self.inp}"
        )


def channel_error(exc: BaseException) -> StarterbusError:
    """Any failure of a channel as a starterbus error (TransportError unless it already is one)."""
    if isinstance(exc, StarterbusError):
        return exc
    return TransportError(f"channel failed: {type(exc).__name__}: {exc}")
