#!/usr/bin/python3
"""pymodbus 3.0 (Debian python3-pymodbus) as a library's own test server
would run it (pymodbus examples/server_async.py): a ModbusSlaveContext of
four ModbusSequentialDataBlock of 200 items each, zero_mode so that request
address 0 is item 0, served on Modbus TCP. Prints "listening PORT" when ready.

With --rtu-tcp it serves RTU frames over TCP (the example's `--comm tcp
--framer rtu`: StartAsyncTcpServer with ModbusRtuFramer); with --rtu, RTU on
a serial line (a pty: 8N1 at BAUD) with StartAsyncSerialServer and
ModbusRtuFramer (pyserial, serial_asyncio), printing "listening DEVICE" once
the port is open. Both RTU modes serve unit 1 only (the example's `--slaves`
context), as a server on a shared line does.

usage: pymodbus_server.py PORT
       pymodbus_server.py --rtu-tcp PORT
       pymodbus_server.py --rtu DEVICE BAUD
"""
import asyncio
import logging
import sys

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.server import StartAsyncSerialServer, StartAsyncTcpServer
from pymodbus.transaction import ModbusRtuFramer

ITEMS = 200
UNIT = 1


def block():
    return ModbusSequentialDataBlock(0, [0] * ITEMS)


def store():
    return ModbusSlaveContext(di=block(), co=block(), hr=block(), ir=block(), zero_mode=True)


async def main(port):
    context = ModbusServerContext(slaves=store(), single=True)
    server = await StartAsyncTcpServer(context=context, address=("127.0.0.1", port), defer_start=True)
    task = asyncio.create_task(server.serve_forever())
    await server.serving
    print(f"listening {port}", flush=True)
    await task


async def main_rtu_tcp(port):
    context = ModbusServerContext(slaves={UNIT: store()}, single=False)
    server = await StartAsyncTcpServer(context=context, address=("127.0.0.1", port), framer=ModbusRtuFramer,
                                       defer_start=True)
    task = asyncio.create_task(server.serve_forever())
    await server.serving
    print(f"listening {port}", flush=True)
    await task


async def main_rtu(device, baud):
    context = ModbusServerContext(slaves={UNIT: store()}, single=False)
    server = await StartAsyncSerialServer(context=context, framer=ModbusRtuFramer, port=device, baudrate=baud,
                                          bytesize=8, parity="N", stopbits=1, defer_start=True)
    await server.start()  # opens the port; raises when it cannot
    if server.transport is None:
        sys.exit(f"cannot open {device}")
    print(f"listening {device}", flush=True)
    await server.serve_forever()


if __name__ == "__main__":
    logging.disable(logging.CRITICAL)
    if sys.argv[1] == "--rtu":
        asyncio.run(main_rtu(sys.argv[2], int(sys.argv[3])))
    elif sys.argv[1] == "--rtu-tcp":
        asyncio.run(main_rtu_tcp(int(sys.argv[2])))
    else:
        asyncio.run(main(int(sys.argv[1])))
