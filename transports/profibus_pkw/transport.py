"""The ``profibus-pkw`` transport: status and commands through PZD, parameters and measurements through PKW.

Its URL (``profibus-pkw+sim://`` or ``profibus-pkw+gateway://``) and parameters: :mod:`.url`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

from starterbus.core import (
    CW_START,
    Capability,
    Command,
    ConfigurationError,
    ControlWordState,
    DecodeError,
    DeviceUrl,
    Kind,
    PlannedRequest,
    PointDef,
    PollResult,
    PollTask,
    Profile,
    Reading,
    SimulatedStarter,
    Status,
    Transport,
    status_with_currents,
)
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, Ppo, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import NO_TASK, PkwRequest, hex_text, output_words, pkw_request
from starterbus.transports.profibus_pkw.driver.channels import Channel, GatewayChannel, SimChannel, get_slave
from starterbus.transports.profibus_pkw.driver.link import CyclicLink
from starterbus.transports.profibus_pkw.driver.poll import StationPoll
from starterbus.transports.profibus_pkw.master.handshake import PkwEngine
from starterbus.transports.profibus_pkw.master.station import FreshInputs, PkwTask, StationRequest, StationTicket
from starterbus.transports.profibus_pkw.settings import profibus_settings
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave
from starterbus.transports.profibus_pkw.url import LinkSettings

PPO1_CAPABILITIES = frozenset(Capability)
PPO3_CAPABILITIES = frozenset({Capability.STATUS, Capability.COMMANDS})
ACT_SCALE = 0.1  # PZD ACT: phase A current in 0.1 A (docs/manuals.md#profibus-golden-vectors)


class ProfibusPkwTransport(Transport):
    """One DP slave through one channel. Thread-safe (the cycle driver serialises the channel)."""

    name = PROTOCOL

    def __init__(self, url: DeviceUrl, profile: Profile, settings: LinkSettings | None = None) -> None:
        super().__init__(url, profile)
        self.settings = settings or LinkSettings.from_url(url, profile)
        self.ppo = self.settings.ppo
        self.link: CyclicLink | None = None
        self.control = ControlWordState()
        self._errors = profibus_settings(profile).errors

    # -- lifecycle -----------------------------------------------------------------------------------------

    def make_channel(self) -> Channel:
        s = self.settings
        if s.variant == "sim":
            if s.name:
                slave = get_slave(s.name)
                if slave.ppo is not s.ppo:
                    raise ConfigurationError(
                        f"{self.url.text}: simulated slave {s.name!r} is configured for {slave.ppo.name}, "
                        f"the URL asks for {s.ppo.name}"
                    )
                if slave.profile.name != self.profile.name:
                    raise ConfigurationError(
                        f"{self.url.text}: simulated slave {s.name!r} is a {slave.profile.display_name}, "
                        f"not a {self.profile.display_name}"
                    )
            else:
                slave = SimulatedDpSlave(SimulatedStarter(self.profile), s.ppo, latency=s.latency)
            return SimChannel(slave)
        return GatewayChannel(
            s.host,
            s.port,
            s.ppo,
            out=s.out,
            inp=s.inp,
            unit=s.unit,
            input_function=s.in_fc,
            timeout=min(s.limits.timeout, 5.0),
        )

    def _open(self) -> None:
        s = self.settings
        engine = PkwEngine(self._errors, s.limits)
        link = CyclicLink(self.make_channel(), engine, cycle=s.cycle, hold=s.hold, pulse=s.pulse, name=self.url.text)
        try:
            word = link.open()
        except BaseException:
            link.channel.close()
            raise
        # The words of the next command: a bus master sets bus control (bit 3) with every command; the run level
        # is the one in force (or, while the link is passive, the motor's state), so "reset" or "take bus control"
        # never changes it by accident.
        running = link.motor_running() if word is None else bool(word & CW_START)
        self.control = ControlWordState(bus_control=True, run=running)
        self.link = link

    def _close(self) -> None:
        link, self.link = self.link, None
        if link is not None:
            link.close()

    def _link(self) -> CyclicLink:
        if self.link is None:
            raise self._not_open()
        return self.link

    # -- what it can do --------------------------------------------------------------------------------

    @property
    def capabilities(self) -> frozenset[Capability]:
        return PPO1_CAPABILITIES if self.ppo is Ppo.PPO1 else PPO3_CAPABILITIES

    def describe(self) -> str:
        where = f" station {self.settings.station}" if self.settings.station is not None else ""
        return f"{self.url.text}{where}"

    def _why_not(self, capability: Capability) -> str:
        if not self.ppo.has_pkw and capability not in PPO3_CAPABILITIES:
            return "PPO3 carries no PKW area (use ppo=1 for parameters and measurements)"
        return super()._why_not(capability)

    def _index(self, point: PointDef) -> int:
        index: int | None = point.addresses.get(PROTOCOL)
        if index is None:
            raise self.unsupported(f"reach {point.key}", f"{point.key} has no Profibus (INDL) address")
        if not 0 <= index <= 0xFF:
            raise ConfigurationError(
                f"{self.profile.source}: {point.key}: Profibus address {index:#x} does not fit INDL"
            )
        return index

    def request_for(self, point: PointDef, raw: int | None = None) -> PkwRequest:
        """The PKW task that reads (``raw`` None) or writes a point."""
        index = self._index(point)
        if raw is not None:
            if point.kind is not Kind.PARAMETER:
                raise self.unsupported(f"write {point.key}", "measurements are read-only")
            return pkw_request(TaskCode.WRITE_PARAMETER, index, raw)
        task = TaskCode.READ_MEASUREMENT if point.kind is Kind.MEASUREMENT else TaskCode.READ_PARAMETER
        return pkw_request(task, index)

    # -- operations ----------------------------------------------------------------------------------------

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        requests = [(p, self.request_for(p)) for p in points]
        link = self._link()
        readings = []
        for point, request in requests:
            job = link.pkw(request, f"read {point.key} ({point.address})")
            assert job.response is not None
            readings.append(Reading(point, job.response.pwe))
        return readings

    def _write_parameter(self, point: PointDef, raw: int) -> None:
        request = self.request_for(point, raw)
        job = self._link().pkw(request, f"write {point.key} ({point.address}) = {raw}")
        assert job.response is not None
        if job.response.pwe != raw:
            raise DecodeError(
                f"the slave answered the write of {raw} to {point.key} with {job.response.pwe}",
                bytes([job.response.ind >> 8, job.response.ind & 0xFF, job.response.pwe >> 8, job.response.pwe & 0xFF]),
                "PWE",
            )

    def _read_status(self) -> Status:
        return self._status(self._link().inputs(self.settings.limits.timeout))

    def _status(self, words: tuple[int, ...]) -> Status:
        zsw, act = (words[2], words[3]) if self.ppo is Ppo.PPO1 else (words[0], words[1])
        return status_with_currents(self.profile, zsw, [act], source=PROTOCOL, scale=ACT_SCALE, extra_raw={"act": act})

    def _send_command(self, command: Command) -> None:
        link = self._link()
        words = self.control.apply(command)
        link.send_control(words, self.settings.limits.timeout)

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        """The poll as a task on the process's scheduler (the station's link is on it: a simulated slave, a
        gateway's connection); None for a third-party channel on a loop of its own (the fleet gives it a thread)."""
        link = self._link()
        if not link.multiplexed:
            return None
        limits = self.settings.limits
        requests: list[StationRequest] = [FreshInputs(limits.timeout)] if status else []
        requests += [PkwTask(self.request_for(p), f"read {p.key} ({p.address})") for p in points]

        def finish(tickets: list[StationTicket]) -> PollResult:
            words = cast("tuple[int, ...]", tickets[0].result) if status else None
            readings = []
            for point, ticket in zip(points, tickets[1:] if status else tickets, strict=True):
                assert ticket.job is not None and ticket.job.response is not None
                readings.append(Reading(point, ticket.job.response.pwe))
            return PollResult(self._status(words) if words is not None else None, readings)

        bound = (limits.timeout + 1.0 + 4 * max(self.settings.cycle, 0.001)) * max(1, len(requests))
        return StationPoll(link, requests, finish, bound)

    def plan(self, points: Sequence[PointDef], status: bool) -> list[PlannedRequest]:
        """What :meth:`poll` sends: the status comes in every cycle's inputs (no telegram of its own); each point is
        a PKW task, a clear and a task telegram. On an open link, the fence reads its handshake sends first (the
        session's start chain, once); not open (``poll --plan``), every round's."""
        planned = [PlannedRequest("read status (in every DP cycle's inputs)", 1, frames=0)] if status else []
        if not points:
            return planned
        fences = [] if self.link is None else self.link.fences_before(self.request_for(points[0]))
        planned += [PlannedRequest(f"fence read INDL {fence.indl:#04x}", 1, frames=2) for fence in fences]
        planned += [PlannedRequest(f"read {point.key} ({point.address})", 1, frames=2) for point in points]
        return planned

    def _fences_before(self, request: PkwRequest) -> list[PkwRequest]:
        """The fence reads before ``request``: the open link's engine's, else a new session's (its start chain)."""
        if self.link is not None:
            return self.link.fences_before(request)
        return PkwEngine(self._errors, self.settings.limits).fences_before(request)

    # -- previews (--dry-run) -----------------------------------------------------------------------------

    def _telegram_hex(self, pkw: PkwRequest, stw: int | None) -> str:
        """An output telegram as text; ``stw`` None: the link is passive on PZD, so the PZD words are not written
        and stay as they are in the output area (``-- --`` each)."""
        words = output_words(self.ppo, pkw, 0 if stw is None else stw)
        written = words if stw is not None else words[:2] if self.ppo is Ppo.PPO1 else ()
        text = [hex_text(b"".join(w.to_bytes(2, "big") for w in written))] if written else []
        return " ".join(text + ["-- --"] * (len(words) - len(written)))

    def _preview_write(self, point: PointDef, raw: int) -> list[str]:
        """The output telegrams of a write: the fence reads the handshake sends first (the session's start chain,
        or one while the INDL is quarantined), each after a clear cycle ("no task"), then the clear cycle and the
        task repeated until answered. The control word is the one the link puts in the output area, or ``-- --``
        while it is passive (the area keeps the word in force)."""
        request = self.request_for(point, raw)
        stw = None if self.link is None else self.link.control  # not open: a new session adopts the word in force
        clear = self._telegram_hex(NO_TASK, stw)
        fences = self._fences_before(request)
        return [text for task in (*fences, request) for text in (clear, self._telegram_hex(task, stw))]

    def _preview_command(self, command: Command) -> list[str]:
        """The output telegrams of a command, one per control word (each held for ``hold`` exchanges)."""
        state = ControlWordState(self.control.bus_control, self.control.run)
        return [self._telegram_hex(NO_TASK, word) for word in state.apply(command)]


class ProfibusSimTransport(ProfibusPkwTransport):
    """``profibus-pkw+sim://`` (the same transport: since the gateway runs on the Modbus TCP engine, both offer poll
    tasks; the name is kept for the plugin and for callers that import it)."""
