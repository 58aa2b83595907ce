#!/usr/bin/env python3
"""Helpers for scripts/soak.sh (issue 51), Python's standard library only.

  soak-client.py hold PORT      hold the web page's controls in Auto: a WebSocket client
                                 that sends {"type":"mode","mode":"auto"}, then a heartbeat
                                 every 200 ms, reads (and answers pings) all the while, and
                                 runs until killed or the daemon closes the socket
  soak-client.py gaps LOG [OUT]  the gaps between consecutive drive commands in the log
                                 motor backend's JSON lines (`{"t":..., "left":...}`): count,
                                 median, p99 and largest for the first and the last tenth,
                                 and every tenth into OUT (CSV) when given
"""

import base64
import json
import os
import socket
import struct
import sys
import threading
import time


def send_text(sock, text):
    """One masked text frame (a client must mask)."""
    data = text.encode()
    mask = os.urandom(4)
    head = bytes([0x81])
    n = len(data)
    if n < 126:
        head += bytes([0x80 | n])
    elif n < 65536:
        head += bytes([0x80 | 126]) + struct.pack(">H", n)
    else:
        head += bytes([0x80 | 127]) + struct.pack(">Q", n)
    masked = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
    sock.sendall(head + mask + masked)


def send_pong(sock, payload):
    mask = os.urandom(4)
    masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    sock.sendall(bytes([0x8A, 0x80 | len(payload)]) + mask + masked)


def read_exact(sock, n):
    buf = b""
    while len(buf) < n:
        part = sock.recv(n - len(buf))
        if not part:
            raise ConnectionError("closed")
        buf += part
    return buf


def reader(sock, lock, done):
    """Reads every frame the daemon sends (status, pings) so it never sees a stalled client."""
    try:
        while True:
            b0, b1 = read_exact(sock, 2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", read_exact(sock, 2))[0]
            elif n == 127:
                n = struct.unpack(">Q", read_exact(sock, 8))[0]
            payload = read_exact(sock, n)
            op = b0 & 0x0F
            if op == 0x9:
                with lock:
                    send_pong(sock, payload)
            elif op == 0x8:
                break
    except (ConnectionError, OSError):
        pass
    done.set()


def hold(port):
    sock = socket.create_connection(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        (
            f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    head = b""
    while b"\r\n\r\n" not in head:
        part = sock.recv(1)
        if not part:
            sys.exit("soak-client: the daemon closed the connection during the handshake")
        head += part
    if b" 101 " not in head.split(b"\r\n")[0]:
        sys.exit(f"soak-client: no WebSocket: {head.split(chr(13).encode())[0]!r}")
    lock = threading.Lock()
    done = threading.Event()
    threading.Thread(target=reader, args=(sock, lock, done), daemon=True).start()
    with lock:
        send_text(sock, json.dumps({"type": "mode", "mode": "auto"}))
    while not done.wait(0.2):
        with lock:
            send_text(sock, json.dumps({"type": "heartbeat"}))
    print("soak-client: the daemon closed the socket", file=sys.stderr)


def quantile(sorted_values, q):
    if not sorted_values:
        return float("nan")
    i = min(len(sorted_values) - 1, int(q * len(sorted_values)))
    return sorted_values[i]


def gaps(log, out=None):
    times = []
    with open(log) as f:
        for line in f:
            if '"left"' in line:
                times.append(json.loads(line)["t"])
    if len(times) < 20:
        sys.exit(f"soak-client: {log}: {len(times)} drive commands; too few for tenths")
    gap_ms = [1e3 * (b - a) for a, b in zip(times, times[1:])]
    tenth = len(gap_ms) // 10
    rows = []
    for k in range(10):
        part = sorted(gap_ms[k * tenth : (k + 1) * tenth])
        rows.append((k + 1, len(part), quantile(part, 0.5), quantile(part, 0.99), part[-1]))
    if out:
        with open(out, "w") as f:
            f.write("tenth,gaps,median_ms,p99_ms,max_ms\n")
            for r in rows:
                f.write("%d,%d,%.3f,%.3f,%.3f\n" % r)
    print(f"drive commands: {len(times)}; gaps between them, per tenth of the run:")
    for name, r in (("first", rows[0]), ("last ", rows[-1])):
        print(f"  {name} tenth: {r[1]} gaps, median {r[2]:.2f} ms, p99 {r[3]:.2f} ms, largest {r[4]:.2f} ms")


def main():
    if len(sys.argv) >= 3 and sys.argv[1] == "hold":
        hold(int(sys.argv[2]))
    elif len(sys.argv) >= 3 and sys.argv[1] == "gaps":
        gaps(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else None)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
