#!/usr/bin/python3
"""Modbus/TCP Security (mbaps) end to end, against real parts: `mbconform serve
--tls`, `mbconform run --target mbtls://`, OpenSSL's s_client and s_server,
and pymodbus 3.0's TLS server. The test PKI is made by make_pki.sh in the
build tree first (the ctest fixture tls_pki).

usage: tls_test.py MBCONFORM PKI OUT TEST
  TEST: standard | roles | bad-input | openssl-client | openssl-server | pymodbus-server | pymodbus-client

What each test expects comes from MB-TCP-Security v2.1 (TLS 1.2 or later,
mutual authentication, one role per certificate as a UTF8String, role-based
authorization, the MBAP ADU unchanged inside TLS) and, for pymodbus, from its
source (file:line named beside each expectation); never from mbconform's
own output.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import time

MB, PKI, OUT, TEST = sys.argv[1:5]
# The sentence a server that drops the MBAP header inside TLS fails with.
NO_MBAP = "PDU without the MBAP header that Modbus/TCP Security carries inside TLS"
os.makedirs(OUT, exist_ok=True)
failures = []


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what, flush=True)
    if not cond:
        failures.append(what)


def pki(name):
    return os.path.join(PKI, name)


class Server:
    """A server started for one test; `lines` are its "listening ..." lines."""

    def __init__(self, argv, wait_for, count=1):
        self.p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines = []
        deadline = time.time() + 30
        while len(self.lines) < count and time.time() < deadline:
            line = self.p.stdout.readline()
            if not line:
                break
            if line.startswith(wait_for):
                self.lines.append(line.strip())
        if len(self.lines) < count:
            self.stop()
            sys.exit(f"server did not start: {argv}: {self.p.stderr.read()}")

    def port(self, i=0):
        return int(self.lines[i].rsplit(":", 1)[1].split()[0]) if ":" in self.lines[i] else int(self.lines[i].split()[-1])

    def stop(self):
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(10)
            except subprocess.TimeoutExpired:
                self.p.kill()


def serve_tls(extra=(), tcp=False):
    argv = [MB, "serve", "--device", "modbus-standard", "--tls", "127.0.0.1:0", "--cert", pki("server.crt"),
            "--key", pki("server.key"), "--ca", pki("ca.crt"), *extra]
    if tcp:
        argv += ["--tcp", "127.0.0.1:0"]
    return Server(argv, "listening", 2 if tcp else 1)


def target(port, client="operator", **extra):
    q = {"cert": pki(client + ".crt"), "key": pki(client + ".key"), "ca": pki("ca.crt"), "clients": PKI}
    q.update(extra)
    return f"mbtls://127.0.0.1:{port}?" + "&".join(f"{k}={v}" for k, v in q.items())


def run(uri, out, *extra):
    argv = [MB, "run", "--target", uri, "--device", "modbus-standard", "--out", out, "--quiet", *extra]
    p = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    report = None
    if os.path.exists(os.path.join(out, "report.json")):
        with open(os.path.join(out, "report.json")) as f:
            report = json.load(f)
    return p, report


def cases(report):
    return {c["id"]: c for d in report["devices"] for c in d["cases"]}


def security(report):
    return {i.split("/security/")[1]: c for i, c in cases(report).items() if "/security/" in i}


def word(c):
    return c["message"].split(":", 1)[0] if c["outcome"] != "skip" else "skip"


def test_standard():
    """The standard cases pass over TLS as over TCP (the MBAP ADU is carried
    unchanged, MB-TCP-Security v2.1 §6), and the handshake is the spec's."""
    # --list and --plan name the security checks too (nothing is connected).
    uri = target(802)
    listed = subprocess.run([MB, "run", "--target", uri, "--device", "modbus-standard", "--list"], capture_output=True, text=True)
    sec = [l for l in listed.stdout.splitlines() if "/security/" in l]
    level = {l.split()[0].split("/security/")[1]: l.split()[1] for l in sec}
    # What MB-TCP-Security v2.1 requires of a server is MUST; what it leaves
    # to the server (resumption, close_notify, no role) OBSERVED.
    check(listed.returncode == 0 and len(sec) >= 10 and level.get("tls-1.0-refused") == "MUST"
          and level.get("asks-client-certificate") == "MUST" and level.get("refuses-no-certificate") == "MUST"
          and level.get("mbap-inside-tls") == "MUST" and level.get("session-resumption") == "OBSERVED"
          and level.get("no-role") == "OBSERVED",
          f"run --list names the security checks with their levels (got {level})")
    planned = subprocess.run([MB, "run", "--target", uri, "--device", "modbus-standard", "--plan", "--filter", "security/"],
                             capture_output=True, text=True)
    check(planned.returncode == 0 and "modbus-standard/security/asks-client-certificate" in planned.stdout,
          f"run --plan --filter security/ names them (exit {planned.returncode}: {planned.stderr.strip()[-200:]!r})")
    s = serve_tls(tcp=True)
    try:
        tls_port, tcp_port = s.port(0), s.port(1)
        plain, plain_report = run(f"tcp://127.0.0.1:{tcp_port}?unit=1", os.path.join(OUT, "tcp"))
        secure, report = run(target(tls_port), os.path.join(OUT, "tls"))
    finally:
        s.stop()
    check(plain.returncode in (0, 1) and secure.returncode == plain.returncode,
          f"run over mbtls:// exits as over tcp:// (tcp {plain.returncode}, tls {secure.returncode}: {secure.stderr.strip()})")
    if not report or not plain_report:
        return
    over_tcp = {i: c["outcome"] for i, c in cases(plain_report).items()}
    over_tls = {i: c["outcome"] for i, c in cases(report).items() if "/security/" not in i}
    check(len(over_tls) > 100, f"the standard cases ran over TLS ({len(over_tls)})")
    differ = [i for i in over_tcp if over_tls.get(i) != over_tcp[i]]
    check(not differ, f"every case has the same outcome over TLS as over TCP (differ: {differ[:5]})")
    sec = security(report)
    want = {
        "mbap-inside-tls": "mbap",           # §6 Figure 3: the MBAP ADU inside TLS
        "server-certificate-x509v3": "x509v3",  # §8.1: x.509v3 certificates (make_pki.sh's server.crt is v3)
        "tls-1.0-refused": "refused",        # §10.1: TLS 1.2 or later
        "tls-1.1-refused": "refused",
        "tls-1.2-accepted": "accepted",
        "asks-client-certificate": "requested",  # §8.1: mutual authentication
        "refuses-no-certificate": "refused",
        "refuses-untrusted-certificate": "refused",
        "refuses-expired-certificate": "refused",
        "refuses-v1-certificate": "refused",   # §8.1: x.509v3 certificates (make_pki.sh's client-v1.crt)
        "refuses-two-roles": "refused",      # §8.3: one role per certificate
        "refuses-role-not-utf8string": "refused",  # §8.3: a UTF8String
        "close-notify": "sent",              # TLS closure alerts
    }
    for k, w in want.items():
        check(k in sec and word(sec[k]) == w, f"security/{k}: {w} (got {sec.get(k, {}).get('message')})")
    # Resumption is the server's to offer: recorded either way, never an error.
    check(word(sec.get("session-resumption", {"outcome": "x", "message": "error"})) in ("resumed", "not-resumed"),
          f"security/session-resumption is recorded ({sec.get('session-resumption', {}).get('message')})")
    check(sec.get("role-authorization", {}).get("outcome") == "skip", "security/role-authorization skips without roles=")
    must_failed = [i for i, c in sec.items() if c["level"] == "MUST" and c["outcome"] != "pass"]
    check(not must_failed, f"serve --tls passes every security MUST (not passed: {must_failed})")


def test_roles():
    """`serve --tls --roles`: a request outside the role's authorization is
    refused with exception 01; a certificate without a role, or with a role
    the file does not name, is not let in."""
    s = serve_tls(["--roles", pki("roles.yaml")])
    try:
        port = s.port()
        flt = ["--filter", "*/security/*"]
        res = {}
        for client in ("operator", "viewer"):
            p, report = run(target(port, client, roles=pki("roles.yaml")), os.path.join(OUT, client), *flt)
            check(p.returncode == 0, f"{client}: run exits 0 (got {p.returncode}: {p.stderr.strip()})")
            res[client] = security(report) if report else {}
    finally:
        s.stop()
    for client in ("operator", "viewer"):
        sec = res[client]
        ra = sec.get("role-authorization", {})
        check(word(ra) == "refused" if ra else False, f"{client}: a write outside its role gets exception 01 ({ra.get('message')})")
        nr = sec.get("no-role", {})
        check(word(nr) == "refused" if nr else False, f"{client}: a certificate without a role is not let in ({nr.get('message')})")
    # The operator may write 0-99 (roles.yaml): the write the check chose was outside it.
    check("0600640000" in res["operator"].get("role-authorization", {}).get("message", "").replace(" ", ""),
          "operator: the refused write is FC 06 at 100, the first address outside 0-99")


def one_line_exit_2(argv, what, needle):
    p = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    lines = [l for l in p.stderr.splitlines() if l.strip()]
    check(p.returncode == 2 and len(lines) == 1 and needle in lines[0],
          f"{what}: exit 2 and one line naming '{needle}' (got {p.returncode}: {p.stderr.strip()!r})")


def test_bad_input():
    bad = os.path.join(OUT, "bad")
    os.makedirs(bad, exist_ok=True)
    garbage = os.path.join(bad, "garbage.crt")
    with open(garbage, "w") as f:
        f.write("not a certificate\n")
    open_key = os.path.join(bad, "open.key")
    shutil.copy(pki("server.key"), open_key)
    os.chmod(open_key, 0o644)
    base = [MB, "serve", "--device", "modbus-standard", "--tls", "127.0.0.1:0"]
    one_line_exit_2(base + ["--cert", garbage, "--key", pki("server.key"), "--ca", pki("ca.crt")], "serve: a bad certificate", "not a PEM certificate")
    one_line_exit_2(base + ["--cert", pki("server.crt"), "--key", os.path.join(bad, "missing.key"), "--ca", pki("ca.crt")],
                    "serve: a missing key", "No such file")
    one_line_exit_2(base + ["--cert", pki("server.crt"), "--key", open_key, "--ca", pki("ca.crt")], "serve: a key others can read", "readable by group or others")
    one_line_exit_2(base + ["--cert", pki("server.crt"), "--key", pki("operator.key"), "--ca", pki("ca.crt")], "serve: a key of another certificate", "does not match")
    one_line_exit_2(base + ["--cert", pki("server.crt"), "--key", pki("server.key")], "serve: no --ca", "--ca")
    roles = os.path.join(bad, "roles.yaml")
    with open(roles, "w") as f:
        f.write("mbconform_roles: 1\nroles:\n  viewer:\n    - functions: [3]\n      adresses: [0-9]\n")
    one_line_exit_2(base + ["--cert", pki("server.crt"), "--key", pki("server.key"), "--ca", pki("ca.crt"), "--roles", roles],
                    "serve: a roles file with a typo", "roles.yaml:5:7: error: roles: unknown key 'adresses'")
    run_base = [MB, "run", "--device", "modbus-standard", "--out", os.path.join(OUT, "bad-run"), "--target"]
    uri = f"mbtls://127.0.0.1:1?cert={pki('operator.crt')}&key={open_key}&ca={pki('ca.crt')}"
    one_line_exit_2(run_base + [uri], "run: a client key others can read", "readable by group or others")
    uri = f"mbtls://127.0.0.1:1?cert={garbage}&key={pki('operator.key')}&ca={pki('ca.crt')}"
    one_line_exit_2(run_base + [uri], "run: a bad client certificate", "not a PEM certificate")
    uri = f"mbtls://127.0.0.1:1?cert={pki('operator.crt')}&ca={pki('ca.crt')}"
    one_line_exit_2(run_base + [uri], "run: a certificate without its key", "give both or neither")


def s_server(cert, extra=()):
    argv = ["openssl", "s_server", "-accept", "127.0.0.1:0", "-cert", pki(cert + ".crt"), "-key", pki(cert + ".key"),
            "-CAfile", pki("ca.crt"), "-naccept", "1", *extra]
    p = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    port = None
    deadline = time.time() + 10
    while time.time() < deadline:
        line = p.stdout.readline()
        if line.startswith("ACCEPT"):
            port = int(line.strip().rsplit(":", 1)[1])
            break
    return p, port


def test_openssl_server():
    """`openssl s_server` as the raw TLS peer of the mbtls:// client: it sends
    its certificate when asked; it refuses a server its CA did not sign, one
    that names another host, an expired one, and TLS below 1.2."""
    out = os.path.join(OUT, "client")
    # The client sends its certificate (s_server -Verify: required).
    p, port = s_server("server", ["-Verify", "1"])
    r = subprocess.run([MB, "run", "--target", target(port), "--device", "modbus-standard", "--out", out, "--quiet"],
                       capture_output=True, text=True, timeout=60)
    try:
        log, _ = p.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        p.kill()
        log, _ = p.communicate()
    check("operator client" in log, f"the client sent its certificate (s_server saw: {log.strip()[-300:]!r})")
    check(r.returncode == 2, f"a TLS peer that never answers Modbus: run exits 2 (got {r.returncode})")
    for cert, extra, needle, what in [
        ("server-untrusted", [], "certificate verify failed", "a server certificate no trusted CA signed"),
        ("server-wrong-host", [], "certificate verify failed", "a server certificate for another host"),
        ("server-expired", [], "certificate verify failed", "an expired server certificate"),
        ("server", ["-tls1_1", "-cipher", "DEFAULT:@SECLEVEL=0"], "TLS handshake failed", "a server that speaks only TLS 1.1"),
    ]:
        p, port = s_server(cert, extra)
        one_line_exit_2([MB, "run", "--target", target(port), "--device", "modbus-standard", "--out", out],
                        f"client refuses {what}", needle)
        p.kill()
        p.wait()


class SClient:
    """`openssl s_client` kept open: what it printed so far is `out`."""

    def __init__(self, port, *args):
        argv = ["openssl", "s_client", "-connect", f"127.0.0.1:{port}", "-CAfile", pki("ca.crt"), "-quiet",
                "-no_ign_eof", "-verify_return_error", *args]
        self.p = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.out = b""

    def send(self, data):
        try:
            self.p.stdin.write(data)
            self.p.stdin.flush()
        except BrokenPipeError:
            pass

    def read(self, want, seconds=10):
        """Until `want` bytes came, s_client ended, or `seconds` passed."""
        import select
        deadline = time.time() + seconds
        while len(self.out) < want and time.time() < deadline:
            r, _, _ = select.select([self.p.stdout], [], [], max(0, deadline - time.time()))
            if not r:
                break
            chunk = os.read(self.p.stdout.fileno(), 4096)
            if not chunk:
                break
            self.out += chunk
        return self.out

    def close(self):
        try:
            self.p.stdin.close()
        except BrokenPipeError:
            pass
        try:
            self.p.wait(10)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait()
        return self.p.returncode, self.p.stderr.read()


def test_openssl_client():
    """`openssl s_client` as the raw TLS peer of `serve --tls`."""
    s = serve_tls()
    try:
        port = s.port()
        # MBAP v1.1b3 §6.3 inside TLS: read 1 holding register at 0; the MBAP
        # header comes back with the same transaction id and unit (MB TCP §3.1.3).
        req = bytes.fromhex("12340000000601" + "0300000001")
        c = SClient(port, "-cert", pki("operator.crt"), "-key", pki("operator.key"))
        c.send(req)
        out = c.read(11)
        c.close()
        check(out[:7] == bytes.fromhex("12340000000501") and out[7:9] == b"\x03\x02",
              f"s_client with a certificate: an MBAP reply inside TLS ({out.hex()})")
        c = SClient(port)
        c.send(req)
        out = c.read(11)
        rc, err = c.close()
        check(out == b"", f"s_client without a certificate: no reply ({out.hex()}, {err[-200:]!r})")
        c = SClient(port, "-tls1_1", "-cipher", "DEFAULT:@SECLEVEL=0", "-cert", pki("operator.crt"), "-key", pki("operator.key"))
        c.send(req)
        out = c.read(11)
        rc, err = c.close()
        check(rc != 0 and out == b"", f"s_client -tls1_1: refused (exit {rc}, {err[-200:]!r})")
        # Two requests in one write: both answered, in order (MBAP framing inside TLS).
        c = SClient(port, "-cert", pki("operator.crt"), "-key", pki("operator.key"))
        c.send(req + bytes.fromhex("12350000000601" + "0300010001"))
        out = c.read(22)
        c.close()
        check(len(out) == 22 and out[:2] == b"\x12\x34" and out[11:13] == b"\x12\x35",
              f"two pipelined requests: both answered, in order ({out.hex()})")
    finally:
        s.stop()


def test_pymodbus_server():
    """pymodbus 3.0's TLS server (StartAsyncTlsServer) as its documentation
    shows it, and as a user who supplies the SSLContext and the MBAP framer
    runs it. Expectations from its source (/usr/lib/python3/dist-packages/pymodbus)."""
    glue = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pymodbus_tls_server.py")
    here = os.path.join(OUT, "pymodbus")
    # 1. As shipped: sslctx_provider(reqclicert=True) sets CERT_REQUIRED but
    #    loads no CA (server/async_io.py:66-67), so no client certificate can
    #    be verified: the handshake fails for every client.
    s = Server(["/usr/bin/python3", glue, "--as-shipped", pki("server.crt"), pki("server.key"), pki("ca.crt")], "listening")
    try:
        p, _ = run(target(s.port()), os.path.join(here, "shipped"))
    finally:
        s.stop()
    check(p.returncode == 2 and "TLS handshake failed" in p.stderr,
          f"as shipped: every client refused in the handshake (got {p.returncode}: {p.stderr.strip()!r})")
    # 2. A user SSLContext (CA loaded) with the default ModbusTlsFramer: no
    #    MBAP header inside TLS (framer/tls_framer.py:18-23, pymodbus #2014):
    #    an MBAP request is not understood, nothing answers.
    s = Server(["/usr/bin/python3", glue, "--tls-framer", pki("server.crt"), pki("server.key"), pki("ca.crt")], "listening")
    try:
        p, _ = run(target(s.port()), os.path.join(here, "tls-framer"), "--map", "auto")
    finally:
        s.stop()
    # The server answered, and what it answered breaks the specification:
    # a failing verdict (exit 1), naming the cause.
    check(p.returncode == 1 and NO_MBAP in p.stdout,
          f"ModbusTlsFramer: exit 1, '{NO_MBAP}' (got {p.returncode}: {p.stdout.strip()[-400:]!r} {p.stderr.strip()[-200:]!r})")
    # 3. A user SSLContext and the MBAP framer (ModbusSocketFramer): the
    #    standard cases run; the handshake checks see Python's ssl module.
    s = Server(["/usr/bin/python3", glue, "--mbap", pki("server.crt"), pki("server.key"), pki("ca.crt")], "listening")
    try:
        p, report = run(target(s.port(), roles=pki("roles.yaml")), os.path.join(here, "mbap"), "--map", "auto", "--allow-writes")
    finally:
        s.stop()
    check(report is not None, f"MBAP framer: the run wrote a report ({p.returncode}: {p.stderr.strip()!r})")
    if not report:
        return
    # Inside TLS with the MBAP framer the cases fail as they fail over plain
    # TCP: exactly pymodbus's deviations of conformance/README.md ("pymodbus
    # 3.0"), each explained there by its source line.
    failed = sorted(i.split("/", 1)[1] for i, c in cases(report).items() if c["outcome"] == "fail")
    known = sorted([
                    # pymodbus 3.0 reads no role extension (no RBAC in the package): a
                    # certificate with two roles, or a role that is not a UTF8String, is let in.
                    "security/refuses-two-roles", "security/refuses-role-not-utf8string",
                    # Python's ssl (CERT_REQUIRED) verifies the chain, not the version.
                    "security/refuses-v1-certificate", "examples/MBAP_6.5_Figure_15/write-coil-bad-value",
                    "examples/MBAP_6.11_Figure_21/write-coils-wrong-byte-count",
                    "examples/MBAP_6.12_Figure_22/write-registers-wrong-byte-count",
                    "standard/fc05/value-00FF", "standard/fc05/value-0001", "standard/fc23/byte-count-over",
                    "standard/fc43/individual-unknown-object"])
    check(failed == known, f"MBAP framer: the failing cases are pymodbus's TCP deviations (got {failed})")
    sec = security(report)
    want = {
        "tls-1.0-refused": "refused",        # async_io.py:62 OP_NO_TLSv1 (the user context: minimum_version TLSv1_2)
        "tls-1.1-refused": "refused",
        "asks-client-certificate": "requested",  # the user context: CERT_REQUIRED
        "refuses-no-certificate": "refused",
        "refuses-untrusted-certificate": "refused",
        "refuses-expired-certificate": "refused",
        "refuses-v1-certificate": "accepted",  # CERT_REQUIRED checks the chain, not the X.509 version
        "refuses-two-roles": "accepted",     # pymodbus 3.0 reads no role: no RBAC anywhere in the package
        "refuses-role-not-utf8string": "accepted",
        "no-role": "accepted",
        "role-authorization": "answered",    # FC 06 outside the role written and echoed
    }
    for k, w in want.items():
        check(k in sec and word(sec[k]) == w, f"pymodbus security/{k}: {w} (got {sec.get(k, {}).get('message')})")


def free_port():
    import socket
    with socket.socket() as so:
        so.bind(("127.0.0.1", 0))
        return so.getsockname()[1]


def socat_front(opts, cert="server"):
    """`serve --tcp` with socat's OPENSSL-LISTEN in front: a TLS server
    nobody here wrote. Returns (serve, socat, port)."""
    s = Server([MB, "serve", "--device", "modbus-standard", "--tcp", "127.0.0.1:0"], "listening")
    port = free_port()
    listen = (f"OPENSSL-LISTEN:{port},bind=127.0.0.1,reuseaddr,fork,cert={pki(cert + '.crt')},key={pki(cert + '.key')},"
              + ",".join(opts))
    p = subprocess.Popen(["socat", listen, f"TCP:127.0.0.1:{s.port()}"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    import socket
    deadline = time.time() + 10
    while time.time() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), 1).close()
            break
        except OSError:
            time.sleep(0.1)
    return s, p, port


def socat_run(opts, name):
    s, p, port = socat_front(opts)
    try:
        r, report = run(target(port), os.path.join(OUT, name), "--filter", "security")
    finally:
        p.terminate()
        p.wait(10)
        s.stop()
    return r, security(report) if report else {}


def test_socat_no_client_certificate():
    """socat OPENSSL-LISTEN with verify=0 in front of `serve --tcp`: the
    server never asks for a client certificate, so mutual authentication
    (MB-TCP-Security v2.1 §8.1) is missing: MUST failures, exit 1."""
    r, sec = socat_run(["verify=0"], "socat-verify0")
    check(r.returncode == 1, f"no mutual authentication: exit 1 (got {r.returncode}: {r.stdout.strip()[-300:]!r})")
    for k in ("asks-client-certificate", "refuses-no-certificate"):
        c = sec.get(k, {})
        check(c.get("level") == "MUST" and c.get("outcome") == "fail" and "§8.1" in c.get("clause", ""),
              f"security/{k}: a failed MUST citing §8.1 ({c.get('level')} {c.get('outcome')}: {c.get('message')})")
    check(sec.get("mbap-inside-tls", {}).get("outcome") == "pass", "the MBAP ADU does pass through socat")
    check("FAIL" in r.stdout.strip().splitlines()[-1], f"the last line is the verdict FAIL ({r.stdout.strip().splitlines()[-1:]})")


def test_socat_tls10():
    """socat accepting TLS 1.0 (mutual authentication on): TLS 1.2 or later
    (MB-TCP-Security v2.1 §10.1) is missing: a MUST failure, exit 1. OpenSSL 3
    refuses TLS 1.0 at its default security level, so socat is told SECLEVEL=0."""
    r, sec = socat_run(["verify=1", f"cafile={pki('ca.crt')}", "openssl-min-proto-version=TLS1", "cipher=DEFAULT:@SECLEVEL=0"],
                       "socat-tls10")
    c = sec.get("tls-1.0-refused", {})
    if c.get("message", "").startswith("refused: handshake failed") and "no protocols available" in c.get("message", ""):
        print(f"skip: the local OpenSSL cannot speak TLS 1.0 at all ({c.get('message')})")
        return
    check(r.returncode == 1, f"TLS 1.0 let in: exit 1 (got {r.returncode}: {r.stdout.strip()[-300:]!r})")
    check(c.get("level") == "MUST" and c.get("outcome") == "fail" and "§10.1" in c.get("clause", ""),
          f"security/tls-1.0-refused: a failed MUST citing §10.1 ({c.get('level')} {c.get('outcome')}: {c.get('message')})")
    check(sec.get("asks-client-certificate", {}).get("outcome") == "pass", "socat verify=1 asks for the client's certificate")


def test_pymodbus_client():
    """pymodbus 3.0's ModbusTlsClient through the pymodbus adapter (as its
    documentation shows it, with the MBAP framer): the scenarios inside TLS
    end as they end over plain TCP, and the client-side checks see what its
    source does (/usr/lib/python3/dist-packages/pymodbus/client/tls.py)."""
    adapter = "/usr/bin/python3 " + os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "peers",
                                                  "adapters", "pymodbus", "pymodbus_adapter.py")
    reports = {}
    for transport in ("tcp", "tls"):
        out = os.path.join(OUT, "client-" + transport)
        argv = [MB, "client", "--adapter", adapter, "--transport", transport, "--out", out]
        if transport == "tls":
            argv += ["--pki", PKI]
        p = subprocess.run(argv, capture_output=True, text=True, timeout=600)
        check(p.returncode in (0, 1), f"client --transport {transport}: a verdict (exit {p.returncode}: {p.stderr.strip()[-300:]!r})")
        path = os.path.join(out, "report.json")
        reports[transport] = json.load(open(path)) if os.path.exists(path) else None
    if not reports["tcp"] or not reports["tls"]:
        return
    tcp = cases(reports["tcp"])
    tls = cases(reports["tls"])
    # Inside TLS the sync client loses replies: client/tcp.py:234 makes the
    # SSL socket non-blocking and :250-254 select() on the socket, then
    # recv(). select() does not see bytes OpenSSL has already decrypted
    # (SSLSocket.pending()): pymodbus reads the 8 bytes it asks for first,
    # the rest of the same TLS record waits inside the SSL object, select()
    # times out ("No Response received ... Unable to decode response"); and a
    # record without application data (TLS 1.3's NewSessionTicket, RFC 8446
    # §4.6.1) makes recv() raise ssl.SSLWantReadError ("The operation did not
    # complete (read)"). Every scenario that passes over TCP and not over TLS
    # fails one of these two ways.
    lost = [i for i, c in tcp.items() if c["outcome"] == "pass" and tls.get(i, {}).get("outcome") != "pass"]
    why = [i for i in lost if "The operation did not complete (read)" in tls[i]["message"]
           or "No Response received from the remote unit" in tls[i]["message"]]
    check(lost and why == lost, f"scenarios lost over TLS all lose the reply in pymodbus's recv ({len(why)} of {len(lost)}: "
          f"{[(i, tls[i]['message'][:120]) for i in lost if i not in why][:3]})")
    sec = {i.split("/security/")[1]: c for i, c in cases(reports["tls"]).items() if "/security/" in i}
    want = {
        "sends-certificate": "sent",              # tls.py:40 load_cert_chain(certfile, keyfile)
        "verifies-server-certificate": "accepted",  # tls.py:34 verify_mode = CERT_NONE
        "verifies-server-host": "accepted",       # tls.py:33 check_hostname = False
        "refuses-expired-server": "accepted",     # tls.py:34, CERT_NONE checks no validity either
        "refuses-tls-1.1": "refused",             # tls.py:35 OP_NO_TLSv1_1
    }
    for k, w in want.items():
        check(k in sec and word(sec[k]) == w, f"pymodbus client security/{k}: {w} (got {sec.get(k, {}).get('message')})")

def test_socat_x509v1():
    """socat serving an X.509 version 1 certificate (`openssl x509 -req`
    without extensions; make_pki.sh's server-v1.crt, checked here with
    `openssl x509 -text`): MB-TCP-Security authenticates by x.509v3
    certificates (§8.1), so server-certificate-x509v3 fails as a MUST, exit 1."""
    text = subprocess.run(["openssl", "x509", "-in", pki("server-v1.crt"), "-noout", "-text"], capture_output=True, text=True).stdout
    check("Version: 1 (0x0)" in text, "openssl writes server-v1.crt as an X.509 version 1 certificate")
    s, p, port = socat_front(["verify=1", f"cafile={pki('ca.crt')}"], cert="server-v1")
    try:
        uri = target(port).replace("mbtls://127.0.0.1:", "mbtls://localhost:")
        r, report = run(uri, os.path.join(OUT, "socat-x509v1"), "--filter", "security")
    finally:
        p.terminate()
        p.wait(10)
        s.stop()
    sec = security(report) if report else {}
    c = sec.get("server-certificate-x509v3", {})
    check(r.returncode == 1, f"a v1 server certificate: exit 1 (got {r.returncode}: {r.stdout.strip()[-300:]!r})")
    check(c.get("level") == "MUST" and c.get("outcome") == "fail" and "§8.1" in c.get("clause", "")
          and "X.509v3" in c.get("requirement", "") and "version 1" in c.get("message", ""),
          f"security/server-certificate-x509v3: a failed MUST citing §8.1 ({c})")
    # The same socat with the v3 certificate meets it.
    r3, sec3 = socat_run(["verify=1", f"cafile={pki('ca.crt')}"], "socat-x509v3")
    c3 = sec3.get("server-certificate-x509v3", {})
    check(c3.get("outcome") == "pass" and "version 3" in c3.get("message", ""), f"a v3 server certificate passes ({c3})")
    # The other side: socat verifies a client certificate's chain and not its
    # version, so it lets in make_pki.sh's X.509 version 1 client certificate:
    # refuses-v1-certificate fails as a MUST, and that alone makes the run exit 1.
    text = subprocess.run(["openssl", "x509", "-in", pki("client-v1.crt"), "-noout", "-text"], capture_output=True, text=True).stdout
    check("Version: 1 (0x0)" in text, "openssl writes client-v1.crt as an X.509 version 1 certificate")
    v1 = sec3.get("refuses-v1-certificate", {})
    check(v1.get("level") == "MUST" and v1.get("outcome") == "fail" and "§8.1" in v1.get("clause", "")
          and word(v1) == "accepted", f"security/refuses-v1-certificate: a failed MUST citing §8.1 ({v1})")
    # socat reads no role extension either: the two role checks fail beside it, and nothing else.
    others = sorted(k for k, c in sec3.items() if c["level"] == "MUST" and c["outcome"] != "pass" and k != "refuses-v1-certificate")
    check(r3.returncode == 1 and others == ["refuses-role-not-utf8string", "refuses-two-roles"],
          f"beside the v1 client certificate only socat's role checks fail, exit 1 (exit {r3.returncode}, others {others})")


tests = {
    "standard": test_standard,
    "roles": test_roles,
    "bad-input": test_bad_input,
    "openssl-client": test_openssl_client,
    "openssl-server": test_openssl_server,
    "pymodbus-server": test_pymodbus_server,
    "pymodbus-client": test_pymodbus_client,
    "socat-no-client-certificate": test_socat_no_client_certificate,
    "socat-tls1.0": test_socat_tls10,
    "socat-x509v1": test_socat_x509v1,
}
tests[TEST]()
if failures:
    print(f"{len(failures)} check(s) failed", flush=True)
    sys.exit(1)
print("all checks passed")
