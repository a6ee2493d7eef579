#!/usr/bin/env python3
"""`mbconform serve --tls` under attack (issue 41): each attack beside a good
client that keeps asking, on its own TLS connection, for one holding
register. The figures it must keep: the good client gets at least 99% of its
answers, with a p99 latency under a bound a loaded 2-core machine keeps
(served on loopback, it is a millisecond or two on a quiet one; the issue's
own target is 10 ms); serve does not crash and answers a fresh client after
the attack. The attackers come from 127.0.0.2, the good clients from
127.0.0.1 (as they would from two hosts).

  tls_door_test.py MBCONFORM PKI_DIR WORK_DIR ATTACK

ATTACK:
  fin           40 clients end with a FIN and no close_notify, while other
                clients hold connections open: none of those is dropped
  half-open     2,200 TCP connections that never start a handshake (at a
                file limit of 4096: poll() once failed with EINVAL and the
                relay died); handshakes time out and are capped
  half-open-1024  1,100 of them at a file limit of 1024
  idle-1024     600 idle TLS connections at a file limit of 1024 (once: 99%
                CPU, and 5 of 21 new clients served): serve's CPU while they
                sit is bounded, and 21 new clients are all served
"""
import os
import resource
import signal
import socket
import ssl
import struct
import subprocess
import sys
import multiprocessing
import time

MB, PKI, WORK, ATTACK = sys.argv[1:5]
failures = []
FORK = multiprocessing.get_context("fork")
# Bounds for a loaded shared machine (the target is p99 <= 10 ms).
P99_BOUND_S = 0.25
SHARE_BOUND = 0.99


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what, flush=True)
    if not cond:
        failures.append(what)


def pki(name):
    return os.path.join(PKI, name)


def raise_own_limit(n):
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(max(soft, n), hard), hard))


class Serve:
    def __init__(self, nofile):
        argv = [MB, "serve", "--device", "modbus-standard", "--tls", "127.0.0.1:0", "--cert", pki("server.crt"),
                "--key", pki("server.key"), "--ca", pki("ca.crt")]

        def limit():
            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

        self.p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=limit)
        line = self.p.stdout.readline()
        if not line.startswith("listening tls"):
            self.p.kill()
            sys.exit(f"serve did not start: {line} {self.p.stderr.read()}")
        self.port = int(line.strip().rsplit(":", 1)[1])

    def cpu_seconds(self):
        with open(f"/proc/{self.p.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self):
        alive = self.p.poll() is None
        if alive:
            self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(20)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()
        return alive


def context():
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=pki("ca.crt"))
    ctx.load_cert_chain(pki("operator.crt"), pki("operator.key"))
    return ctx


CTX = context()


def tls_client(port, source="127.0.0.1", timeout=10):
    raw = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    raw.settimeout(timeout)
    raw.bind((source, 0))
    raw.connect(("127.0.0.1", port))
    raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return CTX.wrap_socket(raw, server_hostname="127.0.0.1")


def recv_exact(s, n):
    b = b""
    while len(b) < n:
        chunk = s.recv(n - len(b))
        if not chunk:
            raise ConnectionError("closed")
        b += chunk
    return b


def ask(s, tid):
    """FC 03, one register at 0; True when the right answer came."""
    s.sendall(struct.pack(">HHHB", tid, 0, 6, 1) + bytes([3, 0, 0, 0, 1]))
    head = recv_exact(s, 7)
    t, _, length, _ = struct.unpack(">HHHB", head)
    body = recv_exact(s, length - 1)
    return t == tid and body[:1] == b"\x03"


class GoodClient:
    """Asks on one connection until stopped; reconnects when dropped (counted).
    It runs in a process of its own: a thread beside the attackers waited for
    Python's interpreter lock while they ran, which its latencies counted as
    serve's (a p50 of 3.4 ms instead of 0.3 while 600 connections opened)."""

    def __init__(self, port):
        self.port, self.asked, self.answered, self.lat, self.drops = port, 0, 0, [], 0
        self.stop_flag, self.ready = FORK.Event(), FORK.Event()
        self.results, sender = FORK.Pipe(duplex=False)
        self.proc = FORK.Process(target=self.run, args=(sender,), daemon=True)

    def start(self):
        self.proc.start()
        check(self.ready.wait(30), "the good client connected")

    def run(self, sender):
        asked = answered = drops = tid = 0
        lat = []
        s = tls_client(self.port, timeout=2)
        self.ready.set()
        while not self.stop_flag.is_set():
            tid = (tid + 1) & 0xFFFF
            asked += 1
            t0 = time.perf_counter()
            try:
                if ask(s, tid):
                    answered += 1
                    lat.append(time.perf_counter() - t0)
            except (OSError, ConnectionError):
                drops += 1
                try:
                    s.close()
                    s = tls_client(self.port, timeout=2)
                except OSError:
                    time.sleep(0.05)
            time.sleep(0.002)
        s.close()
        sender.send((asked, answered, lat, drops))

    def finish(self, what):
        self.stop_flag.set()
        if self.results.poll(30):
            self.asked, self.answered, self.lat, self.drops = self.results.recv()
        self.proc.join(10)
        share = self.answered / max(1, self.asked)
        lat = sorted(self.lat)
        p99 = lat[min(len(lat) - 1, int(0.99 * len(lat)))] if lat else 99
        print(f"     {what}: good client {self.answered}/{self.asked} answered ({share:.2%}), "
              f"p50 {lat[len(lat) // 2] * 1e3 if lat else 0:.2f} ms, p99 {p99 * 1e3:.2f} ms, {self.drops} drops", flush=True)
        check(self.asked >= 100, f"{what}: the good client asked at least 100 times ({self.asked})")
        check(share >= SHARE_BOUND, f"{what}: the good client got >= {SHARE_BOUND:.0%} of its answers ({share:.2%})")
        check(p99 <= P99_BOUND_S, f"{what}: the good client's p99 {p99 * 1e3:.1f} ms <= {P99_BOUND_S * 1e3:.0f} ms")


def fresh_client_served(port, what):
    try:
        s = tls_client(port, timeout=5)
        ok = ask(s, 7)
        s.close()
    except (OSError, ConnectionError) as e:
        ok = False
        print(f"     {e}")
    check(ok, f"{what}: a fresh client is served after the attack")


def half_open(port, n):
    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.bind(("127.0.0.2", 0))
        s.setblocking(False)
        try:
            s.connect(("127.0.0.1", port))
        except BlockingIOError:
            pass
        socks.append(s)
    return socks


def attack_fin():
    srv = Serve(4096)
    holders = [tls_client(srv.port) for _ in range(5)]
    for i, h in enumerate(holders):
        ask(h, i)
    good = GoodClient(srv.port)
    good.start()
    for i in range(40):
        s = tls_client(srv.port, source="127.0.0.2")
        ask(s, i)
        # A FIN without close_notify (SSLSocket.shutdown sends no alert).
        s.shutdown(socket.SHUT_WR)
        s.close()
        time.sleep(0.02)
    time.sleep(0.5)
    held = 0
    for i, h in enumerate(holders):
        try:
            held += ask(h, 100 + i)
        except (OSError, ConnectionError):
            pass
    check(held == len(holders), f"fin: the connections held open all still answer ({held}/{len(holders)})")
    good.finish("fin")
    check(good.drops == 0, f"fin: the good client's connection was never dropped ({good.drops})")
    fresh_client_served(srv.port, "fin")
    check(srv.stop(), "fin: serve is alive at the end")


def attack_half_open(nofile, n, what):
    raise_own_limit(n + 200)
    srv = Serve(nofile)
    good = GoodClient(srv.port)
    good.start()
    # One peer that connects and never starts its handshake: timed out.
    silent = socket.create_connection(("127.0.0.1", srv.port), timeout=1, source_address=("127.0.0.3", 0))
    started = time.time()
    socks = half_open(srv.port, n)
    time.sleep(3)
    # New clients while the half-open connections sit.
    served = 0
    for i in range(10):
        try:
            s = tls_client(srv.port, timeout=5)
            served += ask(s, i)
            s.close()
        except (OSError, ConnectionError):
            pass
    check(served == 10, f"{what}: new clients during the attack are served ({served}/10)")
    time.sleep(max(0.0, started + 7 - time.time()))
    try:
        silent.settimeout(3)
        closed = silent.recv(1) == b""
    except ConnectionResetError:
        closed = True
    except OSError:
        closed = False
    check(closed, f"{what}: a handshake that never starts is closed after its time limit (5 s)")
    silent.close()
    good.finish(what)
    for s in socks:
        s.close()
    fresh_client_served(srv.port, what)
    check(srv.stop(), f"{what}: serve is alive at the end")


def attack_idle_1024():
    raise_own_limit(1000)
    srv = Serve(1024)
    good = GoodClient(srv.port)
    good.start()
    idle = []
    opening_ends = time.time() + 60  # (a door that stalls does not stall the test)
    for _ in range(600):
        if time.time() > opening_ends:
            break
        try:
            idle.append(tls_client(srv.port, source="127.0.0.2", timeout=5))
        except (OSError, ConnectionError):
            pass
    print(f"     {len(idle)} idle TLS connections opened", flush=True)
    time.sleep(0.5)
    cpu0, t0 = srv.cpu_seconds(), time.time()
    time.sleep(3)
    cpu = (srv.cpu_seconds() - cpu0) / (time.time() - t0)
    # The good client's 2 ms loop costs serve a few percent; a spin costs 100%.
    check(cpu < 0.5, f"idle-1024: serve does not spin while they sit ({cpu:.0%} of a core)")
    served = 0
    for i in range(21):
        try:
            s = tls_client(srv.port, timeout=5)
            served += ask(s, i)
            s.close()
        except (OSError, ConnectionError):
            pass
    check(served == 21, f"idle-1024: 21 new clients are served ({served}/21)")
    good.finish("idle-1024")
    for s in idle:
        s.close()
    fresh_client_served(srv.port, "idle-1024")
    check(srv.stop(), "idle-1024: serve is alive at the end")


os.makedirs(WORK, exist_ok=True)
{"fin": attack_fin,
 "half-open": lambda: attack_half_open(4096, 2200, "half-open"),
 "half-open-1024": lambda: attack_half_open(1024, 1100, "half-open-1024"),
 "idle-1024": attack_idle_1024}[ATTACK]()
if failures:
    print(f"{len(failures)} failed", flush=True)
    sys.exit(1)
print("all passed")
