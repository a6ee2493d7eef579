#!/usr/bin/python3
"""report.html as an integrator opens it, in headless Chromium (Debian
`chromium`): the DOM opens with the qualification summary (a verdict
banner, per device its identity, firmware, line settings, counts by level
with the OBSERVED share, the failures grouped by cause with register names
and a replay command, errata, skipped families with their flags), and the
details (failures with a byte diff, the register grid with names) come
after it; printed to PDF (A4), the summary takes at most two pages.

usage: report_browser.py MBCONFORM WORK_DIR
"""
import os
import shutil
import subprocess
import sys
from html.parser import HTMLParser

MBC, WORK = sys.argv[1], sys.argv[2]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


class Dom(HTMLParser):
    """The elements in document order: (tag, attrs, text inside up to the next tag)."""

    def __init__(self):
        super().__init__()
        self.elements = []

    def handle_starttag(self, tag, attrs):
        self.elements.append([tag, dict(attrs), ""])

    def handle_data(self, data):
        if self.elements:
            self.elements[-1][2] += data

    def find(self, tag=None, cls=None, **attrs):
        return [i for i, (t, a, _) in enumerate(self.elements)
                if (tag is None or t == tag) and (cls is None or cls in (a.get("class") or "").split())
                and all(a.get(k.replace("_", "-")) == v for k, v in attrs.items())]


def chromium(*args):
    # --no-sandbox: ctest may run as root, where Chromium's sandbox refuses to start.
    return subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                           f"--user-data-dir={WORK}/profile", *args], capture_output=True, text=True, timeout=120)


def main():
    if not CHROMIUM:
        sys.exit("chromium is not installed (tools/setup.sh installs it)")
    if not shutil.which("pdfinfo") or not shutil.which("pdftotext"):
        sys.exit("pdfinfo/pdftotext are not installed (Debian poppler-utils; tools/setup.sh installs them)")
    shutil.rmtree(WORK, ignore_errors=True)
    os.makedirs(WORK)
    out = os.path.join(WORK, "run")
    # A drive with a fault (out-of-range writes stored: many failures of one cause),
    # served over TCP as a live drive is (so the safety rules skip what needs
    # a flag): the verdict is FAIL.
    server = subprocess.Popen([MBC, "serve", "--device", "sihong-57hs-r", "--fault", "accept-out-of-range", "--tcp", "127.0.0.1:0"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = server.stdout.readline()
    check(line.startswith("listening tcp "), f"serve listens: {line!r}")
    try:
        p = subprocess.run([MBC, "run", "--quiet", "--target", f"tcp://{line.split()[2]}", "--device", "sihong-57hs-r", "--out", out],
                           capture_output=True, text=True, timeout=600)
    finally:
        server.terminate()
        server.wait(timeout=10)
    check(p.returncode == 1, f"run exits 1 (a MUST failed): {p.returncode} {p.stderr[-500:]}")
    page = "file://" + os.path.abspath(os.path.join(out, "report.html"))

    dom = chromium("--dump-dom", page)
    check(dom.returncode == 0 and "<html" in dom.stdout, f"chromium loads the page: exit {dom.returncode} {dom.stderr[-300:]}")
    d = Dom()
    d.feed(dom.stdout)
    verdict = d.find("div", "verdict")
    check(len(verdict) == 1 and "fail" in d.elements[verdict[0]][1]["class"] and d.elements[verdict[0] + 1][2].startswith("FAIL"),
          "one verdict banner, FAIL")
    details = d.find("div", "detail")
    check(len(details) == 1 and verdict and verdict[0] < details[0], "the summary comes before the details")
    summaries = d.find("section", "device-summary")
    check([d.elements[i][1]["data-device"] for i in summaries] == ["sihong-57hs-r"],
          f"a summary of the device: {[d.elements[i][1].get('data-device') for i in summaries]}")
    first_detail = details[0] if details else len(d.elements)
    text_of = lambda lo, hi: " ".join(e[2] for e in d.elements[lo:hi])
    summary_text = text_of(0, first_detail)
    for words in ("Identity", "Firmware", "only OBSERVED", "enable with --allow-", "mbconform run --target"):
        check(words in summary_text, f"the summary says '{words}'")
    # A Modbus TCP target has no serial line: no line settings are shown for it.
    check("Line settings" not in summary_text, "no 'Line settings' for a tcp:// target")
    check(len(d.find("table", "causes")) == 1, "the failures are grouped by cause")
    causes = [i for i in d.find("tr", "fail") if i < first_detail]
    check(0 < len(causes) <= 6, f"a few causes, not one line per case: {len(causes)}")
    check("0x" in text_of(causes[0], causes[0] + 8) if causes else False, "a cause names its registers")
    for level in ("MUST", "SHOULD", "OBSERVED"):
        check(len([i for i in d.find("tr", data_level=level) if i < first_detail]) == 1, f"the count of {level} cases")
    failures_h = [i for i in d.find("h3", "failures") if i > first_detail]
    grid = [i for i, e in enumerate(d.elements) if e[0] == "table" and "regs" in (e[1].get("class") or "")]
    check(failures_h and grid and failures_h[0] < grid[0], "below the summary: failures, then the register grid")
    check(len(d.find("mark")) > 0, "the failures mark the bytes that differ")
    check(any(e[0] == "th" and e[2] == "name" for e in d.elements[grid[0]:grid[0] + 5]) if grid else False,
          "the register grid has a name column")

    # Printed: A4, the summary on at most two pages (the details start on a page of their own).
    pdf = os.path.join(WORK, "report.pdf")
    r = chromium("--no-pdf-header-footer", f"--print-to-pdf={pdf}", page)
    check(r.returncode == 0 and os.path.exists(pdf), f"chromium prints the page: exit {r.returncode} {r.stderr[-300:]}")
    info = subprocess.run(["pdfinfo", pdf], capture_output=True, text=True).stdout
    pages = int(next(l.split()[1] for l in info.splitlines() if l.startswith("Pages:")))
    check("(A4)" in info, f"A4 pages: {[l for l in info.splitlines() if l.startswith('Page size')]}")
    summary_pages = None
    for n in range(1, pages + 1):
        t = subprocess.run(["pdftotext", "-f", str(n), "-l", str(n), pdf, "-"], capture_output=True, text=True).stdout
        if t.lstrip().startswith("Details"):
            summary_pages = n - 1
            break
    check(summary_pages is not None and 1 <= summary_pages <= 2, f"the summary takes {summary_pages} A4 page(s) of {pages}")
    shot = os.path.join(WORK, "report.png")
    chromium("--window-size=1280,1600", f"--screenshot={shot}", page)
    print(f"screenshot: {shot}; pdf: {pdf}")
    return 1 if failures else 0


sys.exit(main())
