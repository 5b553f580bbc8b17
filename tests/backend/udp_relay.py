"""A UDP relay between a host and a rig, for the link-attack tests: a man in the middle that sniffs and sends.

    python udp_relay.py RIG_PORT TAP_PORT

The host talks to the relay's front port as if it were the rig; the relay forwards to the rig from its back
port, so the rig sees the relay as the host. What an attacker on the lab network can do, it offers on two
ports of its own:

- tap: every datagram forwarded goes to 127.0.0.1:TAP_PORT too, prefixed with ``b">"`` (host to rig) or
  ``b"<"`` (rig to host) and the host's port (u16, little-endian): sniffing;
- control: a datagram ``b"H" + data`` is sent to the host from the front port (as if from the rig's address),
  ``b"R" + data`` to the rig from the back port (as if from the host's address): spoofing.

It prints ``FRONT CONTROL`` (ports) on its first line, then runs until killed. Standard library and sim/ only.
"""

from __future__ import annotations

import select
import socket
import sys


def main() -> None:
    rig = ("127.0.0.1", int(sys.argv[1]))
    tap = ("127.0.0.1", int(sys.argv[2]))
    front, back, control, out = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(4))
    for sock in (front, back, control):
        sock.bind(("127.0.0.1", 0))
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    try:
        from sim.realtime import raise_priority

        raise_priority(20)  # as the emulator's: a relay the scheduler leaves waiting looks like a slow link
    except ImportError:
        pass
    print(front.getsockname()[1], control.getsockname()[1], flush=True)
    host = None
    while True:
        readable, _, _ = select.select([front, back, control], [], [])
        for sock in readable:
            data, source = sock.recvfrom(4096)
            if sock is front:
                host = source
                back.sendto(data, rig)
                out.sendto(b">" + host[1].to_bytes(2, "little") + data, tap)
            elif sock is back:
                if host is not None:
                    front.sendto(data, host)
                    out.sendto(b"<" + host[1].to_bytes(2, "little") + data, tap)
            elif data[:1] == b"H" and host is not None:
                front.sendto(data[1:], host)
            elif data[:1] == b"R":
                back.sendto(data[1:], rig)


if __name__ == "__main__":
    main()
