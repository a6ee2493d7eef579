#!/usr/bin/python3
"""A test adapter for the protocol runner: it says hello, connects, hangs
forever on its first read_coils, and answers "unsupported" to anything else.
(The real libraries' adapters are in conformance/peers/adapters/.)"""
import json
import sys
import time

for line in sys.stdin:
    m = json.loads(line)
    if "hello" in m:
        out = {"protocol": 1, "library": "hanging", "version": "0", "ops": ["read_coils", "read_discrete_inputs"],
               "raw": False, "retries": True}
    elif "connect" in m:
        out = {"ready": True}
    elif "disconnect" in m:
        out = {"disconnected": True}
    elif m.get("op") == "close":
        break
    elif m.get("op") == "read_coils":
        print("hanging on purpose", file=sys.stderr, flush=True)
        time.sleep(3600)
        continue
    else:
        out = {"id": m.get("id"), "ok": False, "error": "unsupported"}
    print(json.dumps(out), flush=True)
