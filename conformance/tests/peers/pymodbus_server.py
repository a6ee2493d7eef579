#!/usr/bin/python3
"""pymodbus 3.0 (Debian python3-pymodbus) as a library's own test server
would run it (pymodbus examples/server_async.py): a ModbusSlaveContext of
four ModbusSequentialDataBlock of 200 items each, zero_mode so that request
address 0 is item 0, served on Modbus TCP. Prints "listening PORT" when ready.

usage: pymodbus_server.py PORT
"""
import asyncio
import logging
import sys

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.server import StartAsyncTcpServer

ITEMS = 200


async def main(port):
    def block():
        return ModbusSequentialDataBlock(0, [0] * ITEMS)

    store = ModbusSlaveContext(di=block(), co=block(), hr=block(), ir=block(), zero_mode=True)
    context = ModbusServerContext(slaves=store, single=True)
    server = await StartAsyncTcpServer(context=context, address=("127.0.0.1", port), defer_start=True)
    task = asyncio.create_task(server.serve_forever())
    await server.serving
    print(f"listening {port}", flush=True)
    await task


if __name__ == "__main__":
    logging.disable(logging.CRITICAL)
    asyncio.run(main(int(sys.argv[1])))
