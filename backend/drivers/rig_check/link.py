"""The link of ``isorig check-rig`` to a rig: two UDP sockets with the reference codec (``Link``) and one armed
session's stream of measurements (``Stream``); what a probe sends and reads goes through them."""

from __future__ import annotations

import secrets
import select
import socket
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.measurement import STATUS_ARMED

if TYPE_CHECKING:
    from .check import RigCheck

ARM_RESEND_S = 0.05  # as the host does
SILENT_S = 0.25  # no measurement this long from an armed rig: the stream stopped
RECENT_READS = 32  # a probe's count of dropped datagrams is checked against this check's lateness over as many reads
LATE_S = 0.004  # a measurement read this late (this process was not scheduled): a timed probe is run again


class RigUnreachable(Exception):
    """Nothing (or nothing usable) answers: one sentence, the check cannot run."""


class Disturbed(Exception):
    """A probe interrupted: a measurement without ARMED (``Tripped``) or none at all (``Silent``)."""


class Tripped(Disturbed):
    def __init__(self, rec: Received):
        super().__init__(f"the rig disarmed at sequence {rec.packet.sequence} (status {rec.status:#x})")
        self.rec = rec


class Silent(Disturbed):
    pass


@dataclass
class Received:
    """One measurement from the rig: the packet, its size, where it came from, when it arrived."""

    packet: proto.Packet
    size: int
    source: tuple
    t: float
    late_s: float = 0.0  # how much later than the best seen this one arrived, by the rig's clock (time_ns)

    @property
    def seq(self) -> int:
        return self.packet.sequence

    @property
    def status(self) -> int:
        return int(self.packet.fields["status"])

    def __getitem__(self, name: str):
        return self.packet.fields[name]


def new_session() -> int:
    return secrets.randbits(32) or 1


class Link:
    """Two unconnected UDP sockets towards the rig (the stream's and one for HELLO), so that a reply from an
    address or port other than the one sent to is seen, not dropped by the operating system."""

    def __init__(self, host: str, port: int, security: auth.LinkSecurity):
        self.security, self.codec = security, proto.Codec(security.protocol_version)
        self.session_keys: dict[int, bytes] = {}  # version 2: the key of each session this check armed
        self.current_key: bytes | None = None  # ... and of the running one
        self.challenge: bytes | None = None  # the rig's, from the latest ANSWER (None: spent by an accepted ARM)
        try:
            self.addr = (socket.gethostbyname(host), port)
        except OSError as exc:
            raise RigUnreachable(f"cannot resolve the rig's host {host!r}: {exc.strerror or exc}") from None
        self.sock, self.aux = self._socket(), self._socket()
        self.received = 0
        self.invalid: dict[str, int] = {}
        self.wrong_sources: set = set()

    @staticmethod
    def _socket() -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        sock.bind(("", 0))
        sock.setblocking(False)
        return sock

    def send(self, data: bytes, aux: bool = False) -> None:
        try:
            (self.aux if aux else self.sock).sendto(data, self.addr)
        except OSError:
            pass  # the rig's silence decides

    def receive(self, deadline: float, aux: bool = False) -> Received | None:
        """The next measurement on the stream's (or the HELLO) socket, or None at the deadline."""
        sock = self.aux if aux else self.sock
        while True:
            readable, _, _ = select.select([sock], [], [], max(0.0, deadline - time.perf_counter()))
            if not readable:
                return None
            try:
                data, source = sock.recvfrom(self.codec.max_packet + 64)
            except (BlockingIOError, InterruptedError, ConnectionError):
                continue
            t = time.perf_counter()
            self.received += 1
            if source != self.addr:
                self.wrong_sources.add(source)
            try:
                header = self.codec.peek(data, frozenset({proto.MEASUREMENT, proto.ANSWER}))
                key = self.security.key if header.kind == proto.ANSWER else self.session_keys.get(header.session)
                packet = self.codec.open(data, header, key)
            except proto.PacketError as exc:
                self.invalid[exc.reason] = self.invalid.get(exc.reason, 0) + 1
                continue
            if packet.kind == proto.ANSWER:
                self.challenge = packet.fields["challenge"]
            return Received(packet, len(data), source, t)

    def drain(self, aux: bool = False) -> list[Received]:
        out = []
        while (rec := self.receive(0.0, aux)) is not None:
            out.append(rec)
        return out

    def hello(self, timeout_s: float = 0.2) -> Received | None:
        """One HELLO from the HELLO socket (repeated every 0.2 s within ``timeout_s``) and its answer."""
        self.drain(aux=True)
        end = time.perf_counter() + timeout_s
        while time.perf_counter() < end:
            nonce = auth.new_nonce()
            self.send(self.hello_packet(nonce), aux=True)
            t = time.perf_counter()
            while (rec := self.receive(min(end, t + 0.2), aux=True)) is not None:
                if self.codec.version == 1 or rec.packet.fields["nonce"] == nonce:
                    return rec
        return None

    def close(self) -> None:
        self.sock.close()
        self.aux.close()

    # --- packets: version 1, or version 2 tagged with the lab's key or the session's --------------------------
    def encode(self, kind: int, session: int, sequence: int, time_ns: int, *payload, key: bytes | None = None) -> bytes:
        """A packet of this link's version. Version 2: an ARM gets the rig's current challenge (a HELLO fetches
        it) and its session's key is kept; a COMMAND, DISARM or MEASUREMENT is tagged with its session's key,
        else the running session's (so that only what a probe breaks on purpose is wrong)."""
        if self.codec.version == 1:
            return self.codec.encode(kind, session, sequence, time_ns, *payload)
        if kind == proto.ARM and len(payload) == 2:
            payload = (*payload, self.fresh_challenge())
        if kind == proto.ARM:
            self.session_keys[session] = auth.session_key(self.security.key, payload[2], session)
        if key is None:
            key = self.security.key if kind in proto.LAB_KEY_KINDS else self.key_of(session)
        return self.codec.encode(kind, session, sequence, time_ns, *payload, key=key)

    def key_of(self, session: int) -> bytes | None:
        return self.session_keys.get(session, self.current_key or self.security.key)

    def seal(self, body: bytes, session: int) -> bytes:
        """``body`` with a correct CRC or tag: only what the probe breaks on purpose is wrong."""
        return self.codec.seal(body, None if self.codec.version == 1 else self.key_of(session))

    def hello_packet(self, nonce: bytes | None = None) -> bytes:
        if self.codec.version == 1:
            return self.codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns())
        return self.codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns(), nonce or auth.new_nonce(),
                                 key=self.security.key)

    def fresh_challenge(self) -> bytes:
        """The rig's current challenge (version 2), from a HELLO if the last one was spent."""
        if self.challenge is None and self.hello() is None:
            raise RigUnreachable("no answer to the HELLO that fetches the rig's challenge for an ARM")
        return self.challenge


class Stream:
    """One armed session: its ARM, then its measurements, answered (0 V unless told) or not, one by one."""

    def __init__(self, check: RigCheck, session: int | None = None):
        self.check, self.link = check, check.link
        self.session = session or new_session()
        self.last: Received | None = None
        self.last_answer_t = 0.0
        self.last_answer_data = b""
        self.arm_sent_t = 0.0
        self.foreign = 0  # measurements of another session on this socket
        self.armed = False
        self.best_offset_ns: int | None = None  # arrival minus the rig's time_ns, the least seen
        self.clock = True  # the rig's time_ns advances like a clock (it is only for its own statistics)
        self.recent: deque[Received] = deque(maxlen=RECENT_READS)  # the measurements read last, the latest last

    def arm(self, timeout_s: float) -> Received:
        """ARM (repeated every 50 ms, as the host does) until the first measurement of the session."""
        data = self.arm_data = self.link.encode(proto.ARM, self.session, 0, time.perf_counter_ns(),
                                                self.check.supply_pa, self.check.vertical_load_n)
        start = time.perf_counter()
        end, next_send = start + timeout_s, start
        while time.perf_counter() < end:
            if time.perf_counter() >= next_send:
                if not self.arm_sent_t:
                    self.arm_sent_t = time.perf_counter()
                self.link.send(data)
                next_send = time.perf_counter() + ARM_RESEND_S
            rec = self.link.receive(min(end, next_send))
            if rec is None:
                continue
            if rec.packet.session != self.session:
                self.foreign += 1
                continue
            self.armed = True
            self.link.challenge = None  # spent: the rig draws a new one
            self.link.current_key = self.link.session_keys.get(self.session)
            self.first_ms = (rec.t - start) * 1e3
            self.last = rec
            return rec
        raise Silent(f"no measurement of the session within {timeout_s:g} s of its ARM")

    def next(self, timeout_s: float = SILENT_S) -> Received:
        """The next measurement of this session; ``Tripped`` if it is not armed, ``Silent`` if none comes."""
        deadline = time.perf_counter() + timeout_s
        while True:
            rec = self.link.receive(deadline)
            if rec is None:
                last = self.last.seq if self.last else "none"
                raise Silent(f"no measurement for {timeout_s * 1e3:.0f} ms after sequence {last}")
            if rec.packet.session != self.session:
                self.foreign += 1
                continue
            if self.last is not None and rec.seq > self.last.seq:
                sent_ns = rec.packet.time_ns - self.last.packet.time_ns
                if not 0 < sent_ns < 1000 * (rec.seq - self.last.seq) * max(1, rec["period_ns"]):
                    self.clock = False  # not a clock: this check cannot tell how late it reads
            if self.clock:
                offset = int(rec.t * 1e9) - rec.packet.time_ns
                if self.best_offset_ns is None or offset < self.best_offset_ns:
                    self.best_offset_ns = offset
                rec.late_s = (offset - self.best_offset_ns) * 1e-9
            self.last = rec
            self.recent.append(rec)
            if not rec.status & STATUS_ARMED:
                self.armed = False
                raise Tripped(rec)
            return rec

    def answer(self, rec: Received, command_v: float = 0.0) -> bytes:
        data = self.link.encode(proto.COMMAND, self.session, rec.seq, time.perf_counter_ns(), command_v)
        self.link.send(data)
        self.last_answer_t = time.perf_counter()
        self.last_answer_data = data
        return data

    def steady(self, n: int) -> list[Received]:
        """n measurements, each answered with 0 V."""
        out = []
        for _ in range(n):
            rec = self.next()
            self.answer(rec)
            out.append(rec)
        return out

    def skip(self, n: int) -> list[Received]:
        """n measurements, none answered."""
        return [self.next() for _ in range(n)]

    def sync(self, limit: int = 20) -> list[Received]:
        """Answer the next measurement, and on until the rig reports that answer applied (the last of the list
        returned): whatever was sent before it has then been dealt with. [] if it never is."""
        first = self.next()
        self.answer(first)
        out = [first]
        for _ in range(limit):
            rec = self.next()
            self.answer(rec)
            out.append(rec)
            if rec["command_sequence"] >= first.seq:
                return out
        return []

    def on_time(self, rec: Received) -> None:
        """``Disturbed`` if ``rec`` was read late: this process, not the rig, would decide the probe."""
        if rec.late_s > LATE_S:
            raise Disturbed(f"this check read measurement {rec.seq} {rec.late_s * 1e3:.1f} ms late")

    def recent_on_time(self) -> None:
        """``Disturbed`` if any of the last RECENT_READS measurements was read late: the answers this check sent
        meanwhile may have reached the rig stale and been counted with what a probe sent."""
        for rec in self.recent:
            self.on_time(rec)

    def disarm(self) -> None:
        packet = self.link.encode(proto.DISARM, self.session, 0, time.perf_counter_ns())
        for _ in range(3):
            self.link.send(packet)
        self.armed = False
        end = time.perf_counter() + 0.02
        while self.link.receive(end) is not None:  # what was in flight
            pass
