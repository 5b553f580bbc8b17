"""A keyless HELLO flood at a rig, from a process of its own (issue 33 item 2): what anyone on the lab network can
send without the key. ``Flood(url, rate_per_s, sockets)`` starts it; ``stop()`` ends it and gives the datagrams sent.

Run alone: python tests/backend/hello_flood.py udp://127.0.0.1:PORT RATE_PER_S [SOCKETS] [--protocol 1]
Each datagram is a HELLO of the right size and version, tagged with a random key (version 1: a valid version 1
HELLO, which has no tag), sent round robin from ``SOCKETS`` sockets of this process; the rate is kept on average
(a late wake-up sends what was due, at most 50 ms of it at once).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CATCH_UP_S = 0.05


def flood(url: str, rate_per_s: float, sockets: int = 1, protocol: int = 2) -> None:
    """Send until SIGTERM; print the count sent on stdout at the end."""
    sys.path.insert(0, str(ROOT))
    from backend.drivers.udp import parse_udp_url
    from sim.emulator import auth
    from sim.emulator import protocol as proto

    addr = parse_udp_url(url)
    codec = proto.Codec(protocol)
    hello = (codec.encode(proto.HELLO, 0, 0, 0) if protocol == 1 else
             codec.encode(proto.HELLO, 0, 0, 0, auth.new_nonce(), key=os.urandom(32)))
    socks = []
    for _ in range(sockets):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        socks.append(sock)
    stopped = []
    signal.signal(signal.SIGTERM, lambda *_: stopped.append(True))
    print("flooding", flush=True)
    sent, t0 = 0, time.perf_counter()
    while not stopped:
        due = int((time.perf_counter() - t0) * rate_per_s)
        sent = max(sent, due - int(CATCH_UP_S * rate_per_s))
        while sent < due:
            try:
                socks[sent % sockets].sendto(hello, addr)
            except OSError:
                pass  # a full send buffer, a port unreachable: a flood does not care
            sent += 1
        time.sleep(0.0005)
    print(sent, flush=True)


class Flood:
    """``flood`` in its own process."""

    def __init__(self, url: str, rate_per_s: float, sockets: int = 1, protocol: int = 2):
        self.rate_per_s, self.sockets = rate_per_s, sockets
        self.proc = subprocess.Popen([sys.executable, __file__, url, str(rate_per_s), str(sockets),
                                      "--protocol", str(protocol)], stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline().strip() == "flooding"
        self.t0 = time.perf_counter()

    def stop(self) -> tuple[int, float]:
        """(datagrams sent, seconds flooded)."""
        self.proc.terminate()
        out = self.proc.communicate(timeout=10)[0]
        return int(out.split()[-1]), time.perf_counter() - self.t0


if __name__ == "__main__":
    args = sys.argv[1:]
    version = 2
    if "--protocol" in args:
        i = args.index("--protocol")
        version = int(args[i + 1])
        del args[i:i + 2]
    flood(args[0], float(args[1]), int(args[2]) if len(args) > 2 else 1, version)
