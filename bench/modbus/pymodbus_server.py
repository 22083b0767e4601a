"""A plain pymodbus RTU server (slave 2, holding registers 0x0000-0x01FF) on a serial port path, for baselines.

python bench/modbus/pymodbus_server.py /dev/pts/5 [--baud 19200] [--changing]

``--changing``: every FC03 answer differs from the one before (the first register read counts up), like the
phase currents of a running motor; by default the registers keep their values, like parameters.
"""

from __future__ import annotations

import argparse

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.server import StartSerialServer


async def count_up(
    function_code: int, start: int, address: int, count: int, registers: list[int], written: object
) -> None:
    """pymodbus' SimDevice action, before each request is served: a read changes its first register."""
    if function_code == 3:
        registers[address - start] = (registers[address - start] + 1) & 0xFFFF


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("--baud", type=int, default=19200)
    parser.add_argument("--changing", action="store_true", help="every FC03 answer differs from the last")
    args = parser.parse_args()
    block = ModbusSequentialDataBlock(1, [100 + i for i in range(0x200)])  # type: ignore[no-untyped-call]
    device = ModbusDeviceContext(hr=block)
    if args.changing:
        device.simdevice.action = count_up
    context = ModbusServerContext(devices={2: device}, single=False)
    StartSerialServer(context, framer=FramerType.RTU, port=args.port, baudrate=args.baud)


if __name__ == "__main__":
    main()
