#!/usr/bin/python3
"""The conformance matrix of real Modbus libraries, both directions.

Runs every library of conformance/peers/matrix.yaml
  - as a server: its server glue started here, then
    `mbconform run --map auto --device modbus-standard --allow-writes --allow-disruptive` over each
    transport it serves (tcp, rtu-tcp, and RTU on a pty pair made by socat);
  - as a master: `mbconform client` with its adapter over each transport;
and writes OUT/matrix.json, a self-contained OUT/matrix.html (one row per
library, side and transport, one column per case family) and each run's
report in OUT/runs/<row>/report.html.

usage: conformance/peers/matrix.py [--build DIR] [--out DIR] [--only NAME,...] [--mbconform BIN]
       conformance/peers/matrix.py --check docs/matrix/matrix.json [--out DIR] ...
  --out    where to write (default docs/matrix)
  --only   run only these libraries; without --check their rows replace theirs
           in OUT/matrix.json and every other library's rows are kept
  --check  regenerate into --out (default build/matrix) and compare the
           verdicts with a committed matrix.json: per row its status, counts
           per family and failing cases (not timings, not messages, not HTML).
           Exit 1 when they differ, naming each difference.
Exit codes: 0 written (or fresh), 1 stale, 2 the matrix could not be made.
"""
import argparse
import fnmatch
import html
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time

import yaml

SOURCE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SIDES = ("server", "master")
TRANSPORTS = ("tcp", "rtu-tcp", "pty", "tls")
DEVICE = "modbus-standard"
BAUD = 38400
OUTCOMES = ("pass", "fail", "observed", "unsupported", "skip", "error")


_ports_given = set()
_ports_lock = threading.Lock()


def free_port():
    """A port free now and not given to another row of this run (rows run side by side)."""
    with _ports_lock:
        while True:
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = s.getsockname()[1]
            if port not in _ports_given:
                _ports_given.add(port)
                return port


def fill(cmd, ctx):
    for k, v in ctx.items():
        cmd = cmd.replace("{" + k + "}", str(v))
    return cmd


def sh(cmd, **kw):
    return subprocess.run(["/bin/sh", "-c", cmd], check=False, **kw)


class PtyPair:
    """Two linked ptys (socat): the server opens one end, mbconform the other."""

    def __init__(self, tmp):
        self.server, self.client = os.path.join(tmp, "server"), os.path.join(tmp, "client")
        self.proc = subprocess.Popen(["socat", "pty,raw,echo=0,link=" + self.server, "pty,raw,echo=0,link=" + self.client],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(100):
            if os.path.exists(self.server) and os.path.exists(self.client):
                return
            time.sleep(0.05)
        raise RuntimeError("socat made no pty pair")

    def close(self):
        self.proc.terminate()
        self.proc.wait()


class Server:
    """A library's server glue. A server that dies during the run stays dead:
    the runner reports the case it died on and lists the rest as not run
    (`died` keeps its exit status). One wedged on a pty is killed and started
    again once the run has lost it, so that the restore of what the run wrote
    finds a server (`restarts`)."""

    def __init__(self, cmd, log):
        self.cmd, self.log, self.restarts, self.died = cmd, log, 0, None
        self.ready = threading.Event()
        self.start()

    def start(self):
        self.ready.clear()
        self.proc = subprocess.Popen(["/bin/sh", "-c", "exec " + self.cmd], stdout=subprocess.PIPE, stderr=self.log,
                                     text=True, start_new_session=True)
        threading.Thread(target=self.read, args=(self.proc,), daemon=True).start()
        if not self.ready.wait(30):
            self.stop()
            raise RuntimeError("the server did not print 'listening' within 30 s: " + self.cmd)

    def read(self, proc):
        for line in proc.stdout:
            self.log.write(line)
            self.log.flush()
            if line.startswith("listening"):
                self.ready.set()

    def restart(self):
        self.log.write("matrix: the run lost the target; restarting the server\n")
        self.restarts += 1
        self.stop()
        self.start()

    def stop(self):
        if self.proc.poll() is not None:
            if self.died is None:
                self.died = self.proc.returncode
            return
        os.killpg(self.proc.pid, 15)
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, 9)
            self.proc.wait()


def load_quirks(path):
    if not os.path.exists(path):
        return []
    with open(path, encoding="utf-8") as f:
        return yaml.safe_load(f) or []


def match(entries, case_id, key, transport=None):
    """The first entry whose case glob matches (and whose `transports`, if it
    names any, include this one)."""
    for e in entries:
        if "case" in e and fnmatch.fnmatchcase(case_id, e["case"]) and transport in e.get("transports", [transport]):
            return e[key]
    return None


def field_practice(lib, sets):
    """A library's own field-practice entries, then those of the shared sets it names."""
    return lib.get("field_practice", []) + [e for name in lib.get("field_practice_sets", []) for e in sets[name]]


def summarize(report_path, row, declared, field_practice):
    """Counts per family and the failing cases of one run's report.json."""
    with open(report_path, encoding="utf-8") as f:
        report = json.load(f)
    dev = report["devices"][0]
    cells, failures = {}, []
    for c in dev["cases"]:
        family = c.get("family") or c["id"].split("/")[1]
        outcome = c["outcome"]
        if outcome == "skip" and c.get("message", "").startswith("unsupported"):
            outcome = "unsupported"
        cell = cells.setdefault(family, {k: 0 for k in OUTCOMES})
        cell[outcome] = cell.get(outcome, 0) + 1
        if outcome == "fail":  # the cases not run (a target lost) are counted in the cells
            failures.append({"case": c["id"], "outcome": outcome, "level": c.get("level", ""), "clause": c.get("clause", ""),
                             "message": c.get("message", "").split("\n")[0][:400],
                             "declared": match(declared, c["id"], "reason"),
                             "field_practice": match(field_practice, c["id"], "why", row["transport"])})
    row["cells"] = cells
    row["failures"] = failures
    row["incomplete"] = bool(report.get("incomplete"))
    row["wall_seconds"] = round(dev.get("wall_seconds", 0), 2)


def scrub_report(run_dir, replace):
    """The committed report.html names no path of this machine and no port of this run."""
    path = os.path.join(run_dir, "report.html")
    if not os.path.exists(path):
        return
    with open(path, encoding="utf-8") as f:
        text = f.read()
    for old, new in replace + [(SOURCE + "/", "")]:
        text = text.replace(old, new)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


def make_pki(tmp):
    """A CA, a server and client certificates (conformance/tests/security/make_pki.sh)."""
    pki = os.path.join(tmp, "pki")
    subprocess.run(["bash", os.path.join(SOURCE, "conformance/tests/security/make_pki.sh"), pki], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return pki


def run_server(lib, transport, cmd, ctx, args, row, run_dir):
    tmp = tempfile.mkdtemp(prefix="mbconform-matrix-")
    pty, server = None, None
    log = open(os.path.join(run_dir, "server.log"), "w", encoding="utf-8")
    try:
        ctx = dict(ctx, port=free_port(), baud=BAUD)
        if transport == "pty":
            pty = PtyPair(tmp)
            ctx["device"] = pty.server
            target = "rtu://%s?baud=%d&parity=N&unit=1" % (pty.client, BAUD)
        elif transport == "tls":
            # Modbus/TCP Security: a test PKI made for this run (no key is
            # ever committed); mbconform presents the operator certificate, and
            # clients= holds the untrusted, expired, two-role, PrintableString-role
            # and role-less certificates the security checks offer.
            ctx["pki"] = make_pki(tmp)
            target = "mbtls://127.0.0.1:%d?unit=1&cert=%s/operator.crt&key=%s/operator.key&ca=%s/ca.crt&clients=%s" % (
                ctx["port"], ctx["pki"], ctx["pki"], ctx["pki"], ctx["pki"])
        else:
            scheme = "tcp" if transport == "tcp" else "rtu-tcp"
            target = "%s://127.0.0.1:%d?unit=1" % (scheme, ctx["port"])
        server = Server(fill(cmd, ctx), log)
        quirks = os.path.join(SOURCE, "conformance/peers/quirks", lib["server"].get("quirks", "-") + ".yaml")
        mb = [args.mbconform, "run", "--map", "auto", "--device", DEVICE, "--allow-writes", "--allow-disruptive", "--target", target,
              "--out", run_dir, "--quiet"]
        shown = ("rtu://PTY?baud=%d" % BAUD if transport == "pty" else
                 "mbtls://127.0.0.1:PORT?cert=operator.crt&key=operator.key&ca=ca.crt&clients=pki/" if transport == "tls" else
                 "%s://127.0.0.1:PORT" % target.split(":")[0])
        row["command"] = "mbconform run --map auto --device %s --allow-writes --allow-disruptive --target '%s'" % (DEVICE, shown)
        with open(os.path.join(run_dir, "mbconform.log"), "w", encoding="utf-8") as f:
            p = subprocess.Popen(mb, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            running = True
            for line in p.stdout:  # one line per failing case, flushed as it comes, then the summary
                f.write(line)
                running = running and not line.startswith("device ")
                if running and transport == "pty" and "the target was lost after" in line:
                    server.restart()  # so that the restore of what the run wrote finds a server
            row["exit"] = p.wait()
        row["server_restarts"] = server.restarts
        server.stop()
        row["server_died"] = server.died
        summarize(os.path.join(run_dir, "report.json"), row, load_quirks(quirks), lib["field_practice_all"])
        scrub_report(run_dir, [(tmp, "/tmp/matrix"), ("127.0.0.1:%d" % ctx["port"], "127.0.0.1:PORT")])
    finally:
        if server:
            server.stop()
        if pty:
            pty.close()
        log.close()
        shutil.rmtree(tmp, ignore_errors=True)


def run_master(lib, transport, ctx, args, row, run_dir):
    adapter = fill(lib["master"]["adapter"], ctx)
    deviations = os.path.join(SOURCE, "conformance/peers/deviations", lib["master"]["deviations"][transport] + ".yaml")
    mb = [args.mbconform, "client", "--adapter", adapter, "--transport", transport, "--out", run_dir, "--quiet"]
    row["command"] = "mbconform client --adapter '%s' --transport %s" % (
        lib["master"]["adapter"].replace("{build}", "build").replace("{source}/", "").replace(
            "{node}", "NODE_PATH=build/peers/node_modules node"), transport)
    p = subprocess.run(mb, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, check=False)
    with open(os.path.join(run_dir, "mbconform.log"), "w", encoding="utf-8") as f:
        f.write(p.stdout)
    row["exit"] = p.returncode
    summarize(os.path.join(run_dir, "report.json"), row, load_quirks(deviations), lib["field_practice_all"])
    scrub_report(run_dir, [])


def make_rows(libs, args, ctx, out):
    """Every row, in matrix.yaml's order; the runnable ones run args.jobs at a
    time (each has its own pty or port, server, run directory and mbconform)."""
    rows, runs = [], []
    for lib in libs:
        for side in SIDES:
            spec = lib.get(side, {})
            for transport in TRANSPORTS:
                rid = "%s-%s-%s" % (lib["name"].replace("/", "-"), side, transport)
                row = {"id": rid, "library": lib["name"], "version": lib["version_found"], "side": side, "transport": transport}
                rows.append(row)
                unsupported = spec.get("unsupported", {}).get(transport)
                runnable = spec.get(transport) if side == "server" else transport in spec.get("deviations", {})
                if unsupported or not runnable:
                    row["status"] = "unsupported"
                    row["reason"] = unsupported or (
                        "not run over TLS: the library has no Modbus/TCP Security transport of its own, or none "
                        "this matrix wires up (conformance/peers/matrix.yaml)" if transport == "tls" else
                        "not in conformance/peers/matrix.yaml")
                    continue
                runs.append((lib, side, spec, transport, row))
    printing = threading.Lock()

    def run_row(lib, side, spec, transport, row):
        rid = row["id"]
        run_dir = os.path.join(out, "runs", rid)
        shutil.rmtree(run_dir, ignore_errors=True)
        os.makedirs(run_dir)
        t0 = time.monotonic()
        try:
            if side == "server":
                run_server(lib, transport, spec[transport], ctx, args, row, run_dir)
            else:
                run_master(lib, transport, ctx, args, row, run_dir)
            row["status"] = "run"
        except (RuntimeError, OSError, ValueError, KeyError) as e:
            row["status"] = "not-run"
            row["reason"] = str(e)
        row["seconds"] = round(time.monotonic() - t0, 1)
        # The page links report.html and the verdicts are in matrix.json; the
        # rest stays only where --check writes (the build tree), for a look.
        for name in ("report.json", "junit.xml") + (() if args.check else ("mbconform.log", "server.log", "adapter.log")):
            if os.path.exists(os.path.join(run_dir, name)):
                os.remove(os.path.join(run_dir, name))
        row["report"] = "runs/%s/report.html" % rid
        counts = totals(row)
        with printing:
            print("matrix: %s %s, %.0f s: %d pass, %d fail, %d observed" % (rid, row["status"], row["seconds"], counts["pass"],
                                                                           counts["fail"], counts["observed"]), flush=True)

    # The longest rows first would finish soonest, but the order a reader sees
    # is matrix.yaml's: rows keeps it, whatever order they end in.
    pending = list(runs)
    errors = []

    def worker():
        while True:
            with printing:
                if not pending:
                    return
                job = pending.pop(0)
            try:
                run_row(*job)
            except BaseException as e:  # noqa: BLE001 -- told once the others are done
                errors.append(e)

    threads = [threading.Thread(target=worker) for _ in range(max(1, args.jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return rows


def totals(row):
    t = {k: 0 for k in OUTCOMES}
    for cell in row.get("cells", {}).values():
        for k in OUTCOMES:
            t[k] += cell.get(k, 0)
    return t


# ---- the verdicts, and comparing them ----

def verdicts(matrix):
    """What --check compares: per row its status, counts per family and its
    failing cases; nothing timed, no messages."""
    out = {}
    for r in matrix["rows"]:
        out[r["id"]] = {"status": r["status"], "version": r.get("version"), "cells": r.get("cells", {}),
                        "failures": sorted(f["case"] + " " + f["outcome"] for f in r.get("failures", [])),
                        "server_died": r.get("server_died")}
    return out


def compare(committed, fresh):
    problems = []
    a, b = verdicts(committed), verdicts(fresh)
    for rid in sorted(set(a) | set(b)):
        if rid not in b:
            problems.append("%s: in the committed matrix, not made now" % rid)
        elif rid not in a:
            problems.append("%s: made now, not in the committed matrix" % rid)
        else:
            for key in ("status", "version", "server_died"):
                if a[rid][key] != b[rid][key]:
                    problems.append("%s: %s %s, now %s" % (rid, key, a[rid][key], b[rid][key]))
            for f in sorted(set(a[rid]["failures"]) ^ set(b[rid]["failures"])):
                problems.append("%s: %s %s" % (rid, "no longer fails:" if f in a[rid]["failures"] else "now fails:", f))
            for fam in sorted(set(a[rid]["cells"]) | set(b[rid]["cells"])):
                ca, cb = a[rid]["cells"].get(fam), b[rid]["cells"].get(fam)
                if ca != cb:
                    problems.append("%s: family %s: %s, now %s" % (rid, fam, ca, cb))
    return problems


# ---- the page ----

CSS = """
body{font-family:system-ui,sans-serif;margin:2em;color:#222;max-width:1400px}
table{border-collapse:collapse;margin:1em 0}
th,td{border:1px solid #ccc;padding:4px 8px;text-align:left;vertical-align:top;font-size:14px}
th{background:#f0f0f0}
td.cell{text-align:center;white-space:nowrap}
.ok{background:#c8efc8}.bad{background:#f6c2c2}.obs{background:#fff3bf}.na{background:#e4e4e4;color:#666}
.num{font-variant-numeric:tabular-nums}
td.cell a{color:inherit;text-decoration:none;display:block}
code{font-size:13px}
small{color:#555}
"""


def cell_html(cell, href):
    """One family's counts, coloured, linking that run's report."""
    if not cell:
        return '<td class="cell na">&ndash;</td>'
    cls = "bad" if cell.get("fail") or cell.get("error") else ("ok" if cell.get("pass") else "obs")
    parts = ["%d&#10003;" % cell.get("pass", 0), "%d&#10007;" % cell.get("fail", 0), "%d obs" % cell.get("observed", 0)]
    if cell.get("unsupported"):
        parts.append("%d unsup" % cell["unsupported"])
    if cell.get("error"):
        parts.append("%d not run" % cell["error"])
    return '<td class="cell num %s"><a href="%s">%s</a></td>' % (cls, html.escape(href), " ".join(parts))


def side_table(matrix, side):
    rows = [r for r in matrix["rows"] if r["side"] == side]
    fams = matrix["families"][side]
    h = ['<table><tr><th>library</th><th>version</th><th>transport</th>'
         + "".join("<th>%s</th>" % html.escape(f) for f in fams) + "<th>total</th><th>report</th></tr>"]
    for r in rows:
        h.append("<tr><td>%s</td><td>%s</td><td>%s</td>" % (html.escape(r["library"]), html.escape(r.get("version", "")),
                                                            html.escape(r["transport"])))
        if r["status"] != "run":
            h.append('<td class="cell na" colspan="%d">%s: %s</td><td></td></tr>' % (
                len(fams) + 1, "unsupported" if r["status"] == "unsupported" else "not run", html.escape(r.get("reason", ""))))
            continue
        h.extend(cell_html(r["cells"].get(f), r["report"]) for f in fams)
        h.append(cell_html(totals(r), r["report"]))
        extra = ""
        if r.get("server_died") is not None:
            extra = "<br><small>the server died (exit %s)</small>" % r["server_died"]
        if r.get("server_restarts"):
            extra += "<br><small>the server wedged; restarted after the run lost it</small>"
        if r.get("incomplete"):
            extra += "<br><small>incomplete run</small>"
        h.append('<td><a href="%s">report</a> <small>exit %s</small>%s</td></tr>' % (html.escape(r["report"]), r["exit"], extra))
    h.append("</table>")
    return "\n".join(h)


def deviations_html(matrix):
    h = []
    for lib in matrix["libraries"]:
        rows = [r for r in matrix["rows"] if r["library"] == lib["name"] and r.get("failures")]
        h.append("<h3>%s %s</h3>" % (html.escape(lib["name"]), html.escape(lib["version"])))
        h.append("<p><small>Declared: as a server, %s; as a master, %s.</small></p>" % (
            "<code>conformance/peers/quirks/%s.yaml</code>" % html.escape(lib["server_quirks"]) if lib.get("server_quirks")
            else "no quirks file (nothing in the library's documentation declares these deviations)" if any(
                r["library"] == lib["name"] and r["side"] == "server" and r["status"] == "run" for r in matrix["rows"])
            else "no server",
            ", ".join("<code>conformance/peers/deviations/%s.yaml</code> (%s)" % (html.escape(d), html.escape(t))
                      for t, d in sorted(lib.get("master_deviations", {}).items())) or "no adapter"))
        for r in matrix["rows"]:
            if r["library"] == lib["name"] and totals(r)["error"]:
                h.append("<p>%s / %s: %d cases not run: the run lost the server (%s; its report names the last request).</p>" % (
                    r["side"], r["transport"], totals(r)["error"],
                    "it died" if r.get("server_died") is not None else "it stopped answering"))
        if not rows:
            h.append("<p>No failing case.</p>")
            continue
        h.append("<table><tr><th>side / transport</th><th>case</th><th>level</th><th>clause</th><th>what happened</th>"
                 "<th>declared as a quirk</th><th>field practice?</th></tr>")
        for r in rows:
            for f in r["failures"]:
                h.append("<tr><td>%s / %s</td><td><code>%s</code></td><td>%s</td><td>%s</td><td><small>%s</small></td><td>%s</td><td>%s</td></tr>" % (
                    r["side"], r["transport"], html.escape(f["case"]),
                    html.escape(f["level"]), html.escape(f["clause"]), html.escape(f["message"]),
                    "yes: " + html.escape(f["declared"]) if f["declared"] else "no",
                    html.escape(f["field_practice"]) if f["field_practice"] else "no: a bug"))
        h.append("</table>")
    return "\n".join(h)


def write_html(matrix, path):
    libs = "".join("<tr><td>%s</td><td>%s</td><td>%s</td><td>%s</td><td>%s</td><td>%s</td></tr>" % (
        html.escape(l["name"]), html.escape(l["version"]), html.escape(l["language"]), html.escape(l["from"]),
        ", ".join(r["transport"] for r in matrix["rows"] if r["library"] == l["name"] and r["side"] == "server" and r["status"] == "run") or "none",
        ", ".join(r["transport"] for r in matrix["rows"] if r["library"] == l["name"] and r["side"] == "master" and r["status"] == "run") or "none")
        for l in matrix["libraries"])
    page = """<!DOCTYPE html><html><head><meta charset="utf-8"><title>Modbus conformance matrix</title><style>%s</style></head><body>
<h1>Modbus conformance matrix</h1>
<p>Real Modbus libraries, both directions, judged by mbconform against the Modbus standard (MBAP v1.1b3,
MB-SL v1.02, the TCP Implementation Guide). As a server: <code>mbconform run --map auto --device %s --allow-writes --allow-disruptive</code>
against the library's server (200 coils, discrete inputs, input and holding registers); as a master:
<code>mbconform client</code> with the library's adapter. Cells: passed &#10003;, failed &#10007;, observed (what the
standard leaves to the implementation); &ldquo;unsup&rdquo;: a function code the library lacks. RTU on a pty runs at
%d baud. Regenerate with <code>conformance/peers/matrix.py</code>.</p>
<table><tr><th>library</th><th>version</th><th>language</th><th>from</th><th>server transports</th><th>master transports</th></tr>%s</table>
<h2>As a server</h2>%s
<h2>As a master</h2>%s
<h2>Known deviations</h2>
<p>Every failing case of every run, with its clause. &ldquo;Declared as a quirk&rdquo;: the library's quirks file
(<code>conformance/peers/quirks/</code> for servers, <code>conformance/peers/deviations/</code> for masters) lists
it, so that library's CI stays green on it. &ldquo;Field practice&rdquo;: a deviation a library author could
reasonably defend (conformance/peers/matrix.yaml says why); the rest are bugs.</p>
%s
</body></html>
""" % (CSS, DEVICE, BAUD, libs, side_table(matrix, "server"), side_table(matrix, "master"), deviations_html(matrix))
    with open(path, "w", encoding="utf-8") as f:
        f.write(page)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(SOURCE, "build"))
    ap.add_argument("--out")
    ap.add_argument("--only", help="library names, comma-separated")
    ap.add_argument("--mbconform")
    ap.add_argument("--check", metavar="MATRIX_JSON")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="rows run side by side (default: the number of CPUs)")
    args = ap.parse_args()
    args.build = os.path.abspath(args.build)
    args.out = os.path.abspath(args.out or (os.path.join(args.build, "matrix") if args.check else os.path.join(SOURCE, "docs/matrix")))
    args.mbconform = args.mbconform or os.path.join(args.build, "bin/mbconform")
    if not os.access(args.mbconform, os.X_OK):
        print("matrix: no mbconform at %s (build it first)" % args.mbconform, file=sys.stderr)
        return 2
    with open(os.path.join(SOURCE, "conformance/peers/matrix.yaml"), encoding="utf-8") as f:
        config = yaml.safe_load(f)
    libs = config["libraries"]
    for lib in libs:
        lib["field_practice_all"] = field_practice(lib, config.get("field_practice_set", {}))
    if args.only:
        names = args.only.split(",")
        libs = [l for l in libs if l["name"] in names]
    node = shutil.which("node") or "node"
    ctx = {"build": args.build, "source": SOURCE, "node": "env NODE_PATH=%s/peers/node_modules %s" % (args.build, node)}
    for lib in libs:
        p = sh(fill(lib["version"], ctx), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        lib["version_found"] = p.stdout.strip() or "unknown"
    os.makedirs(args.out, exist_ok=True)
    t0 = time.monotonic()
    rows = make_rows(libs, args, ctx, args.out)
    libraries = [{"name": l["name"], "version": l["version_found"], "language": l["language"], "from": l["from"],
                  "server_quirks": l.get("server", {}).get("quirks"),
                  "master_deviations": l.get("master", {}).get("deviations", {})} for l in libs]
    seconds = round(time.monotonic() - t0, 1)
    committed_path = os.path.join(args.out, "matrix.json")
    if args.only and not args.check and os.path.exists(committed_path):
        # --only rewrites those libraries' rows in OUT/matrix.json and keeps every
        # other library's, in matrix.yaml's order (the time: the kept rows' and these).
        with open(committed_path, encoding="utf-8") as f:
            kept = json.load(f)
        order = [l["name"] for l in config["libraries"]]
        rank = {n: i for i, n in enumerate(order)}
        rows = sorted([r for r in kept["rows"] if r["library"] not in names] + rows,
                      key=lambda r: rank.get(r["library"], len(order)))
        libraries = sorted([l for l in kept["libraries"] if l["name"] not in names] + libraries,
                           key=lambda l: rank.get(l["name"], len(order)))
        seconds = round(sum(r.get("seconds", 0) for r in rows), 1)
    families = {side: sorted({f for r in rows if r["side"] == side for f in r.get("cells", {})}) for side in SIDES}
    matrix = {"matrix": 1, "device": DEVICE, "pty_baud": BAUD, "libraries": libraries,
              "families": families, "rows": rows, "seconds": seconds}
    with open(os.path.join(args.out, "matrix.json"), "w", encoding="utf-8") as f:
        json.dump(matrix, f, indent=1, sort_keys=True)
        f.write("\n")
    write_html(matrix, os.path.join(args.out, "matrix.html"))
    print("matrix: %d rows in %.0f s: %s" % (len(rows), matrix["seconds"], os.path.join(args.out, "matrix.html")))
    if not args.check:
        return 0
    with open(args.check, encoding="utf-8") as f:
        committed = json.load(f)
    if args.only:  # compare only the libraries made now
        committed["rows"] = [r for r in committed["rows"] if r["library"] in names]
    problems = compare(committed, matrix)
    for p in problems:
        print("STALE " + p)
    if problems:
        print("matrix: %s is stale: regenerate it with conformance/peers/matrix.py (%d differences)" % (args.check, len(problems)))
        return 1
    print("matrix: %s is fresh" % args.check)
    return 0


if __name__ == "__main__":
    sys.exit(main())
