"""A Modbus RTU server from pymodbus (a third-party implementation) on a serial port,
for adrive's interoperability test.

Usage: pymodbus_server.py PORT BAUD

Slave id 1. Holding registers 0..9 start at 0; input registers 0..2 hold a steering
drive's feedback (position 2500, velocity -1000 as i16, status 0). Every write is
printed as `WRITE addr value...` on standard output; `READY` is printed before serving.
"""

import sys

from pymodbus.datastore import (
    ModbusSequentialDataBlock,
    ModbusServerContext,
    ModbusSlaveContext,
)
from pymodbus.framer import FramerType
from pymodbus.server import StartSerialServer


class Reporting(ModbusSequentialDataBlock):
    def setValues(self, address, values):
        super().setValues(address, values)
        # pymodbus data blocks are 1-based internally.
        print("WRITE", address - 1, *values, flush=True)


def main():
    port, baud = sys.argv[1], int(sys.argv[2])
    store = ModbusSlaveContext(
        hr=Reporting(1, [0] * 10),
        ir=ModbusSequentialDataBlock(1, [2500, (-1000) & 0xFFFF, 0]),
    )
    context = ModbusServerContext(slaves={1: store}, single=False)
    print("READY", flush=True)
    StartSerialServer(
        context=context,
        framer=FramerType.RTU,
        port=port,
        baudrate=baud,
        timeout=0.05,
        # A real RTU slave stays silent on frames for other ids.
        ignore_missing_slaves=True,
    )


if __name__ == "__main__":
    main()
