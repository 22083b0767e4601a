"""Messages from the host for :class:`~starterbus.serve.session.EdgeSession`, a mixin over the session's state:
NCMD and DCMD checked by :mod:`starterbus.serve.commands`, every outcome published (``Last Command`` and
``Command Count`` + 1, even when the text repeats), every refusal and ignored command handed to the driver for
the audit log; the primary host's STATE (SPARKPLUG.md section 7)."""

from __future__ import annotations

import json

from starterbus.serve.actions import Action, CommandAudit, CommandRequest, Publish, Reconnect, SessionOptions
from starterbus.serve.commands import CommandRefused, check_dcmd, describe, parse
from starterbus.serve.device_state import DeviceState
from starterbus.serve.metrics import COMMAND_COUNT, LAST_COMMAND, REBIRTH, REFUSED, MetricSet

NAMESPACE = "spBv1.0"
_OUTCOME = frozenset({LAST_COMMAND, COMMAND_COUNT})  # published with every outcome, changed or not


def _ms(t: float) -> int:
    return int(t * 1000)


class SessionCommands:
    options: SessionOptions
    node: MetricSet
    devices: dict[str, DeviceState]
    born: bool
    connected: bool
    last_state_ts: int | None
    host_online_ts: int | None
    refused: int
    commands_allowed: bool
    node_commands: int
    node_last_command: str

    # the session's publishing, defined by EdgeSession
    def _births(self, now: float) -> list[Action]:
        raise NotImplementedError

    def _node_data(self, now: float) -> list[Action]:
        raise NotImplementedError

    def _may_birth(self, now: float) -> bool:
        raise NotImplementedError

    def ndeath(self) -> Publish:
        raise NotImplementedError

    def on_disconnected(self) -> None:
        raise NotImplementedError

    def _device_data(
        self, dev: DeviceState, now: float, *, full: bool = False, always: frozenset[str] = frozenset()
    ) -> list[Action]:
        raise NotImplementedError

    def on_message(self, topic: str, data: bytes, now: float) -> list[Action]:
        parts = topic.split("/")
        if len(parts) == 3 and parts[:2] == [NAMESPACE, "STATE"]:
            return self._on_state(parts[2], data, now)
        if parts[:2] != [NAMESPACE, self.options.group] or len(parts) < 4 or parts[3] != self.options.node:
            return []
        if parts[2] == "NCMD" and len(parts) == 4:
            return self._on_ncmd(topic, data, now)
        if parts[2] == "DCMD" and len(parts) == 5:
            return self._on_dcmd(parts[4], topic, data, now)
        return []

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
            return self._births(now) if self._may_birth(now) else []
        if self.born:
            self.on_disconnected()
            return [self.ndeath(), Reconnect()]
        if self.connected and self.options.servers > 1:
            self.on_disconnected()
            return [Reconnect()]  # offline on this server: walk to the next (primary-application-...-walk)
        return []

    def _on_ncmd(self, topic: str, data: bytes, now: float) -> list[Action]:
        try:
            payload = parse(data, self.options)
        except CommandRefused as exc:
            self.refused += 1
            return self._node_outcome(topic, exc.asked, f"refused: {exc}", now)
        asked = describe(self.node, payload.metrics)
        if not any(m.name == REBIRTH and m.field == "boolean_value" and m.raw is True for m in payload.metrics):
            return self._node_outcome(topic, asked, "ignored: only Node Control/Rebirth = true is a node command", now)
        if not self.born:
            return [CommandAudit(None, topic, asked, "ignored: the node is not born")]
        self.node_commands += 1
        self.node_last_command = "rebirth: ok"
        return self._births(now)  # stops DATA at once: everything after is new

    def _node_outcome(self, topic: str, asked: str, text: str, now: float) -> list[Action]:
        """An NCMD refused or ignored: in the node's NDATA (``Node Info/Last Command``, count + 1), audited."""
        self.node_commands += 1
        self.node_last_command = text
        return [*self._node_data(now), CommandAudit(None, topic, asked, text)]

    def _on_dcmd(self, name: str, topic: str, data: bytes, now: float) -> list[Action]:
        dev = self.devices.get(name)
        if dev is None or not dev.born:  # ignored (commands-dcmd-*): no DATA for it; audited
            why = "no such device" if dev is None else "the device is offline or not born"
            return [CommandAudit(name if dev is not None else None, topic, "?", f"ignored: {why}")]
        try:
            payload = parse(data, self.options)
            checked = check_dcmd(dev.metrics, payload, self.options, _ms(now), allowed=self.commands_allowed)
        except CommandRefused as exc:
            return self.refuse(name, str(exc), now, audit=(topic, exc.asked))
        if checked.ignored:
            text = f"ignored: {checked.ignored}"
            return [*self.command_done(name, text, now), CommandAudit(name, topic, checked.asked, text)]
        return [CommandRequest(name, checked.command, checked.writes, topic, checked.asked)]

    def refuse(
        self, name: str, reason: str, now: float, *, failed: bool = False, audit: tuple[str, str] | None = None
    ) -> list[Action]:
        """Report a refused (nothing sent) or failed (sent, not as asked) command in the device's DDATA; with
        ``audit`` (topic, what was asked) also hand the refusal to the audit log."""
        dev = self.devices[name]
        dev.refused += 1
        self.refused += 1
        text = f"{'failed' if failed else 'refused'}: {reason}"
        out = self.command_done(name, text, now)
        if audit is not None:
            out.append(CommandAudit(name, audit[0], audit[1], text))
        return out

    def command_done(self, name: str, text: str, now: float) -> list[Action]:
        """Publish a command's outcome: ``Last Command`` and ``Command Count`` + 1, even if the text is the same."""
        dev = self.devices[name]
        dev.commands += 1
        dev.current[LAST_COMMAND] = (text, _ms(now))
        dev.current[COMMAND_COUNT] = (dev.commands, _ms(now))
        dev.current[REFUSED] = (dev.refused, _ms(now))
        return self._device_data(dev, now, always=_OUTCOME) + self._node_data(now)
