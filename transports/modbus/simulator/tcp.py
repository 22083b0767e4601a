"""The Modbus TCP front end of ``starterbus simulate``: a gateway with simulated starters behind it.

One listening socket, one thread per client connection. Each MBAP request is answered with its own transaction
id by the same slave logic as the RTU simulator (``slave.py``); a unit no starter answers gets exception 0x0B
("gateway target device failed to respond"), as a real gateway answers for a device that is silent behind it.
:attr:`ModbusTcpSimulator.fault_hook` makes a device behind it misbehave as the RTU simulator's does (a
:class:`~starterbus.transports.modbus.simulator.rtu.SlaveFault` a request: silent, late, repeated, refused).
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections.abc import Callable, Mapping

from starterbus.core import ConfigurationError, DecodeError, RunningSimulator, SimulatedStarter
from starterbus.transports.modbus.codec.decoding import decode_request
from starterbus.transports.modbus.codec.messages import ExceptionResponse, Response
from starterbus.transports.modbus.master.mbap import HEADER, HEADER_LENGTH, MAX_PDU, PROTOCOL_ID, encode_adu
from starterbus.transports.modbus.simulator.rtu import FaultHook, fault_response
from starterbus.transports.modbus.slave import SlaveLogic

GATEWAY_TARGET_FAILED = 0x0B
#: what the test hook may do with a request: None answers it as usual; else the answer to send instead (its bytes
#: are a whole ADU, any transaction id), or b"" for none
AnswerHook = Callable[[int, int, bytes], "bytes | None"]


class ModbusTcpSimulator(RunningSimulator):
    """A Modbus TCP server serving simulated starters by unit id."""

    def __init__(self, starters: Mapping[int, SimulatedStarter], host: str = "127.0.0.1", port: int = 0) -> None:
        self.logic = SlaveLogic(starters)
        self._host, self._port = host, port
        self._server: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._conns: list[socket.socket] = []
        self._stop_r, self._stop_w = socket.socketpair()
        self._lock = threading.Lock()
        self._closed = False
        self.address: tuple[str, int] = (host, port)
        self.requests = 0
        self.connections = 0
        #: (transaction, unit, pdu) -> the ADU to send instead of the answer (b"": none), or None: answer as usual
        self.answer_hook: AnswerHook | None = None
        #: what a served device does with a request instead of answering it at once (the connection's thread waits
        #: out a delay: later requests on that connection wait too, as behind a gateway serving one at a time)
        self.fault_hook: FaultHook | None = None

    @property
    def starters(self) -> dict[int, SimulatedStarter]:
        return self.logic.starters

    def start(self) -> ModbusTcpSimulator:
        server = socket.socket(socket.AF_INET6 if ":" in self._host else socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind((self._host, self._port))
        except OSError as exc:
            server.close()
            raise ConfigurationError(f"--modbus-tcp {self._host}:{self._port}: cannot listen: {exc}") from exc
        server.listen(16)
        self._server = server
        bound = server.getsockname()
        self.address = (str(bound[0]), int(bound[1]))
        self._spawn(self._accept, f"modbus-tcp server {self.where}")
        return self

    def _spawn(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        self._threads.append(thread)
        thread.start()

    @property
    def where(self) -> str:
        host, port = self.address
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"

    def url(self, unit: int, **params: object) -> str:
        query = "&".join(f"{k}={v}" for k, v in {"unit": unit, **params}.items())
        host = "127.0.0.1" if self.address[0] in ("0.0.0.0", "") else self.address[0]
        return f"modbus-tcp://{host}:{self.address[1]}?{query}"

    def client_urls(self) -> dict[int, str]:
        return {unit: self.url(unit) for unit in sorted(self.starters)}

    def describe(self) -> list[str]:
        return [f"modbus-tcp: {self.where}"]

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop_w.close()
        for thread in self._threads:
            thread.join(timeout=2.0)
        with self._lock:
            conns = list(self._conns)
        for conn in conns:
            conn.close()
        if self._server is not None:
            self._server.close()
        self._stop_r.close()

    def __enter__(self) -> ModbusTcpSimulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- serving ----------------------------------------------------------------------------------------------

    def _accept(self) -> None:
        assert self._server is not None
        while True:
            ready, _, _ = select.select([self._server, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                conn, _ = self._server.accept()
            except OSError:
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conns.append(conn)
                self.connections += 1
            self._spawn(lambda c=conn: self._serve(c), f"modbus-tcp client {self.where}")  # type: ignore[misc]

    def _serve(self, conn: socket.socket) -> None:
        try:
            self._serve_connection(conn)
        finally:
            with self._lock:
                if conn in self._conns:
                    self._conns.remove(conn)
            conn.close()

    def _serve_connection(self, conn: socket.socket) -> None:
        buffer = b""
        while True:
            ready, _, _ = select.select([conn, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                data = conn.recv(4096)
            except OSError:
                return
            if not data:
                return
            buffer += data
            while len(buffer) >= HEADER_LENGTH:
                transaction, protocol, length, unit = HEADER.unpack_from(buffer)
                if protocol != PROTOCOL_ID or not 2 <= length <= MAX_PDU + 1:
                    return  # out of step: a server drops the connection
                end = HEADER_LENGTH - 1 + length
                if len(buffer) < end:
                    break
                pdu, buffer = buffer[HEADER_LENGTH:end], buffer[end:]
                answer = self._answer(transaction, unit, pdu)
                if answer:
                    try:
                        conn.sendall(answer)
                    except OSError:
                        return

    def _answer(self, transaction: int, unit: int, pdu: bytes) -> bytes:
        self.requests += 1
        hook = self.answer_hook
        if hook is not None:
            instead = hook(transaction, unit, pdu)
            if instead is not None:
                return instead
        response: Response | None
        try:
            request = decode_request(bytes((unit,)) + pdu, crc=False)
        except DecodeError:
            return b""
        if unit != 0 and unit not in self.starters:  # 0: a broadcast, written to every starter, not answered
            response = ExceptionResponse(unit, request.function, GATEWAY_TARGET_FAILED)
            return encode_adu(transaction, unit, response.encode()[1:-2])
        faults = self.fault_hook
        fault = faults(request) if faults is not None else None
        response = fault_response(self.logic, request, fault)
        if response is None or (fault is not None and not fault.answer):
            return b""
        answer = encode_adu(transaction, unit, response.encode()[1:-2])
        if fault is None:
            return answer
        if fault.delay > 0:
            time.sleep(fault.delay)
        return answer * fault.copies


__all__ = ["GATEWAY_TARGET_FAILED", "ModbusTcpSimulator"]
