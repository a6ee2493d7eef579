#!/usr/bin/python3
"""check-capture against tshark, the independent decoder (Debian tshark).

  tshark_compare.py counts MBCONFORM CAPTURE...
      For each capture: check-capture's requests per function code and its
      exception replies per function code equal what tshark's Modbus/TCP
      dissector decodes (`tshark -r FILE -Y mbtcp`).
  tshark_compare.py run-pcap MBCONFORM
      `run --pcap` against `serve` over Modbus TCP and against an in-process
      reference device (RTU): tshark decodes the same requests, per function
      code and as bytes, that the run's report.json lists.

Exit 0 when they agree; 1 with one line per difference.
"""
import collections
import json
import os
import signal
import subprocess
import sys
import tempfile

def tshark_fields(path, display_filter, fields, extra=()):
    cmd = ["tshark", "-n", "-r", path, *extra, "-Y", display_filter, "-T", "fields", "-E", "occurrence=a",
           "-E", "aggregator=,", "-E", "separator=\t"]
    for f in fields:
        cmd += ["-e", f]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return [line.split("\t") for line in out.splitlines()]


def tshark_counts(path):
    """Requests per FC and exception replies per FC, as tshark's dissector sees them."""
    requests, exceptions = collections.Counter(), collections.Counter()
    for dport, sport, fcs, excs in tshark_fields(path, "mbtcp", ["tcp.dstport", "tcp.srcport", "modbus.func_code",
                                                                 "modbus.exception_code"]):
        fcs = [int(x) for x in fcs.split(",") if x]
        excs = [x for x in excs.split(",") if x]
        if dport == "502":
            for fc in fcs:
                requests[fc] += 1
        elif sport == "502" and excs:
            # One exception code per exception reply in the frame; tshark strips the 0x80 bit.
            for fc, _ in zip(fcs, excs):
                exceptions[fc] += 1
    return requests, exceptions


def check_capture(mbconform, path, out):
    rc = subprocess.run([mbconform, "check-capture", path, "--device", "modbus-standard", "--out", out],
                        capture_output=True, text=True)
    if rc.returncode not in (0, 1):
        raise SystemExit(f"{path}: check-capture exit {rc.returncode}: {rc.stderr.strip()}")
    with open(os.path.join(out, "coverage.json")) as f:
        cov = json.load(f)
    with open(os.path.join(out, "report.json")) as f:
        json.load(f)  # well-formed
    req = collections.Counter({int(k): v for k, v in cov["requests_by_function"].items()})
    exc = collections.Counter({int(k): v for k, v in cov["exceptions_by_function"].items()})
    return req, exc, cov


def counts(mbconform, captures):
    bad = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, path in enumerate(captures):
            t_req, t_exc = tshark_counts(path)
            m_req, m_exc, cov = check_capture(mbconform, path, os.path.join(tmp, str(i)))
            name = os.path.basename(path)
            if t_req != m_req:
                bad.append(f"{name}: requests per FC: tshark {dict(sorted(t_req.items()))}, "
                           f"check-capture {dict(sorted(m_req.items()))}")
            if t_exc != m_exc:
                bad.append(f"{name}: exception replies per FC: tshark {dict(sorted(t_exc.items()))}, "
                           f"check-capture {dict(sorted(m_exc.items()))}")
            if not t_req:
                bad.append(f"{name}: tshark decoded no request: nothing was compared")
            print(f"{name}: {sum(m_req.values())} requests in {len(m_req)} function codes, "
                  f"{sum(m_exc.values())} exception replies, {cov['findings_total']} reading findings; tshark agrees"
                  if not bad else f"{name}: differs")
        # A malformed capture: cut inside its last packet. One line on stderr,
        # exit 2, the reports still written, the packets before it counted.
        cut = os.path.join(tmp, "cut.pcap")
        with open(captures[0], "rb") as f:
            data = f.read()
        with open(cut, "wb") as f:
            f.write(data[:len(data) - 7])
        out = os.path.join(tmp, "cut")
        rc = subprocess.run([mbconform, "check-capture", cut, "--device", "modbus-standard", "--out", out],
                            capture_output=True, text=True)
        lines = rc.stderr.strip().splitlines()
        if rc.returncode != 2 or len(lines) != 1 or "truncated" not in lines[0]:
            bad.append(f"truncated capture: exit {rc.returncode}, stderr {rc.stderr!r}: expected exit 2 and one line")
        elif not os.path.exists(os.path.join(out, "report.json")):
            bad.append("truncated capture: no report.json written")
        else:
            print(f"truncated capture: exit 2, {lines[0]!r}")
    return bad


def report_requests(out):
    """Every request the run's report.json lists, as hex, with its function code."""
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    reqs = []
    for d in rep["devices"]:
        for c in d["cases"]:
            for fr in c.get("frames", []):
                if fr.get("request"):
                    reqs.append(fr["request"].replace(" ", "").lower())
    return reqs


def run_pcap(mbconform):
    bad = []
    with tempfile.TemporaryDirectory() as tmp:
        # Modbus TCP: serve the standard device, run a slice of the cases against it.
        # serve writes its side too: --pcap, and --trace (the serial log format) to a file.
        serve_pcap = os.path.join(tmp, "serve.pcapng")
        trace = open(os.path.join(tmp, "serve.log"), "w")
        srv = subprocess.Popen([mbconform, "serve", "--device", "modbus-standard@1", "--tcp", "127.0.0.1:0",
                                "--pcap", serve_pcap, "--trace"],
                               stdout=subprocess.PIPE, stderr=trace, text=True)
        try:
            line = srv.stdout.readline().split()
            port = line[-1].rsplit(":", 1)[-1]
            pcap = os.path.join(tmp, "tcp.pcapng")
            out = os.path.join(tmp, "tcp")
            rc = subprocess.run([mbconform, "run", "--target", f"tcp://127.0.0.1:{port}?unit=1", "--device",
                                 "modbus-standard", "--filter", "*/function-codes/fc03/*", "--pcap", pcap,
                                 "--out", out, "--quiet"], capture_output=True, text=True)
            if rc.returncode not in (0, 1):
                return [f"run --pcap (tcp): exit {rc.returncode}: {rc.stderr.strip()}"]
            listed = report_requests(out)
            rows = tshark_fields(pcap, "mbtcp && tcp.dstport == 502", ["tcp.payload"])
            decoded = [r[0].replace(":", "").lower() for r in rows]
            # The report lists the cases' requests; the pcap also holds the
            # safety snapshot's reads before and after them. Every request
            # the report lists is decoded, byte for byte but the transaction id.
            strip = lambda h: h[4:]
            pool = collections.Counter(strip(h) for h in decoded)
            missing = collections.Counter(strip(h) for h in listed) - pool
            if missing:
                bad.append(f"run --pcap (tcp): {sum(missing.values())} requests the report lists are not in what "
                           f"tshark decodes, e.g. {next(iter(missing))}")
            if not listed:
                bad.append("run --pcap (tcp): the report lists no request")
            print(f"tcp: the report lists {len(listed)} requests; tshark decodes {len(decoded)} Modbus/TCP requests")
        finally:
            srv.send_signal(signal.SIGTERM)
            srv.wait(timeout=10)
            trace.close()
        # serve's own pcap: tshark decodes the same requests the client's holds.
        served = [r[0].replace(":", "").lower() for r in tshark_fields(serve_pcap, "mbtcp && tcp.dstport == 502", ["tcp.payload"])]
        if collections.Counter(served) != collections.Counter(decoded):
            bad.append(f"serve --pcap: tshark decodes {len(served)} requests, the client side's pcap {len(decoded)}")
        # serve --trace read back as a serial log: the same requests per function code.
        req_log, _, cov_log = check_capture(mbconform, os.path.join(tmp, "serve.log"), os.path.join(tmp, "log"))
        req_pcap, _, _ = check_capture(mbconform, serve_pcap, os.path.join(tmp, "spcap"))
        t_req, _ = tshark_counts(serve_pcap)
        if not (req_log == req_pcap == t_req) or not req_log:
            bad.append(f"serve --trace / --pcap: requests per FC: log {dict(req_log)}, pcap {dict(req_pcap)}, tshark {dict(t_req)}")
        if cov_log["findings_total"]:
            bad.append(f"serve --trace: {cov_log['findings_total']} lines check-capture could not read, e.g. {cov_log['findings'][0]}")
        print(f"serve: --pcap holds {len(served)} requests as tshark decodes them; --trace read back: "
              f"{sum(req_log.values())} requests, the same per function code")

        # RTU: the in-process reference device, LINKTYPE_USER0 with a direction byte.
        pcap = os.path.join(tmp, "rtu.pcapng")
        out = os.path.join(tmp, "rtu")
        rc = subprocess.run([mbconform, "run", "--target", "ref:modbus-standard", "--filter", "*/function-codes/*",
                             "--pcap", pcap, "--out", out, "--quiet"], capture_output=True, text=True)
        if rc.returncode not in (0, 1):
            return bad + [f"run --pcap (rtu): exit {rc.returncode}: {rc.stderr.strip()}"]
        listed = report_requests(out)
        uat = 'uat:user_dlts:"User 0 (DLT=147)","mbrtu","1","","0",""'
        def requests_in(display_filter):
            js = subprocess.run(["tshark", "-n", "-r", pcap, "-o", uat, "-Y", display_filter, "-T", "json", "-x"],
                                check=True, capture_output=True, text=True).stdout
            # Without the direction byte.
            return [p["_source"]["layers"]["frame_raw"][0][2:] for p in json.loads(js)]
        decoded = requests_in("mbrtu && frame[0] == 0")
        written = requests_in("frame[0] == 0")
        # tshark 4.0's Modbus RTU dissector leaves frames under 5 bytes as
        # data: the 4-byte requests of FC 07, 0B, 0C, 11 (slave, FC, CRC) are
        # checked as written bytes only.
        short = [h for h in listed if len(h) < 10]
        missing = collections.Counter(h for h in listed if len(h) >= 10) - collections.Counter(decoded)
        missing_short = collections.Counter(short) - collections.Counter(written)
        if not decoded:
            bad.append("run --pcap (rtu): tshark decodes no Modbus RTU request")
        if not listed:
            bad.append("run --pcap (rtu): the report lists no request")
        if missing:
            bad.append(f"run --pcap (rtu): {sum(missing.values())} requests the report lists are not decoded by tshark, "
                       f"e.g. {next(iter(missing))}")
        if missing_short:
            bad.append(f"run --pcap (rtu): {sum(missing_short.values())} short requests the report lists are not in "
                       f"the pcap, e.g. {next(iter(missing_short))}")
        print(f"rtu: the report lists {len(listed)} requests; tshark decodes {len(decoded)} Modbus RTU requests, "
              f"every listed one of 5 bytes or more among them; {len(short)} 4-byte requests found as written")
    return bad


def main():
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    mode, mbconform = sys.argv[1], sys.argv[2]
    bad = counts(mbconform, sys.argv[3:]) if mode == "counts" else run_pcap(mbconform)
    for b in bad:
        print(b)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
