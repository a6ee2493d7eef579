#!/usr/bin/python3
"""A hostile adapter for `mbconform client` (issue 41): it says hello and
connects, then on its first read_coils does one thing (argv[1]):
  stderr-flood  writes 300 MB to stderr, then answers
  deep-json     answers with a JSON line nested 150,000 levels deep
  long-line     writes a 40 MB line without a newline on stdout, then answers
  exit          exits with status 3
Anything else is "unsupported"."""
import json
import os
import sys

mode = sys.argv[1]


def say(obj):
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


for line in sys.stdin:
    m = json.loads(line)
    if "hello" in m:
        say({"protocol": 1, "library": "hostile-" + mode, "version": "0", "ops": ["read_coils"], "raw": False,
             "retries": True})
    elif "connect" in m:
        say({"ready": True})
    elif "disconnect" in m:
        say({"disconnected": True})
    elif m.get("op") == "close":
        break
    elif m.get("op") == "read_coils":
        if mode == "stderr-flood":
            chunk = b"E" * (1 << 20)
            for _ in range(300):
                os.write(2, chunk)
        elif mode == "deep-json":
            sys.stdout.write("[" * 150000 + "]" * 150000 + "\n")
            sys.stdout.flush()
        elif mode == "long-line":
            sys.stdout.write("x" * (40 << 20))
            sys.stdout.write("\n")
            sys.stdout.flush()
        elif mode == "exit":
            sys.exit(3)
        say({"id": m.get("id"), "ok": False, "error": "unsupported"})
    else:
        say({"id": m.get("id"), "ok": False, "error": "unsupported"})
