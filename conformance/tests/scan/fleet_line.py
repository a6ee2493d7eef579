#!/usr/bin/python3
"""mbconform run over a fleet: every drive a scan identified, one report each.

Line A: three reference drives at units 3, 7 and 12 on one served line at
19200 8E1 (serve --line), the HSC60 broken with a served fault that only it
has registers for (swapped-words: its 2-word values are stored in the other
word order, so its word-order cases fail a MUST; the Hanstar and the Rieding
have no such register). Line B: a clean drive on a second served line.

- `scan --out` writes the scan file each line is qualified from.
- `run --scan-file A --plan` lists the three drives' frames with the line
  not served at all (it opens nothing).
- `run --scan-file A --scan-file B` qualifies the four drives, the lines at
  once: one report directory per drive (<port>-unit<N>), a summary.json and a
  junit.xml over them, and exits 1, the worst of the drives' codes (the HSC60
  fails; the others pass or are PARTIAL, 0).
- With unit 12 made unidentified in the scan file, unit 12 is listed as not
  run and the line's trace shows no frame addressed to it; every frame to a
  drive is sent while that drive is the one qualified (unit 3's frames all
  before unit 7's), and no write goes to unit 0.
- `run --scan --target B` scans the line first, then qualifies what it found.
- Bad input: a scan file that is not one, or a target in it moved to another
  unit, or --allow-broadcast, is one line and exit 2 with nothing sent.

The expectations (units, devices, which drive fails) are chosen here, from the
faults' definitions (serve --list-faults), not read from mbconform's output.

usage: fleet_line.py MBCONFORM WORKDIR
"""
import json
import os
import re
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

mb, work = sys.argv[1], sys.argv[2]
shutil.rmtree(work, ignore_errors=True)
os.makedirs(work)
LINE_A = {3: "hsc60", 7: "hanstar-7trsm5740q", 12: "rieding-dhe"}
FAULTY = 3  # hsc60: the one drive swapped-words breaks
LINE_B = {5: "rieding-dhe"}
# The cases each drive runs: the manuals' printed examples (a few each; the
# HSC60's FC 16 example writes a 2-word value, which swapped-words breaks).
FILTER = ["--filter", "/examples/"]
failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what)
    if not ok:
        failures.append(what)


class Served:
    def __init__(self, name, devices, line, *extra):
        self.pty = os.path.join(work, name)
        self.log = os.path.join(work, name + ".trace")
        args = [mb, "serve", "--pty", self.pty, "--line", line, "--trace"] + list(extra)
        for unit, device in devices.items():
            args += ["--device", f"{device}@{unit}"]
        self.p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=open(self.log, "w"), text=True)
        self.p.stdout.readline()  # "listening pty PATH"

    def stop(self):
        self.p.terminate()
        self.p.wait(10)

    def requests(self):
        """(time, unit, fc) of every request the line's drives received."""
        out = []
        for line in open(self.log, errors="replace"):
            m = re.match(r"(\S+Z) pty \S+ rx ((?:[0-9A-Fa-f]{2} ?)+)", line)
            if m:
                b = m.group(2).split()
                if len(b) >= 2:
                    out.append((m.group(1), int(b[0], 16), int(b[1], 16)))
        return out


def mbc(*args, timeout=900):
    t0 = time.monotonic()
    r = subprocess.run([mb] + list(args), capture_output=True, text=True, timeout=timeout)
    print(f"$ mbconform {' '.join(args)}\n  exit {r.returncode} in {time.monotonic() - t0:.1f} s")
    return r


def scan(served, units, out):
    path = os.path.join(work, out)
    r = mbc("scan", "rtu://" + served.pty, "--units", units, "--timeout", "150ms", "--budget", "5m", "--out", path, "-q")
    if r.returncode != 0:
        print(r.stdout, r.stderr)
    return r.returncode, json.load(open(path)) if os.path.exists(path) else None


a = Served("lineA", LINE_A, "19200-8E1", "--fault", "swapped-words")
b = Served("lineB", LINE_B, "9600-8N1")
try:
    rc, scan_a = scan(a, "1-15", "scanA.json")
    check(rc == 0 and scan_a is not None, f"line A scanned (exit {rc})")
    found = {u["unit"]: u.get("spec", {}).get("id") for u in (scan_a or {}).get("units", [])}
    check(found == LINE_A, f"line A: {LINE_A} identified (got {found})")
    rc, scan_b = scan(b, "1-8", "scanB.json")
    found = {u["unit"]: u.get("spec", {}).get("id") for u in (scan_b or {}).get("units", [])}
    check(rc == 0 and found == LINE_B, f"line B: {LINE_B} identified (got {found}, exit {rc})")
finally:
    a.stop()
scan_a_path, scan_b_path = os.path.join(work, "scanA.json"), os.path.join(work, "scanB.json")

# --plan from the scan file, with line A not served: nothing is opened.
r = mbc("run", "--scan-file", scan_a_path, *FILTER, "--plan")
check(r.returncode == 0, f"--plan of line A with the line gone exits 0 (got {r.returncode}: {r.stderr.strip()[-300:]})")
planned = re.findall(r"^# (\S+): \d+ cases, unit (\d+), RTU frames\ndevice (\S+)$", r.stdout, re.M)
check(sorted((int(u), d) for _, u, d in planned) == sorted(LINE_A.items()),
      f"--plan lists each drive of line A on its own spec (got {[(u, d) for _, u, d in planned]})")
check("# every drive on the line receives" not in r.stdout, "--plan sends no broadcast")

# The fleet: both lines at once.
a = Served("lineA", LINE_A, "19200-8E1", "--fault", "swapped-words")
out = os.path.join(work, "fleet")
try:
    r = mbc("run", "--scan-file", scan_a_path, "--scan-file", scan_b_path, *FILTER, "--out", out, "-q")
    print(r.stdout[-3000:], r.stderr[-2000:])
    check(r.returncode == 1, f"the fleet exits 1, its worst drive's code (got {r.returncode})")
    trace_a = a.requests()
finally:
    a.stop()
    b.stop()
summary = json.load(open(os.path.join(out, "summary.json"))) if os.path.exists(os.path.join(out, "summary.json")) else {}
drives = {(d["line"], d["unit"]): d for d in summary.get("drives", [])}
expected = {(a.pty, u): dev for u, dev in LINE_A.items()}
expected.update({(b.pty, u): dev for u, dev in LINE_B.items()})
check(sorted(drives) == sorted(expected), f"summary.json lists the four drives (got {sorted(drives)})")
check(summary.get("exit_code") == 1, f"summary.json: exit code 1 (got {summary.get('exit_code')})")
for (line, unit), device in expected.items():
    d = drives.get((line, unit), {})
    want = "FAIL" if (line, unit) == (a.pty, FAULTY) else None
    check(d.get("spec") == device, f"{os.path.basename(line)} unit {unit} ran on {device} (got {d.get('spec')})")
    if want:
        check(d.get("verdict") == "FAIL" and d.get("exit_code") == 1, f"unit {unit} FAILs, exit 1 (got {d.get('verdict')}, {d.get('exit_code')})")
    else:
        check(d.get("verdict") in ("PASS", "PARTIAL") and d.get("exit_code") == 0,
              f"{os.path.basename(line)} unit {unit} passes, exit 0 (got {d.get('verdict')}, {d.get('exit_code')})")
    rdir = os.path.join(out, f"{os.path.basename(line)}-unit{unit}")
    check(d.get("report") == os.path.basename(rdir), f"its report directory is {os.path.basename(rdir)} (got {d.get('report')})")
    rep = os.path.join(rdir, "report.json")
    if not os.path.exists(rep):
        check(False, f"{rep} written")
        continue
    j = json.load(open(rep))
    devs = j.get("devices", [])
    check(len(devs) == 1 and devs[0].get("device_id") == device and re.search(rf"[?&]unit={unit}(&|$)", devs[0].get("target_uri", "")),
          f"{rep}: one drive, {device} at unit {unit} (got {[(d.get('device_id'), d.get('target_uri')) for d in devs]})")
    check(all(os.path.exists(os.path.join(rdir, f)) for f in ("junit.xml", "report.html")), f"{rdir}: junit.xml, report.html")
junit = os.path.join(out, "junit.xml")
if os.path.exists(junit):
    root = ET.parse(junit).getroot()
    suites = root.findall("testsuite")
    check(len(suites) == 4, f"junit.xml: a testsuite per drive (got {len(suites)})")
    check(int(root.get("failures", "0")) > 0, f"junit.xml: the HSC60's failures counted (got {root.get('failures')})")
else:
    check(False, "junit.xml written")
check("FLEET:" in r.stdout, "the summary table is printed")

# Every frame on line A went to the drive being qualified, one drive after another.
units_seen = [u for _, u, _ in trace_a]
for unit in LINE_A:
    check(unit in units_seen, f"line A: unit {unit} was sent frames")
writes = {5, 6, 15, 16, 22, 23}
check(not [1 for _, u, fc in trace_a if u == 0 and fc in writes], "line A: no broadcast write")
spans = {u: [k for k, (_, uu, _) in enumerate(trace_a) if uu == u] for u in LINE_A}
order = sorted(LINE_A, key=lambda u: spans[u][0] if spans[u] else 0)
interleaved = [(x, y) for x, y in zip(order, order[1:]) if spans[x] and spans[y] and spans[x][-1] > spans[y][0]]
check(not interleaved, f"line A: each drive's frames end before the next drive's begin (order {order}; interleaved {interleaved})")

# A unit the scan did not identify is listed and never sent a frame.
edited = json.load(open(scan_a_path))
for u in edited["units"]:
    if u["unit"] == 12:
        u.pop("spec", None)
        u["confidence"] = "none"
unident = os.path.join(work, "scanA-unidentified.json")
json.dump(edited, open(unident, "w"))
a = Served("lineA", LINE_A, "19200-8E1")
out2 = os.path.join(work, "fleet-unidentified")
try:
    r = mbc("run", "--scan-file", unident, *FILTER, "--out", out2, "-q")
    trace = a.requests()
finally:
    a.stop()
check(r.returncode == 0, f"clean drives and one not identified: exit 0 (got {r.returncode}; {r.stderr.strip()[-300:]})")
s2 = json.load(open(os.path.join(out2, "summary.json"))) if os.path.exists(os.path.join(out2, "summary.json")) else {}
u12 = [d for d in s2.get("drives", []) if d.get("unit") == 12]
check(len(u12) == 1 and u12[0].get("verdict") == "NOT RUN" and u12[0].get("report") is None,
      f"unit 12 is listed as NOT RUN, with no report (got {u12})")
check(not os.path.exists(os.path.join(out2, "lineA-unit12")), "no report directory for unit 12")
check(not [1 for _, u, _ in trace if u == 12], f"no frame was addressed to unit 12 ({sum(1 for _, u, _ in trace if u == 12)} were)")
check([1 for _, u, _ in trace if u == 3] and [1 for _, u, _ in trace if u == 7], "units 3 and 7 were qualified")

# --scan: the line scanned first, then qualified.
b = Served("lineB", LINE_B, "9600-8N1")
out3 = os.path.join(work, "fleet-scan")
try:
    r = mbc("run", "--scan", "--target", "rtu://" + b.pty, "--scan-units", "1-8", *FILTER, "--out", out3, "-q")
finally:
    b.stop()
s3 = json.load(open(os.path.join(out3, "summary.json"))) if os.path.exists(os.path.join(out3, "summary.json")) else {}
got = {d["unit"]: (d.get("spec"), d.get("verdict")) for d in s3.get("drives", [])}
check(r.returncode == 0 and set(got) == set(LINE_B) and all(v[0] == LINE_B[u] and v[1] in ("PASS", "PARTIAL") for u, v in got.items()),
      f"--scan of line B: {LINE_B} found and qualified, exit 0 (got {got}, exit {r.returncode}; {r.stderr.strip()[-300:]})")

# Bad input: one line, exit 2, nothing opened (the line is not served).
notjson = os.path.join(work, "not-a-scan.json")
open(notjson, "w").write("units: [3]\n")
moved = json.load(open(scan_a_path))
moved["units"][0]["target"] = moved["units"][0]["target"].replace("unit=3", "unit=4")
moved_path = os.path.join(work, "moved.json")
json.dump(moved, open(moved_path, "w"))
for args, what in (([ "--scan-file", notjson], "not JSON"),
                   (["--scan-file", moved_path], "a target moved to another unit"),
                   (["--scan-file", scan_a_path, "--allow-broadcast"], "--allow-broadcast"),
                   (["--scan-file", scan_a_path, "--target", "rtu://" + a.pty], "--target with --scan-file"),
                   (["--scan-file", os.path.join(work, "nothing.json")], "no such file")):
    r = mbc("run", *args, "--out", os.path.join(work, "bad"))
    lines = [l for l in r.stderr.splitlines() if l.strip()]
    check(r.returncode == 2 and len(lines) == 1, f"{what}: exit 2 and one line (got {r.returncode}: {r.stderr.strip()[:300]})")

print(f"{len(failures)} failure(s)")
sys.exit(1 if failures else 0)
