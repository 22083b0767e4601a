"""One Modbus master, one operation, for a few seconds: prints one JSON line (transactions, CPU, errors).

    python bench/modbus/clients.py CLIENT PORT --op fc03|fc06 --baud 19200 --seconds 2

Each client runs in its own process so that CPU time per transaction is its own. Every client reads the same
4 registers (FC03 0x0100-0x0103 at unit 2) or writes the same register (FC06 0x0103 = 380).
CLIENTS: starterbus, starterbus-device, pymodbus-sync, pymodbus-async, minimalmodbus, exact-silence,
exact-nosilence.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import select
import time
from collections.abc import Callable
from functools import partial

UNIT = 2
ADDRESS = 0x0100
COUNT = 4
WRITE_ADDRESS = 0x0103
WRITE_VALUE = 380


def loop(op: Callable[[], object], seconds: float) -> tuple[int, int, float, float]:
    """Run ``op`` for ``seconds``: (transactions, errors, wall seconds, CPU seconds)."""
    op()  # warm up: open, first request
    count = errors = 0
    cpu0, t0 = time.process_time(), time.monotonic()
    end = t0 + seconds
    while time.monotonic() < end:
        try:
            op()
            count += 1
        except Exception:
            errors += 1
    return count, errors, time.monotonic() - t0, time.process_time() - cpu0


Ops = tuple[Callable[[], object], Callable[[], None]]  # the operation, and how to close the client


def starterbus_ops(port: str, baud: int, fc: str, device_level: bool) -> Ops:
    from starterbus.core.device import open_device

    device = open_device(f"modbus-rtu://{port}?unit={UNIT}&baudrate={baud}", "jjr5000").open()
    transport = device.transport
    keys = ("motor_rated_current", "ramp_time", "soft_stop_time", "current_limit")
    # partial, not lambda: the floor's op is called directly, so no Python frame of the harness's own is counted
    op: Callable[[], object]
    if device_level:
        op = partial(device.read, *keys) if fc == "fc03" else partial(device.write, "current_limit", WRITE_VALUE)
    elif fc == "fc03":
        op = partial(transport.read_registers, ADDRESS, COUNT)  # type: ignore[attr-defined]
    else:
        op = partial(transport.write_register, WRITE_ADDRESS, WRITE_VALUE)  # type: ignore[attr-defined]
    return op, device.close


def pymodbus_sync_ops(port: str, baud: int, fc: str) -> Ops:
    from pymodbus.client import ModbusSerialClient

    client = ModbusSerialClient(port, baudrate=baud)  # defaults otherwise
    client.connect()

    def read() -> object:
        result = client.read_holding_registers(ADDRESS, count=COUNT, device_id=UNIT)
        if result.isError():
            raise RuntimeError(result)
        return result

    def write() -> object:
        result = client.write_register(WRITE_ADDRESS, WRITE_VALUE, device_id=UNIT)
        if result.isError():
            raise RuntimeError(result)
        return result

    return (read if fc == "fc03" else write), client.close


def pymodbus_async_run(port: str, baud: int, fc: str, seconds: float) -> tuple[int, int, float, float]:
    from pymodbus.client import AsyncModbusSerialClient

    async def main() -> tuple[int, int, float, float]:
        client = AsyncModbusSerialClient(port, baudrate=baud)
        await client.connect()

        async def op() -> None:
            if fc == "fc03":
                result = await client.read_holding_registers(ADDRESS, count=COUNT, device_id=UNIT)
            else:
                result = await client.write_register(WRITE_ADDRESS, WRITE_VALUE, device_id=UNIT)
            if result.isError():
                raise RuntimeError(result)

        await op()
        count = errors = 0
        cpu0, t0 = time.process_time(), time.monotonic()
        while time.monotonic() < t0 + seconds:
            try:
                await op()
                count += 1
            except Exception:
                errors += 1
        stats = (count, errors, time.monotonic() - t0, time.process_time() - cpu0)
        client.close()
        return stats

    return asyncio.run(main())


def minimalmodbus_ops(port: str, baud: int, fc: str) -> Ops:
    import minimalmodbus

    instrument = minimalmodbus.Instrument(port, UNIT)  # defaults (19200 8N1, timeout 0.05 s)
    instrument.serial.baudrate = baud
    if fc == "fc03":
        return (lambda: instrument.read_registers(ADDRESS, COUNT)), instrument.serial.close
    return (lambda: instrument.write_register(WRITE_ADDRESS, WRITE_VALUE, functioncode=6)), instrument.serial.close


def exact_ops(port: str, baud: int, fc: str, silence: bool, watch: bool = False) -> Ops:
    """A hand-written loop: write the request, read exactly the predicted length; optionally keep the silence.

    ``watch``: keep the silence by watching the line after each answer (``select`` for the silent interval, an
    answer followed by bytes refused) instead of sleeping before the next request: the least a client that
    checks for trailing bytes does.
    """
    import serial

    from starterbus.transports.modbus.codec.frames import ReadRequest, WriteRequest, expected_response_length

    ser = serial.Serial(port, baudrate=baud, timeout=0)
    fd = ser.fileno()
    request = ReadRequest(UNIT, ADDRESS, COUNT) if fc == "fc03" else WriteRequest(UNIT, WRITE_ADDRESS, WRITE_VALUE)
    frame, size = request.encode(), expected_response_length(request)
    quiet = 3.5 * 11 / baud if baud <= 19200 else 0.00175
    state = {"quiet_at": 0.0}

    def op() -> bytes:
        if silence and not watch:
            delay = state["quiet_at"] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        os.write(fd, frame)
        data = b""
        deadline = time.monotonic() + 1.0
        while len(data) < size:
            if not select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]:
                raise TimeoutError("no answer")
            data += os.read(fd, size - len(data))
        if watch:
            if select.select([fd], [], [], quiet)[0]:
                raise RuntimeError("bytes followed the answer within the silent interval")
        else:
            state["quiet_at"] = time.monotonic() + quiet
        return data

    return op, ser.close


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("client")
    parser.add_argument("port")
    parser.add_argument("--op", choices=["fc03", "fc06"], default="fc03")
    parser.add_argument("--baud", type=int, default=19200)
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()
    logging.disable(logging.CRITICAL)  # pymodbus logs warnings per transaction on a busy line
    if args.client == "pymodbus-async":
        count, errors, wall, cpu = pymodbus_async_run(args.port, args.baud, args.op, args.seconds)
    else:
        if args.client in ("starterbus", "starterbus-device"):
            op, close = starterbus_ops(args.port, args.baud, args.op, args.client == "starterbus-device")
        elif args.client == "pymodbus-sync":
            op, close = pymodbus_sync_ops(args.port, args.baud, args.op)
        elif args.client == "minimalmodbus":
            op, close = minimalmodbus_ops(args.port, args.baud, args.op)
        elif args.client in ("exact-silence", "exact-nosilence"):
            op, close = exact_ops(args.port, args.baud, args.op, args.client == "exact-silence")
        else:
            raise SystemExit(f"unknown client {args.client!r}")
        count, errors, wall, cpu = loop(op, args.seconds)
        close()
    print(json.dumps({"client": args.client, "tx": count, "errors": errors, "wall": wall, "cpu": cpu}))


if __name__ == "__main__":
    main()
