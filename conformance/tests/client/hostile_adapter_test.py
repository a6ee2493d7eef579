#!/usr/bin/python3
"""`mbconform client` against a hostile adapter (hostile_adapter.py), each
attack with the figures it must keep: no crash (exit 1: the case the attack
met fails), mbconform's peak RSS at most 290 MB above that of `mbconform
--version` in the same build (a flood of stderr once grew it to 2 GB; under
ASan the baseline alone is about 310 MB), report.json under 8 MB (once 671 MB), done within 120 s (bounds
for a loaded 2-core machine), and what happened said in one line.

usage: hostile_adapter_test.py MBCONFORM HOSTILE_ADAPTER WORK_DIR MODE
"""
import json
import os
import subprocess
import sys
import tempfile
import time

failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


def peak_rss_mb(argv):
    """Runs argv to its end; its own peak RSS in MB (wait4), its exit status and its output."""
    with tempfile.TemporaryFile() as log:
        p = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        return usage.ru_maxrss / 1024, p.returncode, log.read().decode("utf-8", "replace")


def main():
    mbconform, adapter, work, mode = sys.argv[1:5]
    os.makedirs(work, exist_ok=True)
    out = os.path.join(work, mode)
    base_mb = peak_rss_mb([mbconform, "--version"])[0]
    t0 = time.time()
    rss_mb, rc, text = peak_rss_mb([mbconform, "client", "--quiet", "--adapter", f"/usr/bin/python3 {adapter} {mode}",
                                    "--filter", "client/request/read_coils", "--timeout-ms", "200", "--out", out])
    seconds = time.time() - t0
    print(f"     {mode}: exit {rc}, {seconds:.1f} s, peak RSS {rss_mb:.0f} MB (--version: {base_mb:.0f} MB), "
          f"output {len(text)} bytes")
    check(rc == 1, f"{mode}: exit 1, no crash ({rc})")
    check(rss_mb < base_mb + 290, f"{mode}: peak RSS {rss_mb:.0f} MB < {base_mb:.0f} + 290 MB")
    check(seconds < 120, f"{mode}: done in {seconds:.1f} s < 120 s")
    check(len(text) < 8 << 20, f"{mode}: the terminal output is bounded ({len(text)} bytes)")
    path = os.path.join(out, "report.json")
    size = os.path.getsize(path) if os.path.exists(path) else -1
    check(0 < size < 8 << 20, f"{mode}: report.json {size} bytes < 8 MB")
    if size <= 0:
        return 1
    with open(path, encoding="utf-8") as f:
        report = json.load(f)
    case = {c["id"]: c for c in report["devices"][0]["cases"]}.get("client/request/read_coils", {})
    log = report["adapter"]["log"]
    check(case.get("outcome") == "fail", f"{mode}: the case the attack met fails ({case.get('outcome')})")
    if mode == "stderr-flood":
        check("bytes was dropped" in log, f"{mode}: the log says how much of the flood was dropped")
    elif mode == "deep-json":
        check("nested deeper than" in log, f"{mode}: the log names the nesting")
    elif mode == "long-line":
        check("longer than" in log, f"{mode}: the log names the long line")
    elif mode == "exit":
        msg = case.get("message", "") + json.dumps(case.get("extra", {}))
        check("exited with status 3" in msg and "hang" not in msg,
              f"{mode}: the adapter is reported as exited with its status, not as hung")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
