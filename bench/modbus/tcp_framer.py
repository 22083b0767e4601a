"""Modbus TCP: our MBAP engine + RTU codec against pymodbus's socket framer, and a whole transaction (a read of
4 registers) through ``modbus-tcp`` against pymodbus's own sync client, both on the simulated gateway.

    python -m starterbus.bench.modbus.tcp_framer
"""

from __future__ import annotations

import time

from pymodbus.client import ModbusTcpClient
from pymodbus.framer import FramerSocket
from pymodbus.pdu import DecodePDU

from starterbus.core.device import open_device
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse, decode_response
from starterbus.transports.modbus.master.mbap import MbapEngine, encode_adu
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator

N = 20000


def per_call(fn: object, n: int = N) -> float:
    """Microseconds per call, the best of 5 runs (the machine is shared: the best run is the least disturbed)."""
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(n):
            fn()  # type: ignore[operator]
        best = min(best, (time.perf_counter() - start) / n * 1e6)
    return best


def main() -> None:
    answer_pdu = ReadResponse(2, (1, 2, 3, 4)).encode()[1:-2]
    request = ReadRequest(2, 0x0100, 4)
    engine = MbapEngine()
    request_pdu = request.encode()[1:-2]  # encoded once, as the transport's prepared exchange holds it

    def ours() -> None:
        transaction, _ = engine.request(2, request_pdu)
        (adu,) = engine.feed(encode_adu(transaction, 2, answer_pdu))
        decode_response(bytes((adu.unit,)) + adu.pdu, crc=False, request=request)

    framer = FramerSocket(DecodePDU(False))
    frame = encode_adu(1, 2, answer_pdu)

    def theirs() -> None:
        framer.handleFrame(frame, 2, 1)

    print(
        f"decode one FC03 answer (4 registers): ours {per_call(ours):.1f} us (numbering, matching and checking "
        f"against the request included), pymodbus FramerSocket {per_call(theirs):.1f} us (framing and decoding)"
    )
    starter = SimulatedStarter(get_profile("jjr5000"))
    with ModbusTcpSimulator({2: starter}) as sim:
        host, port = sim.address
        with open_device(sim.url(2), "jjr5000") as device:
            transport = device.transport
            read = transport.read_registers  # type: ignore[attr-defined]
            print(f"FC03 x4 round trip, modbus-tcp: {per_call(lambda: read(0x0100, 4), 1000):.0f} us")
        client = ModbusTcpClient(host, port=port)
        client.connect()  # type: ignore[no-untyped-call]
        try:
            us = per_call(lambda: client.read_holding_registers(0x0100, count=4, device_id=2), 1000)
            print(f"FC03 x4 round trip, pymodbus ModbusTcpClient: {us:.0f} us")
        finally:
            client.close()  # type: ignore[no-untyped-call]


if __name__ == "__main__":
    main()
