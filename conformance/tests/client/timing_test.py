#!/usr/bin/python3
"""Master-side timing (`mbconform client --transport pty`, conformance/client/):
the shipped broken_master keeps t3.5 before each frame and waits a turnaround
delay after a broadcast; with --defects no-t35,no-turnaround it does neither,
and the client/timing checks say so. The pty delivers at once, so a master's
pause is its own: a busy host only lengthens it, and the two masters' waits
are compared as a ratio, never against a wall-clock bound.

usage: timing_test.py MBCONFORM BROKEN_MASTER OUT_DIR
"""
import json
import re
import shutil
import subprocess
import sys


def run(mbconform, adapter, out):
    shutil.rmtree(out, ignore_errors=True)
    # 300 baud: t3.5 is 128 ms, far longer than the adapter protocol's round trip between two requests.
    cmd = [mbconform, "client", "--quiet", "--adapter", adapter, "--transport", "pty", "--baud", "300",
           "--filter", "client/timing", "--out", out]
    print("$ " + " ".join(cmd), flush=True)
    subprocess.run(cmd, check=False)
    with open(out + "/report.json", encoding="utf-8") as f:
        return {c["id"]: c for c in json.load(f)["devices"][0]["cases"]}


def waits_ms(case):
    m = re.search(r"waited ([0-9.]+) ms after the broadcast", case.get("message", ""))
    return float(m.group(1)) if m else None


def main():
    mbconform, master, out = sys.argv[1:4]
    problems = []
    good = run(mbconform, master, out + "/correct")
    bad = run(mbconform, master + " --defects no-t35,no-turnaround", out + "/broken")
    for name, cases in (("correct", good), ("broken", bad)):
        for cid in ("client/timing/t3.5", "client/timing/broadcast-turnaround"):
            if cid not in cases:
                problems.append("%s master: no %s in the report" % (name, cid))
    if problems:
        print("\n".join("FAIL " + p for p in problems))
        return 1
    t35_good, t35_bad = good["client/timing/t3.5"], bad["client/timing/t3.5"]
    if t35_good["outcome"] != "pass":
        problems.append("correct master: t3.5 %s: %s" % (t35_good["outcome"], t35_good.get("message", "")))
    if t35_bad["outcome"] == "pass" or "before a frame (t3.5 = " not in t35_bad.get("message", ""):
        problems.append("broken master: t3.5 not found: %s %s" % (t35_bad["outcome"], t35_bad.get("message", "")))
    w_good, w_bad = waits_ms(good["client/timing/broadcast-turnaround"]), waits_ms(bad["client/timing/broadcast-turnaround"])
    print("broadcast turnaround: correct master %s ms, broken master %s ms" % (w_good, w_bad))
    if w_good is None or w_bad is None:
        problems.append("no wait recorded: %s / %s" % (good["client/timing/broadcast-turnaround"].get("message"),
                                                       bad["client/timing/broadcast-turnaround"].get("message")))
    elif not w_bad * 2 < w_good:
        problems.append("the master without a turnaround delay waited %.1f ms, the correct one %.1f ms" % (w_bad, w_good))
    for p in problems:
        print("FAIL " + p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
