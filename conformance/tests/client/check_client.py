#!/usr/bin/python3
"""Runs `mbconform client` for one adapter and checks that exactly the
deviations listed in its file fail, and nothing else: the list documents what
the library gets wrong, and this test fails when the library changes.

usage: check_client.py MBCONFORM DEVIATIONS.yaml OUT_DIR -- ADAPTER ARGS... [--transport T]
  MBCONFORM        build/bin/mbconform
  DEVIATIONS.yaml  a quirks file (conformance/client/README.md): case ids, not globs
  OUT_DIR          the report directory (replaced)
  after --          the rest is passed to `mbconform client`
"""
import json
import shutil
import subprocess
import sys

import yaml


def main():
    mbconform, deviations, out = sys.argv[1:4]
    rest = sys.argv[sys.argv.index("--") + 1:]
    with open(deviations, encoding="utf-8") as f:
        listed = {q["case"] for q in (yaml.safe_load(f) or [])}
    shutil.rmtree(out, ignore_errors=True)
    cmd = [mbconform, "client", "--quiet", "--quirks", deviations, "--out", out] + rest
    print("$ " + " ".join(cmd), flush=True)
    rc = subprocess.run(cmd, check=False).returncode
    problems = []
    try:
        with open(out + "/report.json", encoding="utf-8") as f:
            report = json.load(f)
    except OSError as e:
        print("FAIL no report (exit %d): %s" % (rc, e))
        return 1
    cases = report["devices"][0]["cases"]
    # A declared deviation stays a failure, reported apart with its reason ("quirk").
    quirked = {c["id"] for c in cases if c["outcome"] == "fail" and c.get("quirk")}
    failing = {c["id"]: c.get("message", "") for c in cases if c["outcome"] == "fail" and not c.get("quirk")}
    for cid in sorted(listed - quirked):
        problems.append("listed in %s but did not fail: %s" % (deviations, cid))
    for cid, msg in sorted(failing.items()):
        problems.append("fails but is not listed in %s: %s: %s" % (deviations, cid, msg))
    if rc != 0 and not problems:
        problems.append("mbconform client exited %d" % rc)
    d = report["devices"][0]
    print("%s: %d cases, %d deviations as listed; wall %.2f s, wire-time bound %.2f s" % (
        d["device_id"] if "device_id" in d else "?", len(cases), len(quirked & listed),
        d.get("wall_seconds", 0), d.get("wire_time_bound_seconds", 0)))
    for p in problems:
        print("FAIL " + p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
