"""The Sparkplug B edge node as a sans-IO state machine: samples, connection events, commands and times in,
messages to publish (and commands to run through the guarded path) out. No sockets, threads or clocks here.

Decisions (SPARKPLUG.md):
- bdSeq goes +1 before every CONNECT (:meth:`EdgeSession.next_will`); the driver persists it, so it also
  advances across restarts (pitfalls: Restarts), and sets the Will before every connect (pitfalls: Auto-reconnect).
- seq is one counter for NBIRTH/DBIRTH/DDATA/NDATA/DDEATH, 0 in every NBIRTH, wrapping 255 -> 0.
- While no session is up (no broker, or the primary host offline) polling goes on: changed values are kept in a
  bounded store (``history.HistoryStore``, injected: in memory, or ``store.SqliteStore`` on disk); the oldest
  beyond the bounds are dropped and counted (``Node Info/Buffered Messages Dropped``). Once a device is born
  again (``HistoryReady``), :meth:`EdgeSession.history` hands its records out in order, in batches, as DDATA
  with is_historical=true; the driver reports them written with :meth:`EdgeSession.history_sent`.
- A command is refused (and the refusal reported in ``Device Control/Last Command``) on a plaintext connection
  unless allowed, when older than ``command_max_age`` by its metric (else payload) timestamp, for a device not
  born, or for a metric that is not writable. Commands without any timestamp are accepted (the spec makes
  timestamps optional); a host that wants the age check sends them.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from starterbus.core.errors import ConfigurationError
from starterbus.core.status import Command
from starterbus.fleet.config import FleetConfig
from starterbus.fleet.poller import Sample
from starterbus.serve.actions import Action, CommandRequest, HistoryReady, Publish, Reconnect, SessionOptions
from starterbus.serve.history import Bounds, HistoryStore, MemoryStore
from starterbus.serve.metrics import (
    BDSEQ,
    LAST_COMMAND,
    NODE_DEVICES_ONLINE,
    NODE_DROPPED,
    NODE_REFUSED,
    REBIRTH,
    REFUSED,
    Aliases,
    MetricSet,
    Scalar,
    changed,
    device_metrics,
    initial_values,
    node_metrics,
    sample_values,
)
from starterbus.serve.payloads import (
    BadCommandPayload,
    CommandMetric,
    Entry,
    command_value,
    decode_command,
    encode,
    encode_ndeath,
)

NAMESPACE = "spBv1.0"

__all__ = ["Action", "CommandRequest", "EdgeSession", "HistoryReady", "Publish", "Reconnect", "SessionOptions"]


@dataclass
class _Device:
    name: str
    metrics: MetricSet
    online: bool = False
    born: bool = False
    current: dict[str, tuple[Scalar | None, int]] = field(default_factory=dict)  # name -> (value, ms)
    reported: dict[str, Scalar | None] = field(default_factory=dict)
    last_full: float = 0.0
    refused: int = 0


def _ms(t: float) -> int:
    return int(t * 1000)


class EdgeSession:
    def __init__(
        self,
        options: SessionOptions,
        node: MetricSet,
        devices: dict[str, MetricSet],
        bdseq: int = -1,
        store: HistoryStore | None = None,
    ):
        self.options = options
        self.node = node
        self.devices = {name: _Device(name, metrics) for name, metrics in devices.items()}
        for dev in self.devices.values():
            dev.current = {k: (v, 0) for k, v in initial_values().items()}
        self.bdseq = bdseq  # the value of the current (or last) connection; -1 before the first
        self.seq = 0
        self.connected = False  # subscriptions acknowledged
        self.born = False  # NBIRTH published in this connection
        self.host_online_ts: int | None = None
        self.last_state_ts: int | None = None
        bounds = Bounds(options.buffer_messages, options.buffer_size, options.buffer_age)
        self.store: HistoryStore = store if store is not None else MemoryStore(bounds)
        unknown = [r.id for r in self.store.take(set(self.store.pending()) - set(self.devices), 2**31)]
        self.store.discard(unknown)  # buffered by an earlier run for devices the fleet no longer has
        self.refused = 0
        self.online = 0  # devices online now
        self.published = 0
        self.commands_allowed = options.commands_allowed
        self.topic_prefix = f"{NAMESPACE}/{options.group}"
        self._node_reported: dict[str, Scalar | None] = {}

    @classmethod
    def for_fleet(
        cls,
        config: FleetConfig,
        options: SessionOptions,
        *,
        deadband_steps: float = 1.0,
        deadband_per_key: Mapping[str, float] | None = None,
        bdseq: int = -1,
        store: HistoryStore | None = None,
    ) -> EdgeSession:
        """The node and one Sparkplug device per fleet device, described from their profiles.

        ``deadband_per_key`` (point key -> resolution steps) overrides ``deadband_steps``; a key that no device
        of the fleet publishes is a :class:`ConfigurationError`.
        """
        from starterbus.core.registry import get_profile

        aliases = Aliases()
        node = node_metrics(aliases)
        per_key = dict(deadband_per_key or {})
        devices = {
            d.name: device_metrics(d, get_profile(d.model), aliases, deadband_steps, per_key) for d in config.devices
        }
        published = {m.point.key for ms in devices.values() for m in ms.defs if m.point is not None}
        unknown = sorted(set(per_key) - published)
        if unknown:
            raise ConfigurationError(f"--deadband: no device of {config.source} publishes {', '.join(unknown)}")
        return cls(options, node, devices, bdseq=bdseq, store=store)

    # -- topics -------------------------------------------------------------------------------------------

    def topic(self, kind: str, device: str | None = None) -> str:
        base = f"{self.topic_prefix}/{kind}/{self.options.node}"
        return f"{base}/{device}" if device is not None else base

    def subscriptions(self) -> list[tuple[str, int]]:
        subs = [(self.topic("NCMD"), 1), (self.topic("DCMD", "+"), 1)]
        if self.options.primary_host:
            subs.append((f"{NAMESPACE}/STATE/{self.options.primary_host}", 1))
        return subs

    # -- connection ---------------------------------------------------------------------------------------

    def next_will(self) -> Publish:
        """Before every CONNECT: bdSeq + 1 (wrapping 255 -> 0) and the NDEATH to register as the Will."""
        self.bdseq = (self.bdseq + 1) % 256
        self.connected = self.born = False
        return self.ndeath()

    def ndeath(self) -> Publish:
        return Publish(self.topic("NDEATH"), encode_ndeath(self.bdseq), qos=1)

    def on_connected(self, now: float) -> list[Action]:
        """The subscriptions are acknowledged: births now, or after the primary host says it is online."""
        self.connected = True
        self.host_online_ts = None
        if self.options.primary_host:
            return []
        return self._births(now)

    def on_disconnected(self) -> None:
        self.connected = self.born = False
        for dev in self.devices.values():
            dev.born = False

    # -- births -------------------------------------------------------------------------------------------

    def _next_seq(self) -> int:
        seq = self.seq
        self.seq = (self.seq + 1) % 256
        self.published += 1
        return seq

    def _node_values(self) -> dict[str, Scalar | None]:
        return {
            BDSEQ: self.bdseq,
            REBIRTH: False,
            NODE_DEVICES_ONLINE: self.online,
            NODE_DROPPED: self.dropped,
            NODE_REFUSED: self.refused,
        }

    @property
    def dropped(self) -> int:
        """Buffered DDATA dropped: beyond a bound, not storable, or no longer publishable."""
        return self.store.dropped

    def _births(self, now: float) -> list[Action]:
        self.seq = 0
        self.born = True
        values = self._node_values()
        self._node_reported = dict(values)
        entries: list[Entry] = [(d, values[d.name], _ms(now)) for d in self.node.defs]
        out: list[Action] = [
            Publish(self.topic("NBIRTH"), encode(entries, timestamp=_ms(now), seq=self._next_seq(), birth=True))
        ]
        for dev in self.devices.values():
            dev.born = False
            if dev.online:
                out.append(self._dbirth(dev, now))
        if any(self.devices[name].born for name in self.store.pending() if name in self.devices):
            out.append(HistoryReady())
        return out

    def _dbirth(self, dev: _Device, now: float) -> Publish:
        entries: list[Entry] = []
        for d in dev.metrics.defs:
            value, ts = dev.current.get(d.name, (None, 0))
            entries.append((d, value, ts or _ms(now)))
        dev.born = True
        dev.reported = {d.name: dev.current.get(d.name, (None, 0))[0] for d in dev.metrics.defs}
        dev.last_full = now
        payload = encode(entries, timestamp=_ms(now), seq=self._next_seq(), birth=True)
        return Publish(self.topic("DBIRTH", dev.name), payload)

    def history(self, now: float, limit: int = 200) -> tuple[list[Publish], list[int]]:
        """The next buffered DDATA of born devices, oldest first, as historical DDATA with the next seqs, and the
        ids of their records: publish them at once, then :meth:`history_sent` once written (a record stays
        stored until then, so a connection lost meanwhile sends it again in the next session)."""
        born = [name for name in self.store.pending() if name in self.devices and self.devices[name].born]
        if not self.born or not born:
            return [], []
        out: list[Publish] = []
        sent: list[int] = []
        unusable: list[int] = []
        for record in self.store.take(born, limit):
            dev = self.devices[record.device]
            defs = dev.metrics.by_name
            entries: list[Entry] = [(defs[name], value, ts) for name, value, ts in record.values if name in defs]
            try:
                payload = encode(entries, timestamp=_ms(now), seq=self.seq, birth=False, historical=True)
            except (TypeError, ValueError):  # a value of another type than the metric has now (fleet file changed)
                entries = []
            if not entries:
                unusable.append(record.id)
                continue
            self._next_seq()
            out.append(Publish(self.topic("DDATA", dev.name), payload))
            sent.append(record.id)
        self.store.discard(unusable)
        return out, sent

    def history_sent(self, ids: list[int]) -> None:
        """The DDATA of these records were written to the broker: forget them (counted delivered)."""
        self.store.remove(ids)

    # -- samples and time -----------------------------------------------------------------------------------

    def on_sample(self, sample: Sample, now: float) -> list[Action]:
        dev = self.devices.get(sample.device)
        if dev is None:
            return []
        out: list[Action] = []
        if dev.online != sample.online:
            self.online += 1 if sample.online else -1
        dev.online = sample.online
        if not sample.online:
            if dev.born:
                dev.born = False
                payload = encode([], timestamp=_ms(now), seq=self._next_seq(), birth=False)
                out.append(Publish(self.topic("DDEATH", dev.name), payload))
            return out + self._node_data(now)
        ts = _ms(sample.time)
        for name, value in sample_values(sample, dev.metrics).items():
            dev.current[name] = (value, ts)
        if self.born and not dev.born:
            out.append(self._dbirth(dev, now))
            if self.store.pending().get(dev.name):
                out.append(HistoryReady())
        else:
            full = self.options.refresh > 0 and now - dev.last_full >= self.options.refresh
            out += self._device_data(dev, now, full=full)
        return out + self._node_data(now)

    def _device_data(self, dev: _Device, now: float, *, full: bool = False) -> list[Action]:
        entries: list[Entry] = []
        for d in dev.metrics.defs:
            if d.name not in dev.current:
                continue
            value, ts = dev.current[d.name]
            if full or d.name not in dev.reported or changed(d, dev.reported[d.name], value):
                entries.append((d, value, ts or _ms(now)))
                dev.reported[d.name] = value
        if full:
            dev.last_full = now
        if not entries:
            return []
        if dev.born:
            return [
                Publish(
                    self.topic("DDATA", dev.name),
                    encode(entries, timestamp=_ms(now), seq=self._next_seq(), birth=False),
                )
            ]
        if not self.born:
            self.store.append(dev.name, [(d.name, value, ts) for d, value, ts in entries], _ms(now))
        return []

    def _node_data(self, now: float) -> list[Action]:
        if not self.born:
            return []
        values = self._node_values()
        entries: list[Entry] = [
            (d, values[d.name], _ms(now))
            for d in self.node.defs
            if d.alias is not None and self._node_reported.get(d.name) != values[d.name]
        ]
        if not entries:
            return []
        self._node_reported.update({d.name: v for d, v, _ in entries})
        return [Publish(self.topic("NDATA"), encode(entries, timestamp=_ms(now), seq=self._next_seq(), birth=False))]

    def on_tick(self, now: float) -> list[Action]:
        """Called about once a second: drop buffered data past its age."""
        self.store.expire(_ms(now))
        return self._node_data(now)

    # -- commands -----------------------------------------------------------------------------------------

    def on_message(self, topic: str, data: bytes, now: float, actor: str = "") -> list[Action]:
        parts = topic.split("/")
        if len(parts) == 3 and parts[:2] == [NAMESPACE, "STATE"]:
            return self._on_state(parts[2], data, now)
        if parts[:2] != [NAMESPACE, self.options.group] or len(parts) < 4 or parts[3] != self.options.node:
            return []
        try:
            payload = decode_command(data)
        except BadCommandPayload:
            return []  # logged by the driver; nothing to answer (the spec defines no acknowledgement)
        if parts[2] == "NCMD" and len(parts) == 4:
            for m in payload.metrics:
                if (m.name == REBIRTH) and m.field == "boolean_value" and m.raw is True and self.born:
                    return self._births(now)  # stops DATA at once: everything after is new
            return []
        if parts[2] == "DCMD" and len(parts) == 5:
            return self._on_dcmd(parts[4], payload.timestamp, payload.metrics, now)
        return []

    def _on_dcmd(self, name: str, ts: int | None, metrics: Sequence[CommandMetric], now: float) -> list[Action]:
        dev = self.devices.get(name)
        if dev is None or not dev.born:
            return []  # commands for dead or unborn devices are ignored (commands-dcmd-*)
        command: Command | None = None
        writes: dict[str, float | int | str] = {}
        try:
            for m in metrics:
                defn = (
                    dev.metrics.by_alias.get(m.alias) if m.alias is not None else dev.metrics.by_name.get(m.name or "")
                )
                if defn is None:
                    continue  # unknown names are ignored (commands-dcmd-metric-name)
                if not self.commands_allowed:
                    raise PermissionError("commands are refused on a plaintext connection (--allow-plaintext-commands)")
                stamp = m.timestamp if m.timestamp is not None else ts
                if stamp is not None and _ms(now) - stamp > self.options.command_max_age * 1000:
                    age = (_ms(now) - stamp) / 1000
                    raise PermissionError(
                        f"{defn.name}: command is {age:.1f} s old (limit {self.options.command_max_age:g} s)"
                    )
                value = command_value(defn, m)
                if defn.command is not None:
                    if value is True:
                        if command is not None and command is not defn.command:
                            raise PermissionError("one command per DCMD")
                        command = defn.command
                elif defn.writable and defn.point is not None:
                    if isinstance(value, bool):
                        raise ValueError(f"{defn.name}: a boolean is not a parameter value")
                    writes[defn.point.key] = value
                else:
                    raise PermissionError(f"{defn.name} is not writable")
        except (PermissionError, ValueError) as exc:
            return self.refuse(name, str(exc), now)
        if command is not None and writes:
            return self.refuse(name, "a DCMD carries either a command or parameter writes, not both", now)
        if command is None and not writes:
            return []
        return [CommandRequest(name, command, writes)]

    def refuse(self, name: str, reason: str, now: float, *, failed: bool = False) -> list[Action]:
        """Report a refused (nothing sent) or failed (sent, not as asked) command in the device's DDATA."""
        dev = self.devices[name]
        dev.refused += 1
        self.refused += 1
        return self.command_done(name, f"{'failed' if failed else 'refused'}: {reason}", now, count=True)

    def command_done(self, name: str, text: str, now: float, *, count: bool = False) -> list[Action]:
        dev = self.devices[name]
        dev.current[LAST_COMMAND] = (text, _ms(now))
        if count:
            dev.current[REFUSED] = (dev.refused, _ms(now))
        return self._device_data(dev, now) + self._node_data(now)

    # -- primary host ---------------------------------------------------------------------------------------

    def _on_state(self, host: str, data: bytes, now: float) -> list[Action]:
        if host != self.options.primary_host:
            return []
        try:
            state = json.loads(data.decode("utf-8"))
            online, ts = bool(state["online"]), int(state["timestamp"])
        except (ValueError, KeyError, TypeError, UnicodeDecodeError):
            return []
        if self.last_state_ts is not None and ts < self.last_state_ts:
            return []  # an older STATE is ignored (host-offline-timestamp)
        self.last_state_ts = ts
        if online:
            self.host_online_ts = ts
            if self.connected and not self.born:
                return self._births(now)
            return []
        if self.born:
            self.on_disconnected()
            return [self.ndeath(), Reconnect()]
        if self.connected and self.options.servers > 1:
            self.on_disconnected()
            return [Reconnect()]  # offline on this server: walk to the next (primary-application-...-walk)
        return []
