#!/usr/bin/python3
"""Every reader bounded (issue 41), the command line's side: a FIFO or a
device where a file is expected is one line and exit 2, never a hang (a FIFO
as `run --spec` or as a `check-capture` input hung); one duration parser,
range-checked, for every duration option (`--map-time 9999999h` sent
nothing, said "(nothing mapped)" and exited 0); warnings printed in a loop
are the first 20 and a count.

usage: readers_test.py MBCONFORM WORK_DIR
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


def mb(mbconform, *args):
    try:
        p = subprocess.run([mbconform, *args], capture_output=True, text=True, timeout=20, check=False)
    except subprocess.TimeoutExpired:
        return None, "(hung: killed after 20 s)"
    return p.returncode, p.stdout + p.stderr


def one_line_exit_2(rc, out, needle, what):
    lines = [l for l in out.splitlines() if l.strip() and not l.startswith("Run with --help")]
    check(rc == 2 and len(lines) == 1 and needle in out, f"{what}: one line naming it, exit 2 (rc {rc}: {out.strip()[:200]})")


def main():
    mbconform, work = sys.argv[1:3]
    os.makedirs(work, exist_ok=True)
    fifo = os.path.join(work, "fifo")
    if not os.path.exists(fifo):
        os.mkfifo(fifo)
    rc, out = mb(mbconform, "run", "--target", "ref:hsc60", "--spec", fifo, "--out", os.path.join(work, "r1"))
    one_line_exit_2(rc, out, "not a regular file", "a FIFO as run --spec")
    rc, out = mb(mbconform, "check-capture", fifo, "--device", "hsc60", "--out", os.path.join(work, "c1"))
    one_line_exit_2(rc, out, "not a regular file", "a FIFO as the check-capture input")
    rc, out = mb(mbconform, "check-capture", "/dev/zero", "--device", "hsc60", "--out", os.path.join(work, "c2"))
    one_line_exit_2(rc, out, "not a regular file", "a device as the check-capture input")

    for opt, cmd in (("--map-time", ["run", "--target", "ref:hsc60", "--out", os.path.join(work, "m")]),
                     ("--deadline", ["run", "--target", "ref:hsc60", "--out", os.path.join(work, "d")]),
                     ("--duration", ["fuzz", "--target", "ref:hsc60", "--out", os.path.join(work, "f")])):
        for text in ("9999999h", "2562048h", "1e400h", "nan", "-5s", "10x"):
            rc, out = mb(mbconform, *cmd, opt, text)
            one_line_exit_2(rc, out, f"{opt} '{text}'", f"{cmd[0]} {opt} {text}")
    # In range, the same text is taken by each (a short one, so the run is quick).
    rc, out = mb(mbconform, "run", "--target", "ref:hsc60", "--filter", "/registers/0x0040/read", "--deadline", "2m",
                 "--out", os.path.join(work, "ok"))
    check(rc == 0, f"run --deadline 2m is taken (rc {rc})")

    channels = [{"name": f"c{i}", "reg_type": "bogus", "address": i} for i in range(50)]
    template = os.path.join(work, "template.json")
    with open(template, "w", encoding="utf-8") as f:
        json.dump({"title": "x", "device_type": "x", "device": {"name": "x", "id": "x", "channels": channels}}, f)
    rc, out = mb(mbconform, "spec", "import", "--wb-template", template, "--id", "x-dev", "--out", os.path.join(work, "x-dev.yaml"))
    warnings = [l for l in out.splitlines() if ": warning: " in l]
    check(len(warnings) == 20 and "30 more warnings" in out,
          f"50 warnings: the first 20, then a count ({len(warnings)} printed)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
