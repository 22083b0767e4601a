"""A plain pymodbus RTU server (slave 2, holding registers 0x0000-0x01FF) on a serial port path, for baselines.

python bench/modbus/pymodbus_server.py /dev/pts/5 [--baud 19200]
"""

from __future__ import annotations

import argparse

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.server import StartSerialServer


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("--baud", type=int, default=19200)
    args = parser.parse_args()
    block = ModbusSequentialDataBlock(1, [100 + i for i in range(0x200)])  # type: ignore[no-untyped-call]
    context = ModbusServerContext(devices={2: ModbusDeviceContext(hr=block)}, single=False)
    StartSerialServer(context, framer=FramerType.RTU, port=args.port, baudrate=args.baud)


if __name__ == "__main__":
    main()
