"""A host's DCMD checked before anything runs (SPARKPLUG.md section 6): pure functions, no I/O.

In this order: the size, before the payload is parsed; a Sparkplug B payload; for each metric of the device
(by name or alias; unknown ones are ignored, as the specification says): the plaintext guard, a timestamp (the
metric's, else the payload's; none at all is refused), not older than ``command_max_age`` and not further in the
future than ``command_max_skew``, the value type of the BIRTH, writable by the fleet file's ``remote`` table;
then one command, or parameter writes, not both.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from starterbus.core.status import Command
from starterbus.serve.actions import SessionOptions
from starterbus.serve.metrics import MetricDef, MetricSet
from starterbus.serve.payloads import BadCommandPayload, CommandMetric, CommandPayload, command_value, decode_command


class CommandRefused(Exception):
    """A command refused before it reached the guarded path: nothing was sent."""

    def __init__(self, reason: str, asked: str = "?") -> None:
        super().__init__(reason)
        self.asked = asked


@dataclass(frozen=True, slots=True)
class Checked:
    """What an accepted DCMD asks (nothing at all: ``ignored`` says why)."""

    asked: str
    command: Command | None = None
    writes: dict[str, float | int | str] = field(default_factory=dict)
    ignored: str = ""


def parse(data: bytes, options: SessionOptions) -> CommandPayload:
    """The payload of an NCMD/DCMD; its size is checked first, so a huge one costs no parsing."""
    if len(data) > options.command_max_bytes:
        raise CommandRefused(
            f"{len(data)} bytes, more than the limit of {options.command_max_bytes} (--command-max-bytes); not parsed"
        )
    try:
        return decode_command(data)
    except BadCommandPayload as exc:
        raise CommandRefused(str(exc)) from None


def _find(metrics: MetricSet, m: CommandMetric) -> MetricDef | None:
    return metrics.by_alias.get(m.alias) if m.alias is not None else metrics.by_name.get(m.name or "")


def describe(metrics: MetricSet, sent: Sequence[CommandMetric]) -> str:
    """``Device Control/Start=True, Parameters/ramp_time=20``: what a DCMD asked, for the audit log."""
    parts = []
    for m in sent:
        defn = _find(metrics, m)
        name = defn.name if defn is not None else m.name or f"alias {m.alias}"
        parts.append(f"{name}={m.raw!r}" if m.field is not None else f"{name}=null")
    return ", ".join(parts) or "no metrics"


def _check_time(defn: MetricDef, stamp: int | None, options: SessionOptions, now_ms: int) -> None:
    if stamp is None:
        raise ValueError(f"{defn.name}: no timestamp (a DCMD must carry one, in the metric or the payload)")
    ahead = (stamp - now_ms) / 1000
    if ahead > options.command_max_skew:
        raise ValueError(
            f"{defn.name}: dated {ahead:.1f} s in the future (clock skew limit {options.command_max_skew:g} s,"
            " --command-max-skew)"
        )
    age = -ahead
    if age > options.command_max_age:
        raise ValueError(f"{defn.name}: command is {age:.1f} s old (limit {options.command_max_age:g} s)")


def check_dcmd(
    metrics: MetricSet, payload: CommandPayload, options: SessionOptions, now_ms: int, *, allowed: bool
) -> Checked:
    """The command or writes a DCMD asks for; :class:`CommandRefused` with the reason otherwise. ``allowed``:
    commands may run on this connection (False: plaintext, refused)."""
    asked = describe(metrics, payload.metrics)
    command: Command | None = None
    writes: dict[str, float | int | str] = {}
    known = False
    try:
        for m in payload.metrics:
            defn = _find(metrics, m)
            if defn is None:
                continue  # unknown names are ignored (commands-dcmd-metric-name)
            known = True
            if not allowed:
                raise ValueError("commands are refused on a plaintext connection (--allow-plaintext-commands)")
            _check_time(defn, m.timestamp if m.timestamp is not None else payload.timestamp, options, now_ms)
            value = command_value(defn, m)
            if defn.command is not None:
                if value is True:
                    if command is not None and command is not defn.command:
                        raise ValueError("one command per DCMD")
                    command = defn.command
            elif defn.point is not None and defn.point.writable:
                if isinstance(value, bool):
                    raise ValueError(f"{defn.name}: a boolean is not a parameter value")
                if not defn.writable:
                    raise ValueError(
                        f"{defn.name}: the fleet file does not allow remote writes of {defn.point.key} "
                        "(remote.write of this device)"
                    )
                writes[defn.point.key] = value
            else:
                raise ValueError(f"{defn.name} is not writable")
    except ValueError as exc:
        raise CommandRefused(str(exc), asked) from None
    if command is not None and writes:
        raise CommandRefused("a DCMD carries either a command or parameter writes, not both", asked)
    if not known:
        return Checked(asked, ignored="no metric of this device by these names or aliases")
    if command is None and not writes:
        return Checked(asked, ignored="nothing asked (a command metric must be true)")
    return Checked(asked, command, writes)
