"""A rig over UDP: a real-time I/O target (or ``isorig rig-emulator``) speaking docs/rig-protocol.md.

The rig is the clock: it sends one MEASUREMENT per control period and the driver answers each with one
COMMAND. ``wait_next_period`` blocks until the next measurement arrives; a gap in the rig's sequence
numbers means measurements were lost (the loop records those periods as lost, sim.loop). Whatever is
malformed, damaged, of another protocol version or session, stale or duplicated is dropped and counted,
never used. No measurement for ``timeout_s`` raises ``RigFault`` (the rig's own watchdog closes its valve
meanwhile), as does a rig that stops reporting itself armed (watchdog, restart, interlock).

Protocol version 2 (the default) authenticates every packet (sim.emulator.auth): a HELLO with a fresh nonce
fetches the rig's challenge, the ARM carries it, and the session's key derived from it tags every measurement,
command and DISARM; a datagram from anywhere but the rig's address, with a wrong tag, or replayed (a sequence
not above the latest) is dropped and counted. Version 1 runs without a key where it is named (or on loopback
without a key file), and says so in ``describe()`` and ``link_stats()`` (``authenticated: False``).

Standard library only (socket, struct, zlib, hmac): the protocol needs nothing more.
"""

from __future__ import annotations

import math
import secrets
import select
import socket
import time
from urllib.parse import urlsplit

from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.latency import LatencyHistogram
from sim.measurement import RIG_FAULT_BITS, STATUS_ARMED, Measurement, describe_status
from sim.rig import DEFAULT_RIG

from .base import ArmConditions, RigDescription, RigDriver, RigFault, check_command

ARM_RESEND_S = 0.05  # ARM is repeated this often until the rig answers
DISARM_REPEATS = 3  # DISARM travels on UDP too: sent three times
ARM_TRIES_PER_CHALLENGE = 4  # version 2: ARMs sent with one challenge before a HELLO fetches a fresh one
#: a probe's HELLO unanswered this long is sent again (a fresh nonce), until the probe's deadline: a HELLO lost on
#: the network, or dropped by a rig's rate limit (section 9.6), does not make a rig that is there look absent
PROBE_RESEND_S = 0.04


def parse_udp_url(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port), or a ValueError that says what is wrong."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != "udp" or not parts.hostname or port is None or parts.path not in ("", "/"):
        raise ValueError(f"rig {url!r} is not of the form udp://HOST:PORT (e.g. udp://127.0.0.1:5555)")
    if not (1 <= port <= 65535):
        raise ValueError(f"rig {url!r}: port {port} is outside [1, 65535]")
    return parts.hostname, port


class UdpRig(RigDriver):
    """A rig at ``host:port`` over the isorig rig protocol, version 2 (``key_file``) or 1 (see the module
    docstring and sim.emulator.auth.resolve_security for which)."""

    def __init__(self, host: str, port: int, period_s: float = 1e-3, timeout_s: float = 0.05,
                 arm_timeout_s: float = 2.0, command_limit_v: float = DEFAULT_RIG.command_limit_v,
                 key_file: str | None = None, protocol_version: int | None = None,
                 security: auth.LinkSecurity | None = None):
        for name, value in (("period_s", period_s), ("timeout_s", timeout_s), ("arm_timeout_s", arm_timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r} must be a positive number of seconds")
        self.host, self.port = host, port
        self.security = security or auth.resolve_security(host, key_file, protocol_version)  # ValueError: why not
        self.codec = proto.Codec(self.security.protocol_version)
        self.session_key: bytes | None = None
        self.addr: tuple | None = None
        self.period_s = period_s
        self.timeout_s = timeout_s
        self.arm_timeout_s = arm_timeout_s
        self.command_limit_v = command_limit_v
        self.sock: socket.socket | None = None
        self.session = 0
        self.last_sequence: int | None = None
        self.current: Measurement | None = None
        self.received_at = 0.0
        self.received_wall_s: float | None = None  # wall clock (time.time) of the last measurement
        # the rig's send time (its monotonic clock, ns) of the newest measurement and of the first one the last
        # wait took: on loopback the host's clock too (sim.realtime.PeriodTrace tells a late rig from a late host)
        self.sent_ns: int | None = None
        self.first_sent_ns: int | None = None
        self._reset_stats()

    @classmethod
    def from_url(cls, url: str, **link) -> UdpRig:
        host, port = parse_udp_url(url)
        return cls(host, port, **link)

    @property
    def url(self) -> str:
        return f"udp://{self.host}:{self.port}"

    def _reset_stats(self) -> None:
        self.stats = {"received": 0, "lost": 0, "rejected": {}, "commands_sent": 0}
        self.rig_counters = {"commands_missed": 0, "packets_rejected": 0}
        self.round_trip = LatencyHistogram()  # as the rig saw it: measurement sent -> command arrived
        self.answer = LatencyHistogram()  # in this process: measurement received -> command sent
        self.last_command_t: float | None = None
        self.last_command_cpu_s = 0.0  # this thread's CPU time (time.thread_time) at the last command
        self.command_gap_max_s = 0.0  # the longest time between two commands sent (host_stall_max_ms)
        # the stall that ended the test, which no later command measures: a rig fault raised by a wait
        self.stall_at_fault: dict | None = None

    def describe(self) -> RigDescription:
        return RigDescription(name=self.url, kind="udp", control_period_s=self.period_s,
                              command_limit_v=self.command_limit_v, realtime=True,
                              details={"host": self.host, "port": self.port, **self.security.describe(),
                                       "link_timeout_s": self.timeout_s, "arm_timeout_s": self.arm_timeout_s})

    # --- socket ---------------------------------------------------------------------------------------
    def _open(self) -> socket.socket:
        if self.sock is None:
            try:
                self.addr = socket.getaddrinfo(self.host, self.port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][:2]
            except OSError as exc:
                raise RigFault(f"cannot reach the rig at {self.url}: {exc.strerror or exc}") from None
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            # not connected: a datagram from another address is read, dropped and counted (``address``)
            sock.bind(("", 0))
            sock.setblocking(False)
            self.sock = sock
        return self.sock

    def _send(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.addr)
        except OSError:  # e.g. ECONNREFUSED from an earlier datagram: nobody listens yet; the timeouts decide
            pass

    def _reject(self, reason: str) -> None:
        self.stats["rejected"][reason] = self.stats["rejected"].get(reason, 0) + 1

    def _receive(self, deadline: float, nonce: bytes | None = None) -> proto.Packet | None:
        """The next valid MEASUREMENT of this session (with ``nonce``: the ANSWER to the HELLO that carried it),
        or None at the deadline (a past deadline: what is already queued, without waiting)."""
        want = proto.MEASUREMENT if nonce is None else proto.ANSWER
        while True:
            wait = max(0.0, deadline - time.perf_counter())
            readable, _, _ = select.select([self.sock], [], [], wait)
            if not readable:
                return None
            try:
                data, source = self.sock.recvfrom(self.codec.max_packet + 64)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:  # ECONNREFUSED after a send to a port nobody listens on
                continue
            if source[:2] != self.addr:
                self._reject("address")  # not from the rig's address and port
                continue
            try:
                header = self.codec.peek(data, frozenset({want}))
            except proto.PacketError as exc:
                self._reject(exc.reason)
                continue
            if nonce is None and header.session != self.session:
                self._reject("session")
                if self.codec.version == 1 and header.session == 0 and self.current is not None:
                    raise RigFault(f"the rig at {self.url} is no longer armed (it restarted or was disarmed by "
                                   "someone else); nothing moves until a new test is started")
                continue
            try:
                packet = self.codec.open(data, header, self.security.key if nonce else self.session_key)
            except proto.PacketError as exc:
                self._reject(exc.reason)
                continue
            if nonce is not None and packet.fields["nonce"] != nonce:
                self._reject("stale")  # the answer to an earlier HELLO
                continue
            return packet

    def _challenge(self, end: float) -> bytes | None:
        """Version 2: the rig's current ARM challenge, from the ANSWER to a fresh HELLO (sent every 50 ms)."""
        while time.perf_counter() < end:
            nonce = auth.new_nonce()
            self._send(self.codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns(), nonce, key=self.security.key))
            packet = self._receive(min(end, time.perf_counter() + ARM_RESEND_S), nonce=nonce)
            if packet is not None:
                return packet.fields["challenge"]
        return None

    # --- protocol -------------------------------------------------------------------------------------
    def arm(self, conditions: ArmConditions) -> None:
        self._open()
        self._reset_stats()
        self.current = None
        end = time.perf_counter() + self.arm_timeout_s
        v2 = self.codec.version == 2
        while time.perf_counter() < end:
            self.session = secrets.randbits(32) or 1
            if v2:  # a fresh challenge, a new session and its key for each round of ARMs
                challenge = self._challenge(end)
                if challenge is None:
                    break
                self.session_key = auth.session_key(self.security.key, challenge, self.session)
                arm = self.codec.encode(proto.ARM, self.session, 0, time.perf_counter_ns(),
                                        conditions.supply_pressure_pa, conditions.vertical_load_n, challenge,
                                        key=self.security.key)
            else:
                arm = self.codec.encode(proto.ARM, self.session, 0, time.perf_counter_ns(),
                                        conditions.supply_pressure_pa, conditions.vertical_load_n)
            for _ in range(ARM_TRIES_PER_CHALLENGE if v2 else 1 << 30):
                if time.perf_counter() >= end:
                    break
                self._send(arm)
                packet = self._receive(min(end, time.perf_counter() + ARM_RESEND_S))
                if packet is None:
                    continue
                rig_period = packet.fields["period_ns"] * 1e-9
                if abs(rig_period - self.period_s) > 1e-9:
                    self.disarm(success=False)
                    raise RigFault(f"the rig at {self.url} runs at a control period of {rig_period:g} s; "
                                   f"this service is set for {self.period_s:g} s (rig_period_s)")
                if not packet.fields["status"] & STATUS_ARMED:
                    continue
                self._accept(packet)
                return
        self.disarm(success=False)
        raise RigFault(self._why_not_armed(conditions))

    def _why_not_armed(self, conditions: ArmConditions) -> str:
        """Why the ARMs went unanswered: a rig refuses an ARM in silence (docs/rig-protocol.md section 3.1), so
        ask it with HELLO whether it is there, armed by another test, or counting refused ARMs."""
        answer = probe(self.url, security=self.security)
        waited = f"no answer from the rig at {self.url} within {self.arm_timeout_s:g} s of ARM"
        if not answer["connected"]:
            return f"{waited} (is it running and reachable? {answer['detail']})"
        if answer["armed"]:
            return f"{waited}: it is armed by another test or move (its ARM was refused as busy)"
        return (f"{waited}: it answers HELLO but refused the ARM ({conditions.supply_pressure_pa / 1e5:g} bar, "
                f"vertical load {conditions.vertical_load_n / 1e3:g} kN; it has dropped "
                f"{answer['packets_rejected']} packet(s) since its last test): the supply pressure or the vertical "
                "load is outside the rig's own range, which the service's rig file must match")

    def _accept(self, packet: proto.Packet) -> None:
        f = packet.fields
        seq = packet.sequence
        if self.current is not None:
            gap = seq - self.current.period - 1
            if gap < 0:
                self._reject("stale")
                return
            self.stats["lost"] += gap
        self.received_at = time.perf_counter()
        self.received_wall_s = time.time()
        self.stats["received"] += 1
        self.rig_counters = {"commands_missed": f["commands_missed"], "packets_rejected": f["packets_rejected"]}
        if f["command_latency_us"] and f["command_sequence"] == seq - 1:  # the rig's figure for our last answer
            self.round_trip.add(f["command_latency_us"] / 1e3)
        self.last_sequence = seq
        self.sent_ns = packet.time_ns
        self.current = Measurement(seq, seq * self.period_s, f["position_m"], f["force_n"], f["load_pressure_pa"],
                                   f["supply_pressure_pa"], int(f["status"]))

    def read(self) -> Measurement:
        if self.current is None:
            raise RigFault(f"the rig at {self.url} is not armed")
        return self.current

    def write(self, command_v: float) -> None:
        u = check_command(command_v, self.command_limit_v)
        if self.current is None or self.sock is None:
            raise RigFault(f"the rig at {self.url} is not armed")
        self._send(self.codec.encode(proto.COMMAND, self.session, self.current.period, time.perf_counter_ns(), u,
                                     key=self.session_key))
        now = time.perf_counter()
        self.stats["commands_sent"] += 1
        self.answer.add((now - self.received_at) * 1e3)
        if self.last_command_t is not None:
            self.command_gap_max_s = max(self.command_gap_max_s, now - self.last_command_t)
        self.last_command_t = now
        self.last_command_cpu_s = time.thread_time()

    def wait_next_period(self) -> None:
        if self.current is None:
            raise RigFault(f"the rig at {self.url} is not armed")
        entered = time.perf_counter()
        last = self.current.period
        while self.current.period == last:
            packet = self._receive(self.received_at + self.timeout_s)
            if packet is None:
                self._note_fault_stall(entered)
                raise RigFault(f"no measurement from the rig at {self.url} for {self.timeout_s:g} s "
                               f"(last sequence {last}): link lost")
            self._accept(packet)
        self.first_sent_ns = self.sent_ns
        while True:  # measurements that queued up while the host was late: the newest counts, the rest are lost
            packet = self._receive(0.0)
            if packet is None:
                break
            self._accept(packet)
        status = self.current.status
        if not status & STATUS_ARMED:
            self._note_fault_stall(entered)
            raise RigFault(f"the rig at {self.url} disarmed itself ({describe_status(status & RIG_FAULT_BITS)})")

    def _note_fault_stall(self, entered: float) -> None:
        """The wait that ends in a fault: how long since the last command, how much of it the loop spent before it
        waited (its own work, ``busy_ms``), its CPU time over it and, the rest, off its CPU (preempted, or blocked
        elsewhere) before it waited; the rig's measurement that said so (``rig_sent_after_command_ms``, on
        loopback where the rig's clock is this one)."""
        if self.last_command_t is None:
            return
        now = time.perf_counter()
        busy_s = entered - self.last_command_t
        cpu_s = time.thread_time() - self.last_command_cpu_s
        record = {"after_last_command_ms": round((now - self.last_command_t) * 1e3, 3),
                  "busy_ms": round(busy_s * 1e3, 3), "cpu_ms": round(cpu_s * 1e3, 3),
                  "busy_off_cpu_ms": round(max(0.0, busy_s - cpu_s) * 1e3, 3)}
        sent_s = (self.sent_ns or 0) * 1e-9
        if 0 <= now - sent_s < 1.0:  # a rig on this machine: its send time on this clock
            record["rig_sent_after_command_ms"] = round((sent_s - self.last_command_t) * 1e3, 3)
        self.stall_at_fault = record

    def disarm(self, success: bool = True) -> None:
        if self.sock is not None:
            if self.session and (self.codec.version == 1 or self.session_key is not None):
                packet = self.codec.encode(proto.DISARM, self.session, 0, time.perf_counter_ns(), key=self.session_key)
                for _ in range(DISARM_REPEATS):
                    self._send(packet)
            self.sock.close()
            self.sock = None
        self.current = None

    def link_stats(self) -> dict:
        out = {"rig": self.url, "last_sequence": self.last_sequence, "last_received_wall_s": self.received_wall_s,
               "received": self.stats["received"], "lost": self.stats["lost"],
               "rejected": sum(self.stats["rejected"].values()), "rejected_by_reason": dict(self.stats["rejected"]),
               "rig_commands_missed": self.rig_counters["commands_missed"],
               "rig_packets_rejected": self.rig_counters["packets_rejected"], **self.security.describe(),
               "host_stall_max_ms": max(0.0, self.command_gap_max_s - self.period_s) * 1e3}
        if self.stall_at_fault is not None:
            out["stall_at_fault"] = dict(self.stall_at_fault)
        if self.round_trip.n:
            out.update(round_trip_p50_ms=self.round_trip.percentile_ms(50),
                       round_trip_p99_ms=self.round_trip.percentile_ms(99), round_trip_max_ms=self.round_trip.max_ms)
        if self.answer.n:
            out.update(answer_p99_ms=self.answer.percentile_ms(99), answer_max_ms=self.answer.max_ms)
        return out


def probe(url: str, timeout_s: float = 0.2, key_file: str | None = None, protocol_version: int | None = None,
          security: auth.LinkSecurity | None = None) -> dict:
    """HELLO to the rig at ``url``, sent again every PROBE_RESEND_S until an answer or ``timeout_s``: is it there,
    what does it say, how long did it take. Version 2 (a key): each HELLO carries a fresh nonce and only the rig's
    ANSWER to one of them, with a right tag, counts."""
    host, port = parse_udp_url(url)
    try:
        security = security or auth.resolve_security(host, key_file, protocol_version)
    except ValueError as exc:
        return {"rig": url, "connected": False, "detail": str(exc)}
    codec = proto.Codec(security.protocol_version)
    dropped: dict[str, int] = {}
    sent: dict[bytes, float] = {}  # nonce -> when its HELLO left (version 1 sends none: any answer counts)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        t0 = time.perf_counter()
        try:
            sock.connect((host, port))
            packet = _hello_answer(sock, codec, security, t0 + timeout_s, sent, dropped)
        except ConnectionRefusedError:
            return {"rig": url, "connected": False,
                    "detail": f"nothing listens at {host}:{port} (the rig or its emulator is not running there)"}
        except OSError as exc:
            return {"rig": url, "connected": False, "detail": f"cannot reach {host}:{port}: {exc.strerror or exc}"}
        if packet is None:
            if dropped:
                what = ", ".join(f"{n} {reason}" for reason, n in dropped.items())
                hint = (" (the rig holds another key than this host's key file)" if "auth" in dropped else
                        " (another protocol version: --rig-protocol, ISORIG_RIG_PROTOCOL)" if "version" in dropped
                        else "")
                return {"rig": url, "connected": False, "hellos_sent": len(sent), "detail": f"{host}:{port} answers, "
                        f"but not in the isorig rig protocol v{codec.version} this host speaks (dropped: {what}){hint}"}
            return {"rig": url, "connected": False, "hellos_sent": len(sent),
                    "detail": f"no answer from {host}:{port} to {len(sent)} HELLO(s) "
                    f"within {timeout_s:g} s (is it running, with rig protocol v{codec.version}"
                    + (" and the same key file?)" if security.authenticated else "?)")}
        status = int(packet.fields["status"])
        asked = sent.get(packet.fields.get("nonce"), t0)  # version 1: from the first HELLO
        return {"rig": url, "connected": True, "round_trip_ms": (time.perf_counter() - asked) * 1e3,
                "hellos_sent": len(sent), "armed": bool(status & STATUS_ARMED), "status": describe_status(status),
                "fault": bool(status & RIG_FAULT_BITS), "position_m": packet.fields["position_m"],
                "force_n": packet.fields["force_n"], "supply_pressure_pa": packet.fields["supply_pressure_pa"],
                "period_s": packet.fields["period_ns"] * 1e-9, "packets_rejected": packet.fields["packets_rejected"],
                **security.describe()}


def _hello_answer(sock: socket.socket, codec: proto.Codec, security: auth.LinkSecurity, deadline: float,
                  sent: dict, dropped: dict) -> proto.Packet | None:
    """The rig's answer to one of the HELLOs sent on the connected ``sock`` (a new one every PROBE_RESEND_S, each
    recorded in ``sent``), or None at ``deadline``; what was dropped is counted in ``dropped`` by reason."""
    want = proto.MEASUREMENT if codec.version == 1 else proto.ANSWER
    resend = time.perf_counter()
    while True:
        now = time.perf_counter()
        if now >= deadline:
            return None
        if now >= resend:
            nonce = auth.new_nonce()
            sock.send(codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns()) if codec.version == 1 else
                      codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns(), nonce, key=security.key))
            sent[nonce] = now
            resend = now + PROBE_RESEND_S
        sock.settimeout(max(1e-4, min(resend, deadline) - now))
        try:
            data = sock.recv(codec.max_packet + 64)
        except TimeoutError:
            continue
        try:
            header = codec.peek(data)
            if header.kind != want:
                continue
            packet = codec.open(data, header, security.key)
        except proto.PacketError as exc:
            dropped[exc.reason] = dropped.get(exc.reason, 0) + 1
            continue
        if codec.version == 1 or packet.fields["nonce"] in sent:
            return packet


START_TOLERANCE_M = 0.002  # a test starts only with the table this close to zero, where every target begins


def start_position_problem(url: str, tolerance_m: float = START_TOLERANCE_M, timeout_s: float = 0.2,
                           expected_m: float = 0.0, **security) -> str | None:
    """Why nothing may start on the rig at ``url`` now, or None: it may. Refused when the rig does not answer
    (where its table is is then unknown), when it is armed (another host's test or move runs on it), and when
    its table is more than ``tolerance_m`` from ``expected_m``, where the target begins (0 for every test),
    since the controller would drive it there at full flow."""
    answer = probe(url, timeout_s, **security)
    if not answer["connected"]:
        return f"{answer['detail']}, so where its table is is unknown; nothing moved"
    if answer["armed"]:
        return "the rig is armed: another test or move runs on it (wait for it to end); nothing moved"
    y = answer["position_m"]
    if abs(y - expected_m) <= tolerance_m:
        return None
    return (f"the table is at {y * 1e3:.2f} mm and the run starts at {expected_m * 1e3:.2f} mm (within "
            f"+-{tolerance_m * 1e3:g} mm): {move_first(expected_m)}; nothing moved")


def move_first(start_m: float) -> str:
    """What to do when the table is not where a run starts."""
    if start_m == 0.0:
        return "move the table to zero first (POST /api/rig/zero, the console's Zero button, or isorig move)"
    return (f"move the table to {start_m * 1e3:.2f} mm first (POST /api/rig/move, the console's Move button, or "
            "isorig move)")
