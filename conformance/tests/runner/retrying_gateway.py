#!/usr/bin/python3
"""A small Modbus TCP to RTU gateway for tests, written here from the Modbus
Messaging on TCP/IP Implementation Guide v1.0b (TCP IG) and MB-SL v1.02, not
from mbconform's code: it takes MBAP requests on a TCP port and forwards each
as an RTU frame to an RTU-over-TCP device (`mbconform serve --rtu-tcp`),
one request on the line at a time, as a serial master does.

Like a real gateway (mbusd, most PLC gateways) it retries: when the device
does not answer within --try-ms it sends the request again, --retries times,
and then answers exception 0B (Gateway Target Device Failed to Respond, MBAP
v1.1b3 §7); when the line cannot be reached it answers 0A (Gateway Path
Unavailable). A broadcast (unit 0) is forwarded and never answered.

usage: retrying_gateway.py UPSTREAM_PORT [--try-ms N] [--retries N]
prints "listening tcp 127.0.0.1:PORT" when ready; runs until SIGTERM.
"""
import argparse
import signal
import socket
import struct
import sys
import threading
import time


def crc16(data):
    # MB-SL v1.02 §6.2.2: CRC-16, polynomial 0xA001 (reflected), initial 0xFFFF, low byte first.
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


class Line:
    """The RTU side: one connection to the device, one request at a time."""

    def __init__(self, port, try_s, retries):
        self.port, self.try_s, self.retries = port, try_s, retries
        self.lock = threading.Lock()
        self.sock = None

    def _connect(self):
        if self.sock is None:
            self.sock = socket.create_connection(("127.0.0.1", self.port), 2)
        return self.sock

    def _read_frame(self, sock, deadline):
        """An RTU reply: bytes until their CRC checks and the line is quiet
        for 1 ms, or the deadline."""
        buf = b""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return buf if len(buf) >= 4 and crc16(buf[:-2]) == buf[-2:] else None
            sock.settimeout(min(left, 0.001) if len(buf) >= 4 and crc16(buf[:-2]) == buf[-2:] else left)
            try:
                chunk = sock.recv(512)
            except socket.timeout:
                if len(buf) >= 4 and crc16(buf[:-2]) == buf[-2:]:
                    return buf
                continue
            if not chunk:
                raise ConnectionError("the line closed")
            buf += chunk

    def exchange(self, unit, pdu):
        """The reply PDU; None for a broadcast; b"\\x0B" when the device never answered; b"\\x0A" when the line is down."""
        frame = bytes([unit]) + pdu + crc16(bytes([unit]) + pdu)
        with self.lock:
            for attempt in range(1 + self.retries):
                try:
                    sock = self._connect()
                    # Whatever came late belongs to no one now.
                    sock.setblocking(False)
                    try:
                        while sock.recv(512):
                            pass
                    except (BlockingIOError, socket.timeout):
                        pass
                    sock.setblocking(True)
                    sock.sendall(frame)
                    if unit == 0:
                        time.sleep(0.005)  # the turnaround a master leaves after a broadcast
                        return None
                    reply = self._read_frame(sock, time.monotonic() + self.try_s)
                except OSError:
                    if self.sock:
                        self.sock.close()
                    self.sock = None
                    if attempt == self.retries:
                        return b"\x0A"
                    continue
                if reply and reply[0] == unit:
                    return reply[1:-2]
            return b"\x0B"


def serve_client(conn, line):
    with conn:
        buf = b""
        while True:
            try:
                chunk = conn.recv(4096)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while len(buf) >= 7:
                tid, proto, length, unit = struct.unpack(">HHHB", buf[:7])
                # TCP IG v1.0b §3.1.3: a frame is its header's length; a header
                # that is not Modbus (protocol != 0, a length no PDU has) ends the connection.
                if proto != 0 or length < 2 or length > 254:
                    return
                if len(buf) < 6 + length:
                    break
                pdu, buf = buf[7:6 + length], buf[6 + length:]
                reply = line.exchange(unit, pdu)
                if reply is None:
                    continue
                if len(reply) == 1:  # 0A / 0B: an exception to the request's function code
                    reply = bytes([pdu[0] | 0x80]) + reply
                try:
                    conn.sendall(struct.pack(">HHHB", tid, 0, len(reply) + 1, unit) + reply)
                except OSError:
                    return


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("upstream", type=int)
    ap.add_argument("--try-ms", type=int, default=40)
    ap.add_argument("--retries", type=int, default=2)
    a = ap.parse_args()
    line = Line(a.upstream, a.try_ms / 1000.0, a.retries)
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    print(f"listening tcp 127.0.0.1:{srv.getsockname()[1]}", flush=True)
    while True:
        conn, _ = srv.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=serve_client, args=(conn, line), daemon=True).start()


if __name__ == "__main__":
    main()
