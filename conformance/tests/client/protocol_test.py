#!/usr/bin/python3
"""The adapter protocol's failure paths, against `mbconform client`:
an adapter that does not start, one that is not ready, one that hangs, and a
malformed quirks file.

usage: protocol_test.py MBCONFORM LIBMODBUS_ADAPTER HANGING_ADAPTER WORK_DIR
"""
import json
import os
import subprocess
import sys

failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


def client(mbconform, *args):
    p = subprocess.run([mbconform, "client", "--quiet"] + list(args), capture_output=True, text=True, timeout=60,
                       check=False)
    return p.returncode, p.stdout + p.stderr


def main():
    mbconform, libmodbus, hanging, work = sys.argv[1:5]
    os.makedirs(work, exist_ok=True)
    rc, out = client(mbconform, "--adapter", "/nonexistent/adapter", "--out", work + "/none")
    check(rc == 2 and "did not answer hello" in out, "an adapter that does not start: exit 2 (%d)" % rc)
    rc, out = client(mbconform, "--adapter", libmodbus, "--transport", "rtu-tcp", "--out", work + "/notready")
    check(rc == 2 and "not ready" in out and "rtu-tcp" in out, "ready: false (libmodbus on rtu-tcp): exit 2 (%d)" % rc)
    rc, out = client(mbconform, "--adapter", "/usr/bin/python3 " + hanging, "--filter", "client/request/read_",
                     "--timeout-ms", "100", "--out", work + "/hang")
    check(rc == 1, "a hanging adapter fails its case: exit 1 (%d)" % rc)
    with open(work + "/hang/report.json", encoding="utf-8") as f:
        report = json.load(f)
    cases = {c["id"]: c for c in report["devices"][0]["cases"]}
    coils = cases.get("client/request/read_coils", {})
    check(coils.get("outcome") == "fail" and "hang" in coils.get("message", ""), "the hung case is a FAIL naming the hang")
    check(report["adapter"]["restarts"] == 1, "the adapter was restarted once")
    check("hanging on purpose" in report["adapter"]["log"], "the adapter's stderr is in the report")
    inputs = cases.get("client/request/read_discrete_inputs", {})
    check("unsupported" in json.dumps(inputs.get("extra", {})), "the run went on after the restart")
    check(cases.get("client/request/read_holding_registers", {}).get("outcome") == "skip",
          "an op the adapter does not list is skipped, not failed")
    bad = work + "/bad-quirks.yaml"
    with open(bad, "w", encoding="utf-8") as f:
        f.write("- case: client/reply/exception\n  why: missing reason\n")
    rc, out = client(mbconform, "--adapter", libmodbus, "--quirks", bad, "--out", work + "/badq")
    check(rc == 2 and bad + ":2:" in out and "error: quirks" in out, "a malformed quirks file: file:line:col, exit 2")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
