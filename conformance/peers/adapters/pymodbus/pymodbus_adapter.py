#!/usr/bin/python3
"""The pymodbus adapter of `mbconform client` (protocol 1, conformance/client/README.md).

Drives Debian's python3-pymodbus (3.0.x) the way its documentation shows: the
client mixin's calls with `slave=`, and `execute()` of a request object where
the mixin has no call (FC 43). One JSON object a line on stdin, one answer a
line on stdout; pymodbus's logging goes to stderr.

usage: /usr/bin/python3 pymodbus_adapter.py
"""
import json
import logging
import sys

import pymodbus
from pymodbus.client import ModbusSerialClient, ModbusTcpClient, ModbusTlsClient
from pymodbus.exceptions import ConnectionException, ModbusIOException
from pymodbus.framer.rtu_framer import ModbusRtuFramer
from pymodbus.framer.socket_framer import ModbusSocketFramer
from pymodbus.mei_message import ReadDeviceInformationRequest
from pymodbus.pdu import ExceptionResponse

PROTOCOL = 1
OPS = ["read_coils", "read_discrete_inputs", "read_holding_registers", "read_input_registers", "write_single_coil",
       "write_single_register", "write_multiple_coils", "write_multiple_registers", "mask_write_register",
       "read_write_multiple_registers", "read_device_identification"]

logging.basicConfig(stream=sys.stderr, level=logging.WARNING)
client = None


def send(obj):
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def call(c, op, r):
    """The pymodbus call for one op; returns the response object."""
    unit = r.get("unit", 1)
    a = r.get("address", 0)
    if op == "read_coils":
        return c.read_coils(a, r["count"], slave=unit)
    if op == "read_discrete_inputs":
        return c.read_discrete_inputs(a, r["count"], slave=unit)
    if op == "read_holding_registers":
        return c.read_holding_registers(a, r["count"], slave=unit)
    if op == "read_input_registers":
        return c.read_input_registers(a, r["count"], slave=unit)
    if op == "write_single_coil":
        return c.write_coil(a, bool(r["value"]), slave=unit)
    if op == "write_single_register":
        return c.write_register(a, r["value"], slave=unit)
    if op == "write_multiple_coils":
        return c.write_coils(a, [bool(v) for v in r["values"]], slave=unit)
    if op == "write_multiple_registers":
        return c.write_registers(a, r["values"], slave=unit)
    if op == "mask_write_register":
        return c.mask_write_register(address=a, and_mask=r["and_mask"], or_mask=r["or_mask"], slave=unit)
    if op == "read_write_multiple_registers":
        return c.readwrite_registers(read_address=r["read_address"], read_count=r["read_count"],
                                     write_address=r["write_address"], write_registers=r["values"], slave=unit)
    if op == "read_device_identification":
        return c.execute(ReadDeviceInformationRequest(read_code=1, object_id=r.get("object_id", 0), slave=unit))
    return None


def values_of(op, rsp, r):
    if op in ("read_coils", "read_discrete_inputs"):
        return [bool(b) for b in rsp.bits[:r["count"]]]
    if op in ("read_holding_registers", "read_input_registers", "read_write_multiple_registers"):
        return list(rsp.registers)
    if op == "read_device_identification":
        objs = {}
        for k, v in rsp.information.items():
            objs["0x%02X" % k] = v.decode("latin-1") if isinstance(v, bytes) else str(v)
        return {"objects": objs}
    return []


def request(r):
    op, rid = r.get("op"), r.get("id")
    if op not in OPS:
        return {"id": rid, "ok": False, "error": "unsupported"}
    try:
        rsp = call(client, op, r)
    except ValueError as e:  # pymodbus's own argument checks
        return {"id": rid, "ok": False, "error": "refused", "detail": str(e)}
    except ConnectionException as e:
        return {"id": rid, "ok": False, "error": "other", "detail": str(e)}
    except Exception as e:  # pylint: disable=broad-except
        return {"id": rid, "ok": False, "error": "invalid_reply", "detail": "%s: %s" % (type(e).__name__, e)}
    if isinstance(rsp, ExceptionResponse):
        return {"id": rid, "ok": False, "error": "exception", "code": rsp.exception_code}
    if isinstance(rsp, ModbusIOException):
        text = str(rsp)
        kind = "timeout" if "no response" in text.lower() else "invalid_reply"
        return {"id": rid, "ok": False, "error": kind, "detail": text}
    if rsp is None or (hasattr(rsp, "isError") and rsp.isError()):
        return {"id": rid, "ok": False, "error": "invalid_reply", "detail": repr(rsp)}
    try:
        return {"id": rid, "ok": True, "values": values_of(op, rsp, r)}
    except Exception as e:  # pylint: disable=broad-except
        return {"id": rid, "ok": False, "error": "invalid_reply", "detail": "%s: %s" % (type(e).__name__, e)}


def connect(c):
    global client  # pylint: disable=global-statement
    if client:
        client.close()
        client = None
    t = c.get("transport")
    timeout = c.get("timeout_ms", 500) / 1000.0
    common = {"retries": c.get("retries", 0), "retry_on_empty": False}
    if t == "tcp":
        client = ModbusTcpClient(c["host"], port=c["port"], **common)
    elif t == "rtu-tcp":
        client = ModbusTcpClient(c["host"], port=c["port"], framer=ModbusRtuFramer, **common)
    elif t == "tls":
        # Modbus/TCP Security as pymodbus 3.0 documents ModbusTlsClient: the
        # certificate and key, its own SSLContext (client/tls.py:15-43). The
        # framer is the MBAP one: the default ModbusTlsFramer sends the PDU
        # without the MBAP header (framer/tls_framer.py:18-23, pymodbus
        # #2014), which no MB-TCP-Security server reads. `ca` has nowhere to
        # go: the provider's context verifies nothing (tls.py:33-34).
        client = ModbusTlsClient(c["host"], port=c["port"], framer=ModbusSocketFramer, certfile=c["cert"],
                                 keyfile=c["key"], **common)
    elif t == "rtu":
        client = ModbusSerialClient(port=c["device"], method="rtu", baudrate=c.get("baud", 9600),
                                    parity=c.get("parity", "N"), bytesize=c.get("data", 8),
                                    stopbits=c.get("stop", 1), **common)
    else:
        return {"ready": False, "detail": "no transport %s" % t}
    # pymodbus 3.0 truncates the constructor's timeout to whole seconds
    # (int(timeout)); the socket and serial reads take the float as given.
    client.params.timeout = timeout
    if not client.connect():
        return {"ready": False, "detail": "connect to %s failed" % c}
    return {"ready": True}


def main():
    for line in sys.stdin:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            print("pymodbus adapter: not JSON: %r" % line, file=sys.stderr)
            continue
        if "hello" in msg:
            send({"protocol": PROTOCOL, "library": "pymodbus", "version": pymodbus.__version__, "ops": OPS,
                  "raw": False, "retries": True})
        elif "connect" in msg:
            send(connect(msg["connect"]))
        elif "disconnect" in msg:
            if client:
                client.close()
            send({"disconnected": True})
        elif msg.get("op") == "close":
            break
        else:
            send(request(msg))
    if client:
        client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
