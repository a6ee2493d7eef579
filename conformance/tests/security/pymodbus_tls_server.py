#!/usr/bin/python3
"""pymodbus 3.0 (Debian python3-pymodbus) serving Modbus/TCP Security with
StartAsyncTlsServer, the data store of ../../peers/servers/pymodbus_server.py (four
blocks of 200 items, zero_mode). Prints "listening 127.0.0.1:PORT" when ready.

usage: pymodbus_tls_server.py MODE CERT KEY CA [PORT]  (PORT 0 or none: any free port)
  --as-shipped  certfile/keyfile and reqclicert=True, as the documentation
                of StartAsyncTlsServer shows them (sslctx_provider builds the
                context: server/async_io.py:40-70)
  --tls-framer  a user SSLContext (TLS 1.2+, CERT_REQUIRED, the CA loaded)
                and the default framer, ModbusTlsFramer
  --mbap        the same context and ModbusSocketFramer: the MBAP header
                inside TLS, as MB-TCP-Security v2.1 §6 carries it
"""
import asyncio
import logging
import ssl
import sys

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.server import StartAsyncTlsServer
from pymodbus.transaction import ModbusSocketFramer

ITEMS = 200


def store():
    def block():
        return ModbusSequentialDataBlock(0, [0] * ITEMS)
    return ModbusSlaveContext(di=block(), co=block(), hr=block(), ir=block(), zero_mode=True)


def user_context(cert, key, ca):
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.verify_mode = ssl.CERT_REQUIRED
    ctx.load_cert_chain(certfile=cert, keyfile=key)
    ctx.load_verify_locations(cafile=ca)
    return ctx


async def main(mode, cert, key, ca, port="0"):
    context = ModbusServerContext(slaves=store(), single=True)
    kw = {"context": context, "address": ("127.0.0.1", int(port)), "defer_start": True}
    if mode == "--as-shipped":
        kw.update(certfile=cert, keyfile=key, reqclicert=True)
    else:
        kw.update(sslctx=user_context(cert, key, ca))
    if mode == "--mbap":
        kw["framer"] = ModbusSocketFramer
    server = await StartAsyncTlsServer(**kw)
    task = asyncio.create_task(server.serve_forever())
    await server.serving
    host, port = server.server.sockets[0].getsockname()[:2]
    print(f"listening {host}:{port}", flush=True)
    await task


if __name__ == "__main__":
    logging.disable(logging.CRITICAL)
    asyncio.run(main(*sys.argv[1:6]))
