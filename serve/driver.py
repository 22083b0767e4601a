"""The thin driver: runs an :class:`EdgeSession` on asyncio with paho-mqtt and an :class:`AsyncFleet`.

paho runs on the event loop through its external-loop hooks: its socket, non-blocking once connected, is
watched with ``add_reader`` (``add_writer`` only while the kernel's send buffer is full) and
``loop_read``/``loop_write``/``loop_misc`` do the work, so a burst of publishes costs no thread hand-off and is
written by one ``loop_write`` in the next turn of the loop. Only ``connect`` (TCP and the TLS handshake, which
block) runs in a worker thread. A new paho client is made for every connection, with the Will (NDEATH with the
new bdSeq) set before its CONNECT; paho's own reconnect is not used, because it would reuse the old Will
(SPARKPLUG.md pitfalls). bdSeq advances once per CONNECT sent: an attempt that got no TCP or TLS connection reuses it.

Every DCMD/NCMD refused or ignored is appended to the audit log (:class:`~starterbus.core.audit.AuditLog`, the
one the guarded path writes the executed operations to) with its reason, the topic and the actor: by the
session's checks, by the fleet file's ``remote`` table, by validation. Refusals the guarded path audits itself (a
state rule of a command, an operation not confirmed) and outcomes of operations that were sent are not written
twice; an error raised while sending may be (the operation's record, and the DCMD's).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from starterbus.aio import AsyncFleet
from starterbus.core.audit import AuditLog
from starterbus.core.errors import ConfigurationError
from starterbus.core.supervision import Supervisor
from starterbus.fleet.poller import Sample
from starterbus.serve.broker import BrokerOptions
from starterbus.serve.command_run import run_request
from starterbus.serve.paho_loop import PahoOnLoop
from starterbus.serve.session import (
    Action,
    CommandAudit,
    CommandRequest,
    EdgeSession,
    HistoryReady,
    Publish,
    Reconnect,
)
from starterbus.serve.state import save_bdseq

log = logging.getLogger("starterbus.serve")


class EdgeNodeDriver(PahoOnLoop):
    def __init__(
        self,
        fleet: AsyncFleet,
        session: EdgeSession,
        broker: BrokerOptions | Sequence[BrokerOptions],
        *,
        state_file: Path | None = None,
        on_sample: Callable[[Sample], None] | None = None,
        retry_delay: float = 2.0,
        history_batch: int = 200,
        audit: AuditLog | None = None,
    ) -> None:
        """``broker``: one, or a list tried in turn (the first that answers; the next on a loss or when the
        primary host goes offline there; ``retry_delay`` between rounds of the whole list). ``audit``: where
        refused commands go (default: the guarded path's default audit log)."""
        self.fleet = fleet
        self._stream = fleet.subscribe()  # from now on: samples polled while other servers start are not lost
        self.session = session
        self.brokers = [broker] if isinstance(broker, BrokerOptions) else list(broker)
        if not self.brokers:
            raise ConfigurationError("serve: no broker given")
        self.broker = self.brokers[0]  # the one connected to, or tried last
        self.state_file = state_file
        self.on_sample = on_sample
        self.retry_delay = retry_delay
        self.history_batch = history_batch
        self.audit = audit if audit is not None else AuditLog()
        self._history_ready = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._client: mqtt.Client | None = None
        self._lost = asyncio.Event()
        self._tasks: set[asyncio.Task[None]] = set()
        self._watched: dict[int, tuple[int, asyncio.Task[None]]] = {}  # id(socket) -> (fileno, keepalive task)
        self._loop_thread = 0
        self._flushing: set[int] = set()  # id(socket): a _flush is scheduled
        self._writers: set[int] = set()  # id(socket): its writability is watched (a full send buffer)
        self._burst = None  # the packet of paho's queue that _publish adds to
        self._topics = {}  # topic -> its PUBLISH field
        self.connections = 0  # sessions established (births sent at least once)

    @property
    def actor(self) -> str:
        """Who DCMDs come from in the audit log: the MQTT user (or client id) and the broker connected to."""
        b = self.broker
        return f"mqtt:{b.username or b.client_id}@{b.host}:{b.port}"

    @property
    def connected(self) -> bool:
        """Connected to a broker, subscriptions acknowledged (the births may still wait for the primary host)."""
        return self._client is not None and self.session.connected

    # -- paho thread -> event loop -------------------------------------------------------------------------

    def _call(self, fn: Callable[..., None], *args: object) -> None:
        """Run ``fn`` on the event loop: at once from the loop's own thread, else handed over."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        if threading.get_ident() == self._loop_thread:
            fn(*args)
        else:
            loop.call_soon_threadsafe(fn, *args)

    def _make_client(self, b: BrokerOptions, will: Publish) -> mqtt.Client:
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            client_id=b.client_id,
            clean_session=True,
            protocol=mqtt.MQTTv311,
            reconnect_on_failure=False,
        )
        client.will_set(will.topic, will.payload, qos=1, retain=False)
        if b.username:
            client.username_pw_set(b.username, b.password)
        if b.tls:
            try:
                client.tls_set(ca_certs=b.ca_file, certfile=b.cert_file, keyfile=b.key_file)
            except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError
                files = ", ".join(f for f in (b.ca_file, b.cert_file, b.key_file) if f) or "system CAs"
                raise ConfigurationError(f"TLS setup ({files}): {exc}") from None
        session = self.session
        subs = session.subscriptions()

        def on_connect(c: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
            if reason.is_failure:
                log.warning("broker %s refused the connection: %s", b.describe(), reason)
                self._call(self._lost.set)
            else:
                c.subscribe(subs)

        def on_subscribe(_c: mqtt.Client, _u: Any, _mid: int, reasons: Any, _p: Any) -> None:
            if any(r.is_failure for r in reasons):
                log.warning("broker %s refused a subscription: %s", b.describe(), reasons)
            self._call(self._subscribed, client)

        def on_message(_c: mqtt.Client, _u: Any, msg: mqtt.MQTTMessage) -> None:
            self._call(self._message, client, msg.topic, bytes(msg.payload))

        def on_disconnect(_c: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
            self._call(self._disconnected, client)

        client.on_connect = on_connect
        client.on_subscribe = on_subscribe
        client.on_message = on_message
        client.on_disconnect = on_disconnect
        client.on_socket_open = lambda c, _u, sock: self._call(self._watch, c, sock)
        client.on_socket_close = lambda _c, _u, sock: self._call(self._unwatch, sock)
        client.on_socket_register_write = lambda c, _u, sock: self._call(self._want_write, c, sock)
        client.on_socket_unregister_write = lambda _c, _u, sock: self._call(self._unwatch_write, sock)
        return client

    # -- event loop side -----------------------------------------------------------------------------------

    def _subscribed(self, client: mqtt.Client) -> None:
        if client is self._client:
            self.connections += 1
            self._apply(self.session.on_connected(time.time()))

    def _disconnected(self, client: mqtt.Client) -> None:
        if client is self._client:
            self.session.on_disconnected()
            self._lost.set()

    def _message(self, client: mqtt.Client, topic: str, payload: bytes) -> None:
        if client is self._client:
            self._apply(self.session.on_message(topic, payload, time.time()))

    def _apply(self, actions: list[Action]) -> None:
        client = self._client
        for action in actions:
            if isinstance(action, Publish):
                if client is None:
                    pass
                elif action.qos == 0:
                    self._publish(client, action.topic, action.payload)  # a burst: one packet of paho's
                else:
                    client.publish(action.topic, action.payload, qos=action.qos, retain=False)
            elif isinstance(action, CommandAudit):
                self._audit(action.device, action.topic, action.asked, action.result)
            elif isinstance(action, CommandRequest):
                task = asyncio.get_running_loop().create_task(self._execute(action))
                self._tasks.add(task)
                task.add_done_callback(self._tasks.discard)
            elif isinstance(action, Reconnect) and client is not None:
                client.disconnect()
            elif isinstance(action, HistoryReady):
                self._history_ready.set()

    def _audit(self, device: str | None, topic: str, asked: str, result: str) -> None:
        """One audit record for a command refused or ignored here (the guarded path records what it ran)."""
        kind = topic.split("/")[2] if topic.count("/") >= 3 else "command"
        record: dict[str, object] = {"device": None, "model": None}
        config = getattr(getattr(self.fleet, "config", None), "devices_by_name", {}).get(device or "")
        if config is not None:
            record = {"device": config.url, "model": config.model}
        record |= {"name": device, "actor": self.actor, "action": kind.lower(), "topic": topic, "asked": asked}
        try:
            self.audit.append(**record, result=result)
        except OSError as exc:  # the audit file cannot be written: said, never a stop of the edge node
            log.error("audit log %s: %s (%s %s: %s)", self.audit.path, exc, kind, device or "", result)

    async def _execute(self, req: CommandRequest) -> None:
        result = await run_request(self.fleet, req, self.actor)
        log.info("DCMD %s %s: %s", req.device, req.command.value if req.command else req.writes, result.text)
        now = time.time()
        if result.ok:
            self._apply(self.session.command_done(req.device, result.text, now))
            return
        audit = None if result.audited else (req.topic, req.asked)
        self._apply(self.session.refuse(req.device, result.text, now, failed=result.failed, audit=audit))

    # -- tasks ---------------------------------------------------------------------------------------------

    async def _samples(self) -> None:
        try:
            async for sample in self._stream:
                self._take(sample)
        finally:
            self._stream.close()

    def _take(self, sample: Sample) -> None:
        if self.on_sample is not None:
            self.on_sample(sample)
        self._apply(self.session.on_sample(sample, time.time()))

    async def _last_samples(self, consumer: asyncio.Task[None]) -> None:
        """A requested stop: polling ends first, then what it polled last is published (or stored, while no broker
        is connected) before the NDEATH: a stop loses no sample that was polled (and recorded)."""
        stop_polling = getattr(self.fleet, "stop_polling", None)  # a stand-in for the fleet may have none
        if stop_polling is not None:
            await stop_polling()
        consumer.cancel()  # between samples: it waits for the next one
        await asyncio.gather(consumer, return_exceptions=True)
        for sample in self._stream.drain():
            self._take(sample)

    async def _ticks(self) -> None:
        while True:
            await asyncio.sleep(1.0)
            self._apply(self.session.on_tick(time.time()))

    async def _history(self) -> None:
        """Buffered DDATA out in batches once their devices are born; each batch forgotten once written."""
        while True:
            await self._history_ready.wait()
            self._history_ready.clear()
            while (client := self._client) is not None:
                publishes, ids = self.session.history(time.time(), self.history_batch)
                if not ids:
                    break
                infos = [client.publish(p.topic, p.payload, qos=p.qos, retain=False) for p in publishes]
                last = infos[-1]
                while last.rc == mqtt.MQTT_ERR_SUCCESS and not last.is_published() and client is self._client:
                    await asyncio.sleep(0.005)  # written by the loop's writer
                if last.rc != mqtt.MQTT_ERR_SUCCESS or not last.is_published():
                    break  # connection lost: the records stay stored, for the next session
                self.session.history_sent(ids)

    async def _connections(self) -> None:
        index = 0
        saved: int | None = None
        while True:
            b = self.broker = self.brokers[index]
            nxt = (index + 1) % len(self.brokers)
            will = self.session.next_will()
            if self.state_file is not None and saved != self.session.bdseq:  # before the CONNECT that carries it
                await asyncio.to_thread(save_bdseq, self.state_file, self.session.bdseq)
                saved = self.session.bdseq
            client = self._make_client(b, will)
            self._lost.clear()
            # current before CONNECT: its CONNACK and SUBACK may be read before this coroutine resumes
            self._client = client
            sessions = self.connections
            try:
                await asyncio.to_thread(client.connect, b.host, b.port, b.keepalive)
            except (OSError, ValueError) as exc:
                self._client = None
                index = nxt
                if index == 0:  # every broker of the list tried: pause
                    log.warning("broker %s unreachable: %s; retrying in %g s", b.describe(), exc, self.retry_delay)
                    await asyncio.sleep(self.retry_delay)
                else:
                    log.warning("broker %s unreachable: %s; trying %s", b.describe(), exc, self.brokers[nxt].describe())
                continue
            self.session.connect_sent()  # TCP (and TLS) up, the CONNECT with this Will written: a new bdSeq next time
            log.info("connected to %s (bdSeq %d)", b.describe(), self.session.bdseq)
            await self._lost.wait()  # cancelled on stop: _stop_cleanly says goodbye with this client
            self.session.on_disconnected()
            self._client = None
            await self._close(client)
            established = self.connections > sessions
            index = nxt
            log.warning(
                "connection to %s %s; connecting to %s",
                b.describe(), "lost" if established else "refused", self.brokers[index].describe(),
            )  # fmt: skip
            if index == 0:  # a single broker, or every one of the list tried
                await asyncio.sleep(min(self.retry_delay, 0.5) if established else self.retry_delay)

    @staticmethod
    async def _close(client: mqtt.Client, timeout: float = 2.0) -> None:
        """DISCONNECT (written by the loop's writer), then wait until paho closed the socket."""
        client.disconnect()
        deadline = time.monotonic() + timeout
        while client.socket() is not None and time.monotonic() < deadline:
            await asyncio.sleep(0.01)

    async def _stop_cleanly(self) -> None:
        """Intentional stop: NDEATH (QoS 1), wait for its PUBACK, then DISCONNECT (intentional-disconnect-*)."""
        client = self._client
        if client is None:
            return
        self._client = None
        if self.session.born:
            death = self.session.ndeath()
            info = client.publish(death.topic, death.payload, qos=1, retain=False)
            deadline = time.monotonic() + 2.0
            while not info.is_published() and client.socket() is not None and time.monotonic() < deadline:
                await asyncio.sleep(0.01)  # the PUBACK arrives through the loop's reader
        self.session.on_disconnected()
        await self._close(client)

    def _supervisor(self) -> Supervisor:
        """The fleet's (:mod:`starterbus.core.supervision`): a task failing stops the service, poller included."""
        supervisor = getattr(self.fleet, "supervisor", None)
        if not isinstance(supervisor, Supervisor):  # a stand-in for the fleet (the benchmark's)
            supervisor = Supervisor()
            setattr(self.fleet, "supervisor", supervisor)  # noqa: B010
        return supervisor

    async def run(self, stop: asyncio.Event) -> None:
        """Until ``stop`` is set; a failing part (e.g. TLS files that cannot be read) ends it with its error, and so
        does a failure anywhere in the service (:class:`~starterbus.core.supervision.ServiceFailed`)."""
        self._loop = loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        supervisor = self._supervisor()
        failed = asyncio.Event()

        def on_fatal(_failure: object) -> None:  # any thread
            if not loop.is_closed():
                loop.call_soon_threadsafe(failed.set)

        supervisor.on_fatal(on_fatal)
        jobs = [
            supervisor.task(f"serve-{make.__name__.strip('_')}", make)
            for make in (self._samples, self._ticks, self._connections, self._history)
        ]
        stopped, died = asyncio.create_task(stop.wait()), asyncio.create_task(failed.wait())
        try:
            await asyncio.wait([stopped, died, *jobs], return_when=asyncio.FIRST_COMPLETED)
            if stopped.done() and not died.done() and not any(job.done() for job in jobs):
                await self._last_samples(jobs[0])
        finally:
            for job in (*jobs, stopped, died):
                job.cancel()
            results = await asyncio.gather(*jobs, return_exceptions=True)
            await self._stop_cleanly()
        for result in results:
            if isinstance(result, Exception) and not isinstance(result, asyncio.CancelledError):
                raise result
        supervisor.check()
