#!/usr/bin/python3
"""`mbconform spec discover` against a reference device served over Modbus
TCP (`mbconform serve`), as a user meets a drive whose map they do not know:
the skeleton it writes passes `spec check`, the probe stays within its
default budget of 2000 requests, and it finds at least 95% of the readable
registers the device's spec maps (counted register by register: a register
is found when every word of it is inside a block the skeleton states), and
nothing the spec does not map.

usage: discover_served.py MBCONFORM DEVICE WORK_DIR
"""
import json
import os
import re
import shutil
import subprocess
import sys
import threading

import yaml

MBC, DEVICE, WORK = sys.argv[1], sys.argv[2], sys.argv[3]
TABLES = {"holding": "holding", "input": "input", "coil": "coil", "discrete_input": "discrete_input"}


def main():
    shutil.rmtree(WORK, ignore_errors=True)
    os.makedirs(WORK)
    spec = json.loads(subprocess.check_output([MBC, "spec", "dump", DEVICE]))
    server = subprocess.Popen([MBC, "serve", "--device", DEVICE, "--tcp", "127.0.0.1:0"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    timer = threading.Timer(10, server.kill)  # no listening line in 10 s: fail, do not hang
    timer.start()
    line = server.stdout.readline()
    timer.cancel()
    if not line.startswith("listening tcp "):
        server.kill()
        sys.exit(f"serve did not listen: {line!r} {server.stderr.read()}")
    address = line.split()[2]
    out = os.path.join(WORK, "discovered.yaml")
    try:
        p = subprocess.run([MBC, "spec", "discover", "--target", f"tcp://{address}", "--out", out], capture_output=True,
                           text=True, timeout=600)
    finally:
        server.terminate()
        server.wait(timeout=10)
    print(p.stdout, p.stderr, end="")
    if p.returncode != 0:
        sys.exit(f"spec discover: exit {p.returncode}")
    failures = []
    check = subprocess.run([MBC, "spec", "check", out], capture_output=True, text=True)
    if check.returncode != 0:
        failures.append(f"the skeleton does not pass spec check:\n{check.stdout}{check.stderr}")
    text = open(out, encoding="utf-8").read()
    requests = int(re.search(r"\((\d+) read requests", text).group(1))
    if requests > 2000:
        failures.append(f"{requests} requests: over the default budget of 2000")
    if "PARTIAL" in text:  # the least likely places were left: said in the skeleton, no failure
        print("the probe's budget ran out before its last seeds:", re.search(r"# PARTIAL: (.*)", text).group(1))
    found = set()
    for r in yaml.safe_load(text)["registers"] or []:
        for a in range(r["address"], r["address"] + r.get("count", 1)):
            found.add((TABLES[r.get("table", "holding")], a))
    readable = [r for r in spec["registers"] if r["access"] != "wo"]
    hits = [r for r in readable if all((r["table"], r["address"] + k) in found for k in range(r["words"]))]
    missed = [f"{r['table']} {r['address']:#06x}" for r in readable if r not in hits]
    mapped = {(r["table"], r["address"] + k) for r in spec["registers"] for k in range(r["words"])}
    extra = sorted(a for a in found if a not in mapped)
    share = 100.0 * len(hits) / len(readable)
    print(f"{DEVICE}: found {len(hits)} of {len(readable)} readable registers ({share:.1f}%) in {requests} requests;"
          f" missed: {', '.join(missed) or 'none'}")
    if share < 95:
        failures.append(f"found {share:.1f}% of the readable registers, under 95%")
    if extra:
        failures.append(f"blocks over addresses the spec does not map: {extra[:10]}")
    for f in failures:
        print("FAIL:", f)
    return 1 if failures else 0


sys.exit(main())
