#!/usr/bin/python3
"""`mbconform serve` against pymodbus (Debian python3-pymodbus 3.0.x), a
third-party master: Modbus TCP, RTU over TCP and RTU on the pty. Register
addresses and values come from the spec (`mbconform spec dump`).

usage: pymodbus_interop.py MBCONFORM_BIN
"""
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.framer.rtu_framer import ModbusRtuFramer

DEVICE = "hsc60"
SLAVE = 3
failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


def plain_rw(spec, reg):
    """The same rule as spec_registers.cpp: a ranged rw word that is no serial setting."""
    settings = {s["register"] for s in spec["serial"].get("settings", [])}
    return (reg.get("table") == "holding" and reg.get("access") == "rw" and reg.get("words", 1) == 1
            and reg.get("type") in ("u16", "s16") and reg.get("range") and "command" not in reg
            and reg.get("takes_effect") == "immediate" and reg["address"] not in settings)


def main():
    mbconform = sys.argv[1]
    spec = json.loads(subprocess.check_output([mbconform, "spec", "dump", DEVICE]))
    reg = next(r for r in spec["registers"] if plain_rw(spec, r))
    lo, hi = reg["range"]["min"], reg["range"]["max"]
    value = int((lo + hi) // 2) & 0xFFFF

    with tempfile.TemporaryDirectory() as tmp:
        tty = os.path.join(tmp, "tty")
        server = subprocess.Popen(
            [mbconform, "serve", "--device", f"{DEVICE}@{SLAVE}", "--tcp", "0", "--rtu-tcp", "0", "--pty", tty],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # A hang fails fast: no listening lines in 10 s kills the server.
        timer = threading.Timer(10, server.kill)
        timer.start()
        endpoints = {}
        while len(endpoints) < 3:
            line = server.stdout.readline()
            if not line:
                break
            word, transport, address = line.split()
            if word == "listening":
                endpoints[transport] = address
        timer.cancel()
        check(len(endpoints) == 3, f"three listening lines: {endpoints}")
        if len(endpoints) < 3:
            server.kill()
            print(server.stderr.read())
            return 1

        def port(t):
            return int(endpoints[t].rsplit(":", 1)[1])

        clients = {
            "tcp": ModbusTcpClient("127.0.0.1", port=port("tcp"), timeout=2),
            "rtu-tcp": ModbusTcpClient("127.0.0.1", port=port("rtu-tcp"), framer=ModbusRtuFramer, timeout=2),
            "pty": ModbusSerialClient(endpoints["pty"], baudrate=9600, timeout=2),
        }
        for step, (name, client) in enumerate(clients.items()):
            check(client.connect(), f"{name}: connect")
            v = (value + step) if (value + step) <= hi else value  # each transport writes its own value
            w = client.write_register(reg["address"], v, slave=SLAVE)
            check(not w.isError(), f"{name}: write {v} to 0x{reg['address']:04X} ({w})")
            r = client.read_holding_registers(reg["address"], 1, slave=SLAVE)
            check(not r.isError() and r.registers == [v], f"{name}: read back 0x{reg['address']:04X} = {v} ({r})")
            client.close()

        server.send_signal(signal.SIGTERM)
        try:
            rc = server.wait(timeout=5)
        except subprocess.TimeoutExpired:
            server.kill()
            rc = None
        check(rc == 0, f"SIGTERM: exit code {rc}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
