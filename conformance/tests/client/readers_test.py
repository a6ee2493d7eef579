#!/usr/bin/python3
"""Every reader bounded (issue 41), the command line's side: a FIFO or a
device where a file is expected is one line and exit 2, never a hang (a FIFO
as `run --spec` or as a `check-capture` input hung); one duration parser,
range-checked, for every duration option (`--map-time 9999999h` sent
nothing, said "(nothing mapped)" and exited 0; `client --timeout-ms -5` was
sent to the adapter); warnings printed in a loop are the first 20 and a
count; a template is read up to the importer's cap (a 16 MB one took 13.4 s
and 360 MB with 144k warnings): over it, one line and exit 2 before it is
read; just under it, with a warning on every channel, the first 20 warnings
and a count, with peak RSS and time bounds a loaded 2-core machine under
ASan keeps (release: about 3 s and 70 MB).

usage: readers_test.py MBCONFORM WORK_DIR
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


def mb(mbconform, *args):
    try:
        p = subprocess.run([mbconform, *args], capture_output=True, text=True, timeout=20, check=False)
    except subprocess.TimeoutExpired:
        return None, "(hung: killed after 20 s)"
    return p.returncode, p.stdout + p.stderr


def one_line_exit_2(rc, out, needle, what):
    lines = [l for l in out.splitlines() if l.strip() and not l.startswith("Run with --help")]
    check(rc == 2 and len(lines) == 1 and needle in out, f"{what}: one line naming it, exit 2 (rc {rc}: {out.strip()[:200]})")


def peak_rss_mb(argv):
    """Runs argv to its end: its own peak RSS in MB (wait4), exit status, seconds and output."""
    with tempfile.TemporaryFile() as log:
        t0 = time.time()
        p = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
        seconds = time.time() - t0
        log.seek(0)
        return usage.ru_maxrss / 1024, os.waitstatus_to_exitcode(status), seconds, log.read().decode("utf-8", "replace")


def template_of(channels):
    return json.dumps({"title": "x", "device_type": "x", "device": {"name": "x", "id": "x", "channels": channels}})


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

    # The client's response time-out is range-checked like every duration.
    for text in ("-5", "0", "99999999"):
        rc, out = mb(mbconform, "client", "--adapter", "/bin/false", "--timeout-ms", text, "--out", os.path.join(work, "t"))
        one_line_exit_2(rc, out, "--timeout-ms", f"client --timeout-ms {text}")

    # Templates at the importer's cap (spec/exchange/exchange.h: 4 MiB).
    cap = 4 << 20
    channels, i = [], 0
    while True:
        channels += [{"name": f"channel number {j}", "reg_type": "bogus", "address": j} for j in range(i, i + 1000)]
        i += 1000
        text = template_of(channels)
        if len(text) > cap - 100_000:
            break
    under = os.path.join(work, "under-cap.json")
    with open(under, "w", encoding="utf-8") as f:
        f.write(text)
    over = os.path.join(work, "over-cap.json")
    with open(over, "w", encoding="utf-8") as f:
        f.write(text + " " * (cap - len(text) + 1))
    rc, out = mb(mbconform, "spec", "import", "--wb-template", over, "--id", "over-cap", "--out", os.path.join(work, "over-cap.yaml"))
    one_line_exit_2(rc, out, f"more than the {cap}", "a template one byte over the cap")
    check(not os.path.exists(os.path.join(work, "over-cap.yaml")), "a template over the cap: nothing written")
    base_mb = peak_rss_mb([mbconform, "--version"])[0]
    rss_mb, rc, seconds, out = peak_rss_mb([mbconform, "spec", "import", "--wb-template", under, "--id", "under-cap",
                                            "--out", os.path.join(work, "under-cap.yaml")])
    warnings = [l for l in out.splitlines() if ": warning: " in l]
    print(f"     a {len(text)}-byte template of {i} channels: exit {rc}, {seconds:.1f} s, peak RSS {rss_mb:.0f} MB "
          f"(--version: {base_mb:.0f} MB), {len(out)} bytes of output")
    check(rc in (0, 1), f"a template just under the cap is read, no crash (rc {rc})")
    check(len(warnings) == 20 and f"{i - 20} more warnings" in out,
          f"{i} warnings: the first 20, then a count ({len(warnings)} printed)")
    check(rss_mb < base_mb + 250, f"peak RSS {rss_mb:.0f} MB < {base_mb:.0f} + 250 MB")
    check(seconds < 120, f"done in {seconds:.1f} s < 120 s")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
