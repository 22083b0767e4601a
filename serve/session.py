"""The Sparkplug B edge node as a sans-IO state machine: samples, connection events, commands and times in,
messages to publish (and commands to run through the guarded path) out. No sockets, threads or clocks here.

Decisions (SPARKPLUG.md):
- bdSeq goes +1 once per CONNECT actually sent: :meth:`EdgeSession.next_will` gives the Will of the next CONNECT,
  the same again after an attempt that never reached the broker (no TCP or TLS connection), a new one once
  :meth:`EdgeSession.connect_sent` (or the CONNACK) said the last one went out. The driver persists it before
  the CONNECT, so it also advances across restarts (pitfalls: Restarts), and sets the Will before every connect
  (pitfalls: Auto-reconnect).
- Every session starts with NBIRTH and the DBIRTH of every online device before any DATA: the births wait until
  every device was polled once (answered or not; at most ``first_round_wait`` after the CONNACK) and, with a
  primary host, for its online STATE. A device that answers later gets its DBIRTH then (allowed mid-session).
- seq is one counter for NBIRTH/DBIRTH/DDATA/NDATA/DDEATH, 0 in every NBIRTH, wrapping 255 -> 0.
- While no session is up (no broker, or the primary host offline) polling goes on: changed values are kept in a
  bounded store (``history.HistoryStore``, injected: in memory, or ``store.SqliteStore`` on disk); the oldest
  beyond the bounds are dropped and counted (``Node Info/Buffered Messages Dropped``). Once a device is born
  again (``HistoryReady``), :meth:`EdgeSession.history` hands its records out in order, in batches, as DDATA
  with is_historical=true; the driver reports them written with :meth:`EdgeSession.history_sent`.
- Commands are checked by :mod:`starterbus.serve.commands` (size before parsing, plaintext, timestamps, types,
  writability). Every outcome of a DCMD to a born device (executed, refused, failed, ignored) is published as
  ``Device Control/Last Command`` with ``Device Control/Command Count`` + 1, of an NCMD as ``Node Info/Last
  Command`` and ``Node Info/Command Count``; every refusal and ignored command is handed to the driver for the
  audit log (:class:`CommandAudit`). DCMDs for unknown or unborn devices are ignored (audited, not published).
"""

from __future__ import annotations

from collections.abc import Mapping

from starterbus.core.errors import ConfigurationError
from starterbus.fleet.config import FleetConfig
from starterbus.fleet.poller import Sample
from starterbus.serve.actions import (
    Action,
    CommandAudit,
    CommandRequest,
    HistoryReady,
    Publish,
    Reconnect,
    SessionOptions,
)
from starterbus.serve.device_state import DeviceState
from starterbus.serve.history import Bounds, HistoryStore, MemoryStore
from starterbus.serve.metrics import (
    BAD,
    BDSEQ,
    GOOD,
    NODE_COMMAND_COUNT,
    NODE_DEVICES_ONLINE,
    NODE_DROPPED,
    NODE_LAST_COMMAND,
    NODE_REFUSED,
    REBIRTH,
    Aliases,
    MetricDef,
    MetricSet,
    Scalar,
    device_metrics,
    initial_values,
    node_metrics,
    sample_values,
)
from starterbus.serve.payloads import Entry, encode, encode_fields, encode_ndeath
from starterbus.serve.session_commands import NAMESPACE, SessionCommands

__all__ = [
    "Action",
    "CommandAudit",
    "CommandRequest",
    "EdgeSession",
    "HistoryReady",
    "Publish",
    "Reconnect",
    "SessionOptions",
]


def _ms(t: float) -> int:
    return int(t * 1000)


class EdgeSession(SessionCommands):
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
        self.devices = {name: DeviceState(name, metrics) for name, metrics in devices.items()}
        for dev in self.devices.values():
            dev.current.update({k: (v, 0) for k, v in initial_values().items()})
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
        self.node_commands = 0
        self.node_last_command = ""
        self.online = 0  # devices online now
        self.published = 0
        self.commands_allowed = options.commands_allowed
        self.topic_prefix = f"{NAMESPACE}/{options.group}"
        self._topics: dict[tuple[str, str | None], str] = {}  # (kind, device) -> topic, built once
        self._node_reported: dict[str, Scalar | None] = {}
        self._node_key: tuple[object, ...] | None = None  # _node_key() when _node_reported was last complete
        self._will_pending = False  # the Will of next_will() is not yet sent in a CONNECT
        self._connected_at: float | None = None

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
        topic = self._topics.get((kind, device))
        if topic is None:
            base = f"{self.topic_prefix}/{kind}/{self.options.node}"
            topic = self._topics[kind, device] = f"{base}/{device}" if device is not None else base
        return topic

    def subscriptions(self) -> list[tuple[str, int]]:
        subs = [(self.topic("NCMD"), 1), (self.topic("DCMD", "+"), 1)]
        if self.options.primary_host:
            subs.append((f"{NAMESPACE}/STATE/{self.options.primary_host}", 1))
        return subs

    # -- connection ---------------------------------------------------------------------------------------

    def next_will(self) -> Publish:
        """Before every CONNECT attempt: the NDEATH to register as the Will, with bdSeq + 1 (wrapping 255 -> 0) if
        the last one was sent in a CONNECT, else the same bdSeq again."""
        if not self._will_pending:
            self.bdseq = (self.bdseq + 1) % 256
            self._will_pending = True
        self.connected = self.born = False
        return self.ndeath()

    def connect_sent(self) -> None:
        """The CONNECT carrying the Will of :meth:`next_will` went out: the next connection takes a new bdSeq."""
        self._will_pending = False

    def ndeath(self) -> Publish:
        return Publish(self.topic("NDEATH"), encode_ndeath(self.bdseq), qos=1)

    def on_connected(self, now: float) -> list[Action]:
        """The subscriptions are acknowledged: births now, or after the primary host says it is online."""
        self.connect_sent()
        self.connected = True
        self.host_online_ts = None
        self._connected_at = now
        return self._births(now) if self._may_birth(now) else []

    def _may_birth(self, now: float) -> bool:
        """Connected, not born, the primary host (if any) online, and every device polled once (or waited long)."""
        if not self.connected or self.born or (self.options.primary_host and self.host_online_ts is None):
            return False
        waited = self._connected_at is not None and now - self._connected_at >= self.options.first_round_wait
        return waited or all(dev.seen for dev in self.devices.values())

    def on_disconnected(self) -> None:
        self._connected_at = None
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
            NODE_LAST_COMMAND: self.node_last_command,
            NODE_COMMAND_COUNT: self.node_commands,
        }

    def _node_state(self) -> tuple[object, ...]:
        """What the node's NDATA metrics depend on: unchanged since the NBIRTH or NDATA that reported it, so
        is every one of them (every sample asks; this spares building and comparing them)."""
        return (self.online, self.store.dropped, self.refused, self.node_last_command, self.node_commands)

    @property
    def dropped(self) -> int:
        """Buffered DDATA dropped: beyond a bound, not storable, or no longer publishable."""
        return self.store.dropped

    def _births(self, now: float) -> list[Action]:
        self.seq = 0
        self.born = True
        values = self._node_values()
        self._node_reported = dict(values)
        self._node_key = self._node_state()
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

    def _dbirth(self, dev: DeviceState, now: float) -> Publish:
        entries: list[Entry] = []
        for d in dev.metrics.defs:
            value, ts = dev.current.get(d.name, (None, 0))
            entries.append((d, value, ts or _ms(now)))
        dev.born = True
        dev.reported = {d.name: dev.current.get(d.name, (None, 0))[0] for d in dev.metrics.defs}
        dev.quality = {d.name: self._quality(dev, d) for d in dev.metrics.defs if d.polled}
        dev.settle()
        dev.last_full = now
        payload = encode(entries, timestamp=_ms(now), seq=self._next_seq(), birth=True, quality=dev.quality)
        return Publish(self.topic("DBIRTH", dev.name), payload)

    @staticmethod
    def _quality(dev: DeviceState, d: MetricDef) -> int:
        """Good when read in the device's last good poll; bad when not read then (null, or an older value)."""
        return GOOD if d.name in dev.fresh else BAD

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
        dev.seen = True
        if dev.online != sample.online:
            self.online += 1 if sample.online else -1
        dev.online = sample.online
        if not sample.online:
            if dev.born:
                dev.born = False
                payload = encode([], timestamp=_ms(now), seq=self._next_seq(), birth=False)
                out.append(Publish(self.topic("DDEATH", dev.name), payload))
            return out + self._node_data(now) + self._births_due(now)
        ts = _ms(sample.time)
        values = sample_values(sample, dev.metrics)
        fresh = dev.fresh = set(values)
        if None in values.values():  # a status bit the model does not have
            fresh -= {name for name, value in values.items() if value is None}
        full = self.options.refresh > 0 and now - dev.last_full >= self.options.refresh
        settled = dev.born and not full and dev.settled == fresh and len(fresh) == len(values)
        dev.keep(values, ts, settled=settled)
        if settled:
            metrics = dev.report_settled(values, ts or _ms(now))  # only this sample's values can have changed
            if metrics:
                payload = encode_fields(metrics, timestamp=_ms(now), seq=self._next_seq())
                out.append(Publish(self.topic("DDATA", dev.name), payload))
        elif self.born and not dev.born:
            out.append(self._dbirth(dev, now))
            if self.store.pending().get(dev.name):
                out.append(HistoryReady())
        else:
            out += self._device_data(dev, now, full=full)
        out += self._node_data(now)
        if not self.born:  # born: no births are due
            out += self._births_due(now)
        return out

    def _births_due(self, now: float) -> list[Action]:
        return self._births(now) if self._may_birth(now) else []

    def _device_data(
        self, dev: DeviceState, now: float, *, full: bool = False, always: frozenset[str] = frozenset()
    ) -> list[Action]:
        """DDATA of what changed (``full``: everything; ``always``: these metrics whether changed or not)."""
        now_ms = _ms(now)
        entries, quality = dev.changes(now_ms, full=full, always=always)
        if full:
            dev.last_full = now
        if not entries:
            return []
        if dev.born:
            payload = encode(entries, timestamp=now_ms, seq=self._next_seq(), birth=False, quality=quality)
            return [Publish(self.topic("DDATA", dev.name), payload)]
        polled = [(d.name, value, ts) for d, value, ts in entries if d.polled]  # history is of the device's values
        if not self.born and polled:
            self.store.append(dev.name, polled, now_ms)
        return []

    def _node_data(self, now: float) -> list[Action]:
        if not self.born:
            return []
        state = self._node_state()
        if state == self._node_key:
            return []
        values = self._node_values()
        entries: list[Entry] = [
            (d, values[d.name], _ms(now))
            for d in self.node.defs
            if d.alias is not None and self._node_reported.get(d.name) != values[d.name]
        ]
        self._node_key = state  # reported as it is now once these are
        if not entries:
            return []
        self._node_reported.update({d.name: v for d, v, _ in entries})
        return [Publish(self.topic("NDATA"), encode(entries, timestamp=_ms(now), seq=self._next_seq(), birth=False))]

    def on_tick(self, now: float) -> list[Action]:
        """Called about once a second: drop buffered data past its age; the births once the first round waited long."""
        self.store.expire(_ms(now))
        return self._node_data(now) + self._births_due(now)

    # -- messages from the host (NCMD, DCMD, STATE): session_commands.SessionCommands -------------------------
