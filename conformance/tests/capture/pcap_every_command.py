#!/usr/bin/python3
"""--pcap on props, fuzz and client (run and serve: tshark_compare.py run-pcap).
Each command is pointed at a served drive (props, fuzz) or runs its scenario
servers (client, with the pymodbus adapter), writes --pcap, and tshark, the
independent decoder, must find Modbus/TCP requests in the file (the tap
writes the server side as port 502).
usage: pcap_every_command.py MBCONFORM ADAPTER_SCRIPT"""
import json
import os
import socket
import subprocess
import sys
import tempfile
import time

MB, ADAPTER = sys.argv[1], sys.argv[2]
failures = []


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def requests_in(pcap):
    """Modbus/TCP requests tshark decodes (to the server port: mbtcp.trans_id with the query flag)."""
    p = subprocess.run(["tshark", "-r", pcap, "-Y", "mbtcp && tcp.dstport == 502", "-T", "fields", "-e", "mbtcp.trans_id"],
                       capture_output=True, text=True, timeout=120)
    return len([l for l in p.stdout.splitlines() if l.strip()])


with tempfile.TemporaryDirectory() as tmp:
    PORT = free_port()
    serve = subprocess.Popen([MB, "serve", "--device", "hsc60@1", "--tcp", "127.0.0.1:%d" % PORT], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(1.0)
        target = "tcp://127.0.0.1:%d?unit=1" % PORT
        for name, extra in (("props", []), ("fuzz", ["--duration", "2s"])):
            pcap, out = os.path.join(tmp, name + ".pcapng"), os.path.join(tmp, name)
            p = subprocess.run([MB, name, "--target", target, "--device", "hsc60", "--pcap", pcap, "--out", out, "-q"] + extra,
                               capture_output=True, text=True, timeout=300)
            if p.returncode not in (0, 1):
                failures.append(f"{name} --pcap: exit {p.returncode}: {p.stderr.strip()[-300:]}")
                continue
            n = requests_in(pcap)
            sent = None
            report = os.path.join(out, "report.json")
            if os.path.exists(report):  # props writes one; fuzz writes findings only
                with open(report) as f:
                    sent = sum(d.get("frames_sent", 0) for d in json.load(f).get("devices", []))
            # The pcap also holds the session's own reads (preflight, journal,
            # restore), which the report's count leaves out; tshark does not
            # count a frame it cannot call Modbus: neither bounds the other.
            ok = n > 0
            print(f"{'ok  ' if ok else 'FAIL'} {name} --pcap: tshark decodes {n} Modbus/TCP requests; the report: {sent} frames sent")
            if not ok:
                failures.append(f"{name} --pcap: tshark decodes {n} Modbus/TCP requests, the report says {sent} frames sent")
    finally:
        serve.terminate()
        serve.wait(timeout=30)
    pcap = os.path.join(tmp, "client.pcapng")
    p = subprocess.run([MB, "client", "--adapter", "/usr/bin/python3 " + ADAPTER, "--transport", "tcp", "--pcap", pcap, "--out",
                        os.path.join(tmp, "client"), "-q"], capture_output=True, text=True, timeout=300)
    if p.returncode not in (0, 1):
        failures.append(f"client --pcap: exit {p.returncode}: {p.stderr.strip()[-300:]}")
    else:
        q = subprocess.run(["tshark", "-r", pcap, "-Y", "mbtcp", "-T", "fields", "-e", "mbtcp.trans_id"], capture_output=True,
                           text=True, timeout=120)
        n = len([l for l in q.stdout.splitlines() if l.strip()])
        print(f"{'ok  ' if n > 0 else 'FAIL'} client --pcap: tshark decodes {n} Modbus/TCP frames")
        if n == 0:
            failures.append("client --pcap: tshark decodes no Modbus/TCP frame")

for f in failures:
    print("FAIL " + f)
sys.exit(1 if failures else 0)
