#!/usr/bin/python3
"""mbconform scan against served lines whose settings it is not told.

A line of three reference drives at different units, served at 19200 8E1
with the line model (serve --line: a master at another rate gets what a UART
at that rate makes of it) is scanned with no settings given: every drive is
found at 19200 baud with its identity, and a master held to 9600 baud finds
nothing. The same drives behind Modbus TCP are found by unit.

usage: scan_line.py MBCONFORM WORKDIR
"""
import json
import os
import shutil
import subprocess
import sys
import time

mb, work = sys.argv[1], sys.argv[2]
shutil.rmtree(work, ignore_errors=True)
os.makedirs(work)
# The drives on the line, by unit: what the scan must report (chosen here, not read from its output).
line = {3: "hsc60", 7: "hanstar-7trsm5740q", 12: "rieding-dhe"}
failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what)
    if not ok:
        failures.append(what)


def serve(*endpoint):
    args = [mb, "serve"] + sum([["--device", f"{d}@{u}"] for u, d in line.items()], []) + list(endpoint)
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=open(os.path.join(work, "serve.log"), "a"), text=True)
    first = p.stdout.readline().split()
    return p, first[-1]


def scan(target, *extra, out="scan.json"):
    path = os.path.join(work, out)
    t0 = time.monotonic()
    r = subprocess.run([mb, "scan", target, "--out", path, "-q"] + list(extra), capture_output=True, text=True, timeout=600)
    took = time.monotonic() - t0
    print(r.stdout, r.stderr)
    data = json.load(open(path)) if os.path.exists(path) else None
    return r.returncode, data, took


pty = os.path.join(work, "line")
p, _ = serve("--pty", pty, "--line", "19200-8E1")
try:
    rc, data, took = scan("rtu://" + pty, "--units", "1-20", "--timeout", "150ms", "--budget", "5m")
    check(rc == 0, f"scan of the 19200 8E1 line exits 0 (got {rc}, {took:.1f} s)")
    found = {u["unit"]: u for u in (data or {}).get("units", [])}
    check(sorted(found) == sorted(line), f"units {sorted(line)} found (got {sorted(found)})")
    for unit, device in line.items():
        u = found.get(unit, {})
        st = u.get("settings", {})
        # A pty carries the baud rate but not parity (Linux forces CS8, no
        # parity: reference/serve/uart.h): 8 data bits and 1 stop bit are
        # right, the parity is the first tried at 19200 and the scan says so.
        check(st.get("baud") == 19200 and st.get("data") == 8 and st.get("stop") == 1,
              f"unit {unit} at 19200 baud, 8 data bits, 1 stop bit (got {st})")
        check(u.get("spec", {}).get("id") == device, f"unit {unit} identified as {device} (got {u.get('spec')})")
        check(f"baud=19200" in u.get("command", "") and f"unit={unit}" in u.get("command", "")
              and f"--device {device}" in u.get("command", ""), f"unit {unit}'s run command: {u.get('command')}")
    check(data is not None and not data["partial"], "the scan finished within its budget")
    check(data is not None and any("pseudo-terminal" in n for n in data.get("notes", [])),
          "the scan file says a pty does not carry parity")

    # A master held to another rate gets nothing from the line.
    rc, data, _ = scan("rtu://" + pty + "?baud=9600", "--units", "1-15", "--timeout", "100ms", out="wrong.json")
    check(rc == 1, f"at 9600 baud nothing is found: exit 1 (got {rc})")
    check(data is not None and data["units"] == [], "at 9600 baud no unit in the scan file")
finally:
    p.terminate()
    p.wait(10)

# Behind Modbus TCP (a gateway's view): units only.
p, addr = serve("--tcp", "127.0.0.1:0")
try:
    rc, data, _ = scan("tcp://" + addr, "--units", "1-15", "--timeout", "150ms", out="tcp.json")
    found = {u["unit"]: u for u in (data or {}).get("units", [])}
    check(rc == 0 and sorted(found) == sorted(line), f"tcp: units {sorted(line)} found (got {sorted(found)}, exit {rc})")
    for unit, device in line.items():
        check(found.get(unit, {}).get("spec", {}).get("id") == device, f"tcp: unit {unit} identified as {device}")
        check("settings" not in found.get(unit, {"settings": 1}), f"tcp: unit {unit} has no line settings")
finally:
    p.terminate()
    p.wait(10)

print(f"{len(failures)} failure(s)")
sys.exit(1 if failures else 0)
