"""What an edge session knows of one device, and which of its values a DDATA reports (report by exception):
:class:`~starterbus.serve.session.EdgeSession` keeps one :class:`DeviceState` each, its host commands in
:mod:`starterbus.serve.session_commands` read them."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

from starterbus.serve.metrics import BAD, BAND_MET, GOOD, MetricDef, MetricSet, Scalar, changed
from starterbus.serve.payloads import Entry
from starterbus.serve.schema import WRITERS


class _Unreported(enum.Enum):
    UNREPORTED = 0


UNREPORTED: Final = _Unreported.UNREPORTED  # ``reported.get(name, UNREPORTED)``: never published in this session

#: what :meth:`DeviceState.report_settled` needs of a metric: its name, the DDATA field naming it (``alias``, or
#: ``name`` for a metric without one) and its value, its value field and wire form (``schema.WRITERS``), the
#: float deadband as :func:`~starterbus.serve.metrics.changed` compares it, and the definition
_Slot = tuple[str, str, "int | str", str, Callable[[Any], object], float, MetricDef]


def _slot(d: MetricDef) -> _Slot:
    field_name, wire = WRITERS[d.datatype]
    key, ident = ("name", d.name) if d.alias is None else ("alias", d.alias)
    return (d.name, key, ident, field_name, wire, d.deadband * BAND_MET, d)


@dataclass(slots=True)
class DeviceState:
    """What the session knows of one device: its metrics, last values and what it published of them."""

    name: str
    metrics: MetricSet
    online: bool = False
    born: bool = False
    held: dict[str, tuple[Scalar | None, int]] = field(default_factory=dict)  # ``current``, but the last sample's
    reported: dict[str, Scalar | None] = field(default_factory=dict)
    last_full: float = 0.0
    refused: int = 0
    commands: int = 0  # outcomes published (Device Control/Command Count)
    seen: bool = False  # polled at least once (answered or not)
    fresh: set[str] = field(default_factory=set)  # polled metrics read in the last good poll
    quality: dict[str, int] = field(default_factory=dict)  # the Quality last published per metric
    #: ``fresh`` when every metric was last looked at (:meth:`changes`, or the DBIRTH); None: not since a change
    #: that :meth:`report_settled` does not see. While a sample's values are these metrics, none of them None,
    #: only they can have changed and no Quality can: :meth:`report_settled` looks at them alone.
    settled: set[str] | None = None
    _settled_slots: tuple[_Slot, ...] = ()
    _sampled: dict[str, Scalar | None] | None = None  # a settled sample's values (:meth:`keep`), not yet in held
    _sampled_ts: int = 0

    @property
    def current(self) -> dict[str, tuple[Scalar | None, int]]:
        """Metric name -> (value, acquisition time in ms) of every metric known of the device."""
        sampled = self._sampled
        if sampled is not None:
            held, ts = self.held, self._sampled_ts
            for name, value in sampled.items():
                held[name] = (value, ts)
            self._sampled = None
        return self.held

    def keep(self, values: dict[str, Scalar | None], ts: int, *, settled: bool) -> None:
        """A good sample's values, acquired at ``ts`` (ms), into :attr:`current`: at once, or, for a ``settled``
        one (:meth:`report_settled`), once :attr:`current` is read. A settled sample names the metrics the last
        one kept did, if that was settled too (``settled`` changes only after :attr:`current` was read): it
        replaces it whole, so a device's values are not copied at all while its samples stay settled."""
        if settled:
            self._sampled, self._sampled_ts = values, ts
            return
        current = self.current
        for name, value in values.items():
            current[name] = (value, ts)

    def settle(self) -> None:
        """Every metric was just looked at with ``fresh`` as it is: remember it (and the metrics it names)."""
        fresh = set(self.fresh)
        if fresh != self.settled:
            self._settled_slots = tuple(_slot(d) for d in self.metrics.defs if d.name in fresh)
        self.settled = fresh

    def changes(
        self, now_ms: int, *, full: bool = False, always: frozenset[str] = frozenset()
    ) -> tuple[list[Entry], dict[str, int]]:
        """What a DDATA reports of every metric (``full``: everything; ``always``: these metrics whether changed or
        not), and the Quality to attach to it, each marked reported.

        The per-metric work is inlined: equal values are never a change (see
        :func:`~starterbus.serve.metrics.changed`); a polled metric's Quality is good when read in the device's
        last good poll, bad when not (null, or an older value); it is needed only when not good, or good again."""
        entries: list[Entry] = []
        quality: dict[str, int] = {}
        current, reported, fresh, published_quality = self.current, self.reported, self.fresh, self.quality
        for d in self.metrics.defs:
            name = d.name
            held = current.get(name)
            if held is None:
                continue
            value, ts = held
            is_polled = d.polled
            q = (GOOD if name in fresh else BAD) if is_polled else GOOD
            q_changed = is_polled and published_quality.get(name) != q
            old = reported.get(name, UNREPORTED)
            if full or old is UNREPORTED or name in always or (old != value and changed(d, old, value)):
                entries.append((d, value, ts or now_ms))
                reported[name] = value
            elif q_changed:
                entries.append((d, value, ts or now_ms))
            else:
                continue
            if is_polled and (q_changed or q != GOOD):
                quality[name] = published_quality[name] = q
        self.settle()
        return entries, quality

    def report_settled(self, values: dict[str, Scalar | None], ts: int) -> list[dict[str, object]]:
        """:meth:`changes` for a sample whose values name the ``settled`` metrics, none of them None: only these
        can have changed, and no Quality can (each is good, as when they were settled). The changed ones marked
        reported, as the DDATA's metrics, ready for protobuf (``payloads.encode_fields``)."""
        reported = self.reported
        metrics: list[dict[str, object]] = []
        for name, key, ident, field_name, wire, band, d in self._settled_slots:
            value = values[name]
            old = reported.get(name, UNREPORTED)
            if old == value:
                continue
            kind = type(value)
            if (kind is float or kind is int) and type(old) is kind:  # changed()'s rule for numbers, inlined (hot)
                if not abs(float(value) - float(old)) >= band:  # type: ignore[arg-type]
                    continue
            elif old is not UNREPORTED and not changed(d, old, value):
                continue
            reported[name] = value
            metrics.append({"timestamp": ts, key: ident, field_name: wire(value)})
        return metrics
