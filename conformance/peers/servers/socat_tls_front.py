#!/usr/bin/python3
"""Modbus/TCP Security as an integrator builds it from parts nobody here wrote:
socat's OPENSSL-LISTEN (OpenSSL) terminating TLS with mutual authentication
(verify=1, the client's certificate checked against CA) in front of a plain
Modbus TCP server, `mbconform serve --device modbus-standard@1 --tcp`. The
matrix's tls row for socat: what the TLS front does is socat's and OpenSSL's,
what is answered inside it is the reference device's.

usage: socat_tls_front.py MBCONFORM CERT KEY CA PORT
prints "listening tls 127.0.0.1:PORT" when socat listens; runs until SIGTERM
(it and what it started are one process group: the matrix ends the group).
"""
import signal
import subprocess
import sys


def main():
    if len(sys.argv) != 6:
        print(__doc__, file=sys.stderr)
        return 2
    mbconform, cert, key, ca, port = sys.argv[1:]
    serve = subprocess.Popen([mbconform, "serve", "--device", "modbus-standard@1", "--tcp", "127.0.0.1:0"],
                             stdout=subprocess.PIPE, text=True)
    inner = None
    for line in serve.stdout:
        if line.startswith("listening tcp "):
            inner = line.strip().rsplit(":", 1)[1]
            break
    if inner is None:
        print("socat_tls_front: serve did not start", file=sys.stderr)
        return 2
    listen = "OPENSSL-LISTEN:%s,bind=127.0.0.1,reuseaddr,fork,cert=%s,key=%s,cafile=%s,verify=1" % (port, cert, key, ca)
    # -d -d: socat says "listening on" (stderr) once its socket is bound.
    socat = subprocess.Popen(["socat", "-d", "-d", listen, "TCP:127.0.0.1:" + inner], stderr=subprocess.PIPE, text=True)
    for line in socat.stderr:
        sys.stderr.write(line)
        if "listening on" in line:
            print("listening tls 127.0.0.1:%s" % port, flush=True)
            break
    else:
        print("socat_tls_front: socat did not listen", file=sys.stderr)
        serve.terminate()
        return 2
    signal.signal(signal.SIGTERM, lambda *_: (socat.terminate(), serve.terminate(), sys.exit(0)))
    for line in socat.stderr:  # socat's log goes on to the server log
        sys.stderr.write(line)
    return socat.wait()


if __name__ == "__main__":
    sys.exit(main())
