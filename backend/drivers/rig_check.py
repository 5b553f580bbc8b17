"""``check_rig(url)``: the conformance check of a rig's real-time I/O target against docs/rig-protocol.md.

What ``check_driver`` (backend/drivers/check.py) does for a Python driver, for a target written in any
language: it talks raw UDP with the reference codec (sim/emulator/protocol.py) and checks every rule of the
protocol document, one row per rule naming its section (``isorig check-rig``, docs/drivers.md):

- HELLO: the answer, session 0 and sequence 0 when unarmed, the table's position, the counters; armed, the
  test's session and latest sequence; replies from the address and port it was sent to;
- ARM: refused in silence and counted outside the rig's ranges (``rig``: the lab's rig file) or with session 0;
  accepted with measurement 0 and the counters from zero; repeated, busy, and again after the test ended;
- the sequence (+1 per period), the period, ``command_sequence``, ``COMMAND_MISSED``, a late command applied;
- each drop reason (short, size, magic, version, kind, crc, session, stale, future, value, busy, arm), seen in
  the rig's ``packets_rejected`` and in the command not being applied (``command_sequence`` not reaching it);
- DISARM (the stream stops), the rig unarmed (silent, commands dropped), the watchdog (its time from the last
  command and from ARM, its last measurement, stale commands not feeding it);
- version 2 (section 9): a HELLO without the key unanswered, HELLO's rate, a HELLO answered while a keyless flood
  from another socket runs (the rate is per source), tags, the ARM's address and challenge;
- with ``motion``: the direction of the table, the signs of ``load_pressure_pa`` (its change from the rest
  before each push, ``pressure_change``: whatever specimen is mounted) and ``force_n``, the position a HELLO
  reports after the table moved.

Every command it sends is 0.0 V, except the ones a conforming rig must refuse (NaN, infinite, 1.2 x the command
limit: never applied), and, with ``motion``, +-``motion_v`` until the table has moved 0.3 mm (stopped at once
beyond 1 mm). ARMs outside the rig's ranges are sent too: a conforming rig refuses them.

The rig's watchdog (10-20 ms) closes the valve whenever this process is late: a probe it interrupts is run
again with a new session, up to ``TRIES`` times, and the row says so.
"""

from __future__ import annotations

import gc
import math
import secrets
import select
import socket
import statistics
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.measurement import STATUS_ARMED, STATUS_COMMAND_MISSED, STATUS_WATCHDOG
from sim.realtime import realtime_priority
from sim.rig import DEFAULT_RIG, RigParameters

from .udp import parse_udp_url
from .udp import probe as hello_probe

WATCHDOG_MIN_S, WATCHDOG_MAX_S = 0.010, 0.020  # section 1.5
WATCHDOG_TOLERANCE_S = 0.004  # plus one period: the figure adds the link both ways and the rig's tick
WATCHDOG_GIVE_UP_S = 0.3  # still armed this long after the last command: the rig has no watchdog
WATCHDOG_TRIPS = 3  # the figure is their median: one late wake-up of a shared machine does not decide it
STALE_PERIODS = 10  # section 5
ARM_RESEND_S = 0.05  # as the host does
SILENCE_S = 0.05  # a refused ARM, a disarmed rig: nothing may arrive for this long
SILENT_S = 0.25  # no measurement this long from an armed rig: the stream stopped
LATE_S = 0.004  # a measurement read this late (this process was not scheduled): a timed probe is run again
STEADY_PERIODS = 500
TRIES = 3
VALUE_FACTOR = 1.2  # a command this far beyond the limit must be refused
POSITION_AGREE_M = 0.5e-3  # a HELLO's position and the armed stream's, at rest
MOTION_STEP_M = 0.3e-3  # --motion: how far the table is pushed
MOTION_STOP_M = 1e-3  # ... and where the command goes to 0 V at once
MOTION_MAX_V = 3.0
MOTION_REST_PERIODS = 20  # readings at rest before each push: the load pressure's level and noise there
MOTION_PRESSURE_MIN_PA = 0.1e5  # a push changes the mean load pressure by at least this much ...
MOTION_PRESSURE_SIGMAS = 4.0  # ... and by this many standard errors of the reading's noise (seen at rest)
HELLO_FOLLOW_M = 0.05e-3  # a HELLO after the motion: where the last measurement left the table
HELLO_BURST_SENT = 40  # version 2: HELLOs sent at once to see the rate limit (section 9.6) ...
HELLO_BURST, HELLO_RATE_PER_S = 10, 100.0  # ... which answers about this many at once and per second
HELLO_FLOOD_SENT = 30  # version 2: keyless HELLOs from a third socket before the host's HELLO, and as many after


def pressure_change(rest_pa: list[float], pushed_pa: list[float]) -> tuple[float, float]:
    """(the mean load pressure over a push less its mean at rest just before it, the smallest change that is
    not noise): MOTION_PRESSURE_MIN_PA, or MOTION_PRESSURE_SIGMAS standard errors of that difference with the
    reading's noise estimated at rest, the larger. The rest reading holds the specimen (and friction); a push
    towards +y must add to it, so the change has the push's sign whatever specimen is mounted (docs/rig-
    protocol.md section 4.2)."""
    if len(rest_pa) < 2 or not pushed_pa:
        return math.nan, math.nan
    noise_pa = statistics.stdev(rest_pa)
    error_pa = noise_pa * math.sqrt(1.0 / len(rest_pa) + 1.0 / len(pushed_pa))
    change_pa = statistics.fmean(pushed_pa) - statistics.fmean(rest_pa)
    return change_pa, max(MOTION_PRESSURE_MIN_PA, MOTION_PRESSURE_SIGMAS * error_pa)


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


@dataclass
class RuleResult:
    """One rule: the section of docs/rig-protocol.md, what it says, passed (None: not checked), the figure."""

    section: str
    rule: str
    ok: bool | None
    figure: str = ""
    detail: str = ""

    def to_dict(self) -> dict:
        return {"section": self.section, "rule": self.rule, "ok": self.ok, "figure": self.figure,
                "detail": self.detail}


def _section_key(section: str) -> tuple:
    return tuple(int(part) for part in section.lstrip("§").split("."))


@dataclass
class RigCheckReport:
    """Every rule's result, in the order of the document, and the measured figures."""

    url: str
    motion: bool
    results: list[RuleResult] = field(default_factory=list)
    figures: dict = field(default_factory=dict)

    @property
    def failures(self) -> list[RuleResult]:
        return [r for r in self.results if r.ok is False]

    @property
    def ok(self) -> bool:
        return bool(self.results) and not self.failures

    def ordered(self) -> list[RuleResult]:
        return sorted(self.results, key=lambda r: _section_key(r.section))

    def table(self) -> str:
        width = max(len(r.rule) for r in self.results)
        lines = [f"{'':4}  {'section':7}  {'rule':{width}}  measured"]
        for r in self.ordered():
            mark = "PASS" if r.ok else ("FAIL" if r.ok is False else "skip")
            lines.append(f"{mark:4}  {r.section:7}  {r.rule:{width}}  {r.figure}".rstrip())
            if r.detail and r.ok is not True:
                lines.append(f"{'':15}{r.detail}")
        passed = sum(1 for r in self.results if r.ok)
        skipped = sum(1 for r in self.results if r.ok is None)
        failed = self.failures
        verdict = f"{passed} of {len(self.results)} rules passed"
        if skipped:
            verdict += f", {skipped} not checked"
        if failed:
            verdict += f"; FAILED: {', '.join(f'{r.section} {r.rule}' for r in failed)}"
        lines.append(verdict)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"rig": self.url, "ok": self.ok, "motion": self.motion,
                "passed": sum(1 for r in self.results if r.ok), "failed": len(self.failures),
                "rules": [r.to_dict() for r in self.ordered()], "figures": self.figures}


def _new_session() -> int:
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
        self.session = session or _new_session()
        self.last: Received | None = None
        self.last_answer_t = 0.0
        self.last_answer_data = b""
        self.arm_sent_t = 0.0
        self.foreign = 0  # measurements of another session on this socket
        self.armed = False
        self.best_offset_ns: int | None = None  # arrival minus the rig's time_ns, the least seen
        self.clock = True  # the rig's time_ns advances like a clock (it is only for its own statistics)

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

    def disarm(self) -> None:
        packet = self.link.encode(proto.DISARM, self.session, 0, time.perf_counter_ns())
        for _ in range(3):
            self.link.send(packet)
        self.armed = False
        end = time.perf_counter() + 0.02
        while self.link.receive(end) is not None:  # what was in flight
            pass


Probe = Callable[[Stream], list[tuple[bool, str, str]]]


class RigCheck:
    """The check of one rig (see the module docstring); ``run()`` gives the report."""

    def __init__(self, url: str, rig: RigParameters = DEFAULT_RIG, supply_pa: float = 20e5,
                 vertical_load_n: float = 0.0, period_s: float = 1e-3, timeout_s: float = 1.0,
                 motion: bool = False, motion_v: float = 1.5, security: auth.LinkSecurity | None = None):
        host, port = parse_udp_url(url)
        self.security = security or auth.resolve_security(host)  # loopback without a key: version 1
        if not (rig.min_supply_pa <= supply_pa <= rig.max_supply_pa):
            raise ValueError(f"the check's supply pressure {supply_pa / 1e5:g} bar is outside the rig's range "
                             f"[{rig.min_supply_pa / 1e5:g}, {rig.max_supply_pa / 1e5:g}] bar")
        if not (0.0 <= vertical_load_n <= rig.max_vertical_load_n):
            raise ValueError(f"the check's vertical load {vertical_load_n:g} N is outside the rig's range "
                             f"[0, {rig.max_vertical_load_n:g}] N")
        for name, value in (("period_s", period_s), ("timeout_s", timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r} must be a positive number of seconds")
        if not (0.0 < motion_v <= min(MOTION_MAX_V, rig.command_limit_v)):
            raise ValueError(f"motion_v = {motion_v!r} V is outside (0, {min(MOTION_MAX_V, rig.command_limit_v):g}] V")
        self.url, self.host, self.port = url, host, port
        self.rig, self.supply_pa, self.vertical_load_n = rig, supply_pa, vertical_load_n
        self.period_s, self.timeout_s = period_s, timeout_s
        self.motion, self.motion_v = motion, motion_v
        self.report = RigCheckReport(url, motion)
        self.figures = self.report.figures
        self.link: Link | None = None
        self.stream: Stream | None = None
        self.unsolicited: list[str] = []  # what an unarmed rig sent without being asked
        self.last_disarmed: int | None = None
        self.last_disarmed_arm = b""
        self.steady_miscount: list[int] = []
        self.watchdog_s: float | None = None

    # --- results ----------------------------------------------------------------------------------------
    def add(self, section: str, rule: str, ok: bool | None, figure: str = "", detail: str = "") -> bool | None:
        self.report.results.append(RuleResult(section, rule, ok, figure, detail))
        return ok

    def attempt(self, rules: list[tuple[str, str]], fn: Probe) -> None:
        """Run ``fn`` on the armed stream: one (ok, figure, detail) per rule. If the rig's watchdog interrupts it
        (this process was late) or the stream stops, arm a new session and run it again, up to TRIES times."""
        note = ""
        for attempt in range(TRIES):
            try:
                if self.stream is None or not self.stream.armed:
                    self._rearm()
                outcomes = fn(self.stream)
            except Disturbed as exc:
                note = str(exc)
                if self.stream is not None:
                    self.stream.disarm()
                self.stream = None
                continue
            for (section, rule), (ok, figure, detail) in zip(rules, outcomes, strict=True):
                if attempt:
                    detail = (detail + "; " if detail else "") + f"run {attempt + 1} times (before: {note})"
                self.add(section, rule, ok, figure, detail)
            return
        for section, rule in rules:
            self.add(section, rule, False, "", f"could not be checked in {TRIES} tries: {note}")

    def _rearm(self) -> None:
        self.stream = Stream(self)
        try:
            self.stream.arm(self.timeout_s)
        except Silent:
            raise RigUnreachable(f"the rig at {self.url} stopped accepting ARM ({self.supply_pa / 1e5:g} bar, "
                                 f"{self.vertical_load_n:g} N) in the middle of the check") from None
        self.stream.steady(5)

    # --- helpers ------------------------------------------------------------------------------------------
    def silent(self, seconds: float, label: str) -> list[Received]:
        """What arrives on the stream's socket within ``seconds`` (an unarmed rig must send nothing)."""
        got = []
        end = time.perf_counter() + seconds
        while (rec := self.link.receive(end)) is not None:
            got.append(rec)
        if got:
            self.unsolicited.append(f"{len(got)} measurement(s) {label}")
        return got

    def hello(self) -> Received:
        rec = self.link.hello(max(0.2, min(self.timeout_s, 1.0)))
        if rec is None:
            raise RigUnreachable(f"the rig at {self.url} stopped answering HELLO in the middle of the check")
        return rec

    # --- the check ----------------------------------------------------------------------------------------
    def run(self) -> RigCheckReport:
        """Every check, with this process at real-time priority for their duration, as the worker's loop runs: the
        rig's timings are measured here, and a host starved by ordinary processes would blame the rig."""
        with realtime_priority(CHECK_RR_PRIORITY):
            return self._run()

    def _run(self) -> RigCheckReport:
        gc_enabled = gc.isenabled()
        gc.disable()  # a collection in the middle of a probe would look like a late host to the rig's watchdog
        self.link = Link(self.host, self.port, self.security)
        try:
            self._hello_unarmed()  # RigUnreachable: nothing to check
            try:
                if self.link.codec.version == 2:
                    self._hello_without_key()
                    self._hello_rate()
                    self._hello_under_flood()
                self._refused_arms()
                self._main_session()
                self._finished_session()
                self._watchdog()
                self._stale_age()
                if self.motion:
                    self._motion()
            except RigUnreachable as exc:
                self.add("§8", "the check ran to its end", False, "", str(exc))
            self._link_rules()
        finally:
            if self.stream is not None and self.stream.armed:
                self.stream.disarm()
            self.link.close()
            if gc_enabled:
                gc.enable()
        return self.report

    def _hello_unarmed(self) -> None:
        t0 = time.perf_counter()
        rec = self.link.hello(self.timeout_s)
        if rec is None:
            if self.link.invalid:
                bad = ", ".join(f"{n} {reason}" for reason, n in self.link.invalid.items())
                raise RigUnreachable(f"{self.host}:{self.port} answers, but not with a valid packet of the isorig rig "
                                     f"protocol v{self.security.protocol_version} (dropped: {bad})")
            answer = hello_probe(self.url, timeout_s=0.2, security=self.security)
            detail = answer["detail"] if not answer["connected"] else "it answered only a later HELLO"
            raise RigUnreachable(f"no answer to HELLO from the rig at {self.url} within {self.timeout_s:g} s: {detail}")
        self.figures["hello_round_trip_ms"] = (rec.t - t0) * 1e3
        f = rec.packet.fields
        if rec.status & STATUS_ARMED:
            raise RigUnreachable(f"the rig at {self.url} is armed (session {rec.packet.session}): another test or "
                                 "move runs on it; check-rig needs an idle rig")
        problems = []
        if rec.packet.session != 0 or rec.seq != 0:
            problems.append(f"session {rec.packet.session} and sequence {rec.seq}, not 0 and 0")
        if f["period_ns"] <= 0:
            problems.append(f"period_ns {f['period_ns']}")
        if not all(math.isfinite(f[name]) for name in ("position_m", "force_n", "load_pressure_pa",
                                                        "supply_pressure_pa")):
            problems.append("a channel is not finite")
        self.hello_position_m = f["position_m"]
        self.add("§3.5", "HELLO answered unarmed: a measurement, session 0, sequence 0", not problems,
                 f"{(rec.t - t0) * 1e3:.2f} ms round trip, {rec.size} bytes", "; ".join(problems))

    # --- version 2 (section 9) ------------------------------------------------------------------------------------
    def _unanswered(self, datagrams: list[bytes], aux: bool = True) -> tuple[int, int]:
        """(answers within SILENCE_S, the rise of packets_rejected) for ``datagrams`` sent to an idle rig."""
        before = self.hello()["packets_rejected"]
        for data in datagrams:
            self.link.send(data, aux=aux)
        answers = 0
        end = time.perf_counter() + SILENCE_S
        while self.link.receive(end, aux=aux) is not None:
            answers += 1
        return answers, self.hello()["packets_rejected"] - before

    def _hello_without_key(self) -> None:
        wrong = self.link.codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns(), auth.new_nonce(),
                                       key=auth.new_nonce() * 2)
        answers, rose = self._unanswered([wrong])
        ok = answers == 0 and rose == 1
        self.add("§9.6", "drop auth: a HELLO without the key gets no answer (no session revealed)", ok,
                 f"{answers} answer(s), packets_rejected +{rose}",
                 "" if ok else "a HELLO with a wrong tag must be dropped in silence and counted once (auth)")

    def _hello_rate(self) -> None:
        time.sleep(HELLO_BURST / HELLO_RATE_PER_S)  # a full bucket
        before = self.hello()["packets_rejected"]
        time.sleep(HELLO_BURST / HELLO_RATE_PER_S)
        t0 = time.perf_counter()
        for _ in range(HELLO_BURST_SENT):
            self.link.send(self.link.hello_packet(), aux=True)
        sent_s = time.perf_counter() - t0
        answers = 0
        end = time.perf_counter() + SILENT_S  # every answer, however late this process reads them
        while self.link.receive(end, aux=True) is not None:
            answers += 1
        time.sleep(2 * HELLO_BURST / HELLO_RATE_PER_S)  # the bucket fills again for the rest of the check
        rose = self.hello()["packets_rejected"] - before
        most = 2 * (HELLO_BURST + HELLO_RATE_PER_S * sent_s) + 1
        problems = []
        if not 5 <= answers <= most:
            problems.append(f"{answers} of {HELLO_BURST_SENT} answered: at least 5 and at most {most:.0f} (a burst of "
                            f"{HELLO_BURST} and {HELLO_RATE_PER_S:g}/s, within a factor of 2)")
        if rose != HELLO_BURST_SENT - answers:
            problems.append(f"packets_rejected rose by {rose}, not the {HELLO_BURST_SENT - answers} unanswered (rate)")
        self.add("§9.6", f"HELLO's rate: a burst of {HELLO_BURST_SENT} answered in part, the rest counted (rate)",
                 not problems, f"{answers} answered, packets_rejected +{rose}", "; ".join(problems))

    def _hello_under_flood(self) -> None:
        """A flood of keyless HELLOs from another socket around the host's HELLO: answered all the same (9.6)."""
        before = self.hello()["packets_rejected"]
        junk = self.link.codec.encode(proto.HELLO, 0, 0, 0, auth.new_nonce(), key=auth.new_nonce() * 2)
        nonce = auth.new_nonce()
        with Link._socket() as flood:
            for i in range(2 * HELLO_FLOOD_SENT):
                if i == HELLO_FLOOD_SENT:
                    self.link.send(self.link.hello_packet(nonce), aux=True)
                flood.sendto(junk, self.link.addr)
            rec = self.link.receive(time.perf_counter() + SILENT_S, aux=True)
            answered = rec is not None and rec.packet.fields["nonce"] == nonce
            rose = self.hello()["packets_rejected"] - before
            junk_answered = len(select.select([flood], [], [], 0.0)[0])
        ok = answered and rose == 2 * HELLO_FLOOD_SENT and not junk_answered
        self.add("§9.6", f"HELLO under a flood: answered after {HELLO_FLOOD_SENT} keyless HELLOs from another socket, "
                 "the flood counted", ok, f"{'answered' if answered else 'no answer'}, packets_rejected +{rose}",
                 "" if ok else "a HELLO must be rated per source (address and port): a flood from others must not "
                 f"use up the host's HELLOs; every keyless one dropped and counted ({2 * HELLO_FLOOD_SENT})")

    def _replayed_arm(self, data: bytes) -> None:
        answers, rose = self._unanswered([data], aux=False)
        if answers:  # it armed: end that session, or the rules after this one would see it running
            Stream(self, int.from_bytes(data[8:12], "little")).disarm()
            self.link.challenge = None
        ok = answers == 0 and rose == 1
        self.add("§9.5", "drop challenge: a finished session's ARM sent again arms nothing", ok,
                 f"{answers} measurement(s), packets_rejected +{rose}",
                 "" if ok else "an ARM whose challenge was spent must be dropped in silence and counted (challenge)")

    def _refused_arms(self) -> None:
        rig = self.rig
        below = rig.min_supply_pa * 0.5 if rig.min_supply_pa > 0 else -1e5
        above_load = rig.max_vertical_load_n * 1.1 if rig.max_vertical_load_n > 0 else 1e3
        cases = [(f"supply {below / 1e5:g} bar", below, self.vertical_load_n),
                 (f"supply {rig.max_supply_pa * 1.1 / 1e5:g} bar", rig.max_supply_pa * 1.1, self.vertical_load_n),
                 ("supply NaN", math.nan, self.vertical_load_n),
                 ("vertical load -1 kN", self.supply_pa, -1e3),
                 (f"vertical load {above_load / 1e3:g} kN", self.supply_pa, above_load),
                 ("vertical load NaN", self.supply_pa, math.nan)]
        before = self.hello()["packets_rejected"]
        failures, total = [], 0
        for name, supply, load in cases:
            failure, counted, before = self._refused(_new_session(), supply, load, before)
            total += counted
            if failure:
                failures.append(f"{name}: {failure}")
        ranges = (f"supply [{rig.min_supply_pa / 1e5:g}, {rig.max_supply_pa / 1e5:g}] bar, vertical load "
                  f"[0, {rig.max_vertical_load_n / 1e3:g}] kN")
        self.add("§5", "drop arm: an ARM outside the rig's ranges, in silence", not failures,
                 f"{len(cases)} refused, packets_rejected +{total}", "; ".join(failures) or f"ranges: {ranges}")
        failure, counted, _ = self._refused(0, self.supply_pa, self.vertical_load_n, before)
        self.add("§3.2", "an ARM with session 0 is refused (arm), in silence", not failure,
                 f"packets_rejected +{counted}", failure)

    def _refused(self, session: int, supply: float, load: float, before: int) -> tuple[str, int, int]:
        """(what went wrong or '', the count it added, the count now) for an ARM the rig must refuse."""
        self.link.send(self.link.encode(proto.ARM, session, 0, time.perf_counter_ns(), supply, load))
        end = time.perf_counter() + SILENCE_S
        answered = []
        while (rec := self.link.receive(end)) is not None:
            answered.append(rec)
        if answered:
            self.link.challenge = None  # the rig armed: its challenge is spent
            Stream(self, session).disarm()
        answer = self.hello()
        now = answer["packets_rejected"]
        problems = []
        if answered:
            problems.append(f"the rig answered with {len(answered)} measurement(s) (it armed)")
        if answer.status & STATUS_ARMED:
            problems.append("a HELLO says it is armed")
        if now - before != 1:
            problems.append(f"packets_rejected rose by {now - before}, not 1")
        return "; ".join(problems), now - before, now

    def _main_session(self) -> None:
        stream = self.stream = Stream(self)
        try:
            first = stream.arm(self.timeout_s)
        except Silent:
            raise RigUnreachable(f"the rig at {self.url} answers HELLO but did not arm within {self.timeout_s:g} s "
                                 f"of ARM at {self.supply_pa / 1e5:g} bar and {self.vertical_load_n:g} N: are they "
                                 "within its ranges (--supply-bar, --vertical-load-n, --rig-file)?") from None
        stream.answer(first)
        self.figures["arm_to_first_measurement_ms"] = stream.first_ms
        f = first.packet.fields
        problems = [what for what, bad in (
            (f"sequence {first.seq}, not 0", first.seq != 0),
            ("not ARMED", not first.status & STATUS_ARMED),
            ("COMMAND_MISSED set", first.status & STATUS_COMMAND_MISSED),
            (f"counters not from zero (command_sequence {f['command_sequence']}, commands_missed "
             f"{f['commands_missed']}, packets_rejected {f['packets_rejected']})",
             f["command_sequence"] or f["commands_missed"] or f["packets_rejected"])) if bad]
        self.add("§3.1", "ARM accepted: measurement 0 of its session, armed, counters from zero", not problems,
                 f"{stream.first_ms:.1f} ms from ARM to measurement 0", "; ".join(problems))
        dy = f["position_m"] - self.hello_position_m
        self.add("§3.5", "HELLO reports the table's position", abs(dy) <= POSITION_AGREE_M,
                 f"{self.hello_position_m * 1e3:+.3f} mm (armed: {dy * 1e3:+.3f} mm from it)",
                 "" if abs(dy) <= POSITION_AGREE_M else f"more than {POSITION_AGREE_M * 1e3:g} mm apart at rest")
        self.attempt([("§1.1", "sequence +1 per period"),
                      ("§1.1", "period: period_ns, and measurements that far apart"),
                      ("§1.2", "command_sequence: the last command applied")], self._steady)
        self._command_rules()

    def _steady(self, s: Stream):
        """Sequence, period and command_sequence over STEADY_PERIODS periods answered at once with 0 V."""
        steady = s.steady(STEADY_PERIODS)
        steps = [b.seq - a.seq for a, b in zip(steady, steady[1:], strict=False)]
        back = sum(1 for step in steps if step <= 0)
        lost = sum(step - 1 for step in steps if step > 1)
        rows = [(back == 0 and lost <= 0.01 * len(steady), f"{len(steady)} measurements, {lost} lost, {back} repeated "
                 "or back", "" if back == 0 else "a sequence repeated or went backwards")]
        period_ns = steady[0]["period_ns"]
        gaps = [(b.t - a.t) for a, b in zip(steady, steady[1:], strict=False) if b.seq == a.seq + 1]
        median = statistics.median(gaps) if gaps else math.nan
        mean = (steady[-1].t - steady[0].t) / max(1, steady[-1].seq - steady[0].seq)
        self.figures.update(period_ns=period_ns, inter_arrival_median_ms=median * 1e3, inter_arrival_mean_ms=mean * 1e3)
        problems = []
        if abs(period_ns * 1e-9 - self.period_s) > 1e-9:
            problems.append(f"period_ns says {period_ns * 1e-6:g} ms; the host is set for {self.period_s * 1e3:g} ms "
                            "(--period-s, ISORIG_RIG_PERIOD_S): it refuses this rig at ARM")
        if not abs(median - self.period_s) <= 0.1 * self.period_s:
            problems.append("the median time between measurements is more than 10 % off period_ns")
        if not abs(mean - self.period_s) <= 0.2 * self.period_s:
            problems.append("the mean time between measurements is more than 20 % off period_ns")
        rows.append((not problems, f"period_ns {period_ns * 1e-6:g} ms; between measurements median "
                     f"{median * 1e3:.3f} ms, mean {mean * 1e3:.3f} ms", "; ".join(problems)))
        pairs = [(a, b) for a, b in zip(steady, steady[1:], strict=False) if b.seq == a.seq + 1]
        wrong_echo = [b.seq for a, b in pairs if (b.status & STATUS_COMMAND_MISSED and b["command_sequence"] >= a.seq)
                      or (not b.status & STATUS_COMMAND_MISSED and b["command_sequence"] != a.seq)]
        in_time = sum(1 for _, b in pairs if not b.status & STATUS_COMMAND_MISSED)
        rows.append((not wrong_echo, f"{in_time} of {len(pairs)} answered in time",
                     f"at sequence(s) {wrong_echo[:5]}: measurement n + 1 without COMMAND_MISSED must carry "
                     "command_sequence n, with it less than n" if wrong_echo else ""))
        self.steady_miscount = [b.seq for a, b in pairs if b["commands_missed"] - a["commands_missed"]
                                != (1 if b.status & STATUS_COMMAND_MISSED else 0)]
        return rows

    def _command_rules(self) -> None:
        self.attempt([("§1.3", "COMMAND_MISSED in n + 1 when n went unanswered, counted")], self._missed)
        self.attempt([("§1.4", "a late command (2 periods) is still applied")], self._late)
        self.attempt([("§3.5", "HELLO while armed: the session, latest sequence, counters")], self._hello_armed)
        self.attempt([("§3.2", "a repeated ARM of the running session is ignored")], self._repeated_arm)
        self.attempt([("§5", "drop busy: an ARM of another session while armed")], self._busy)
        limit = self.rig.command_limit_v
        v2 = self.link.codec.version == 2
        trailer = self.link.codec.trailer
        good = self._good
        seal = self.link.seal
        drops = [
            ("short", "fewer bytes than a header", lambda s, n: [good(s, n)[:20]], None),
            ("size", "not the size of its kind", lambda s, n: [seal(good(s, n)[:-trailer] + b"\0", s.session)], 0),
            ("magic", "another protocol", lambda s, n: [seal(b"ISRX" + good(s, n)[4:-trailer], s.session)], 0),
            ("version", "another version",
             lambda s, n: [seal(good(s, n)[:4] + struct.pack("<H", 1 if v2 else 2) + good(s, n)[6:-trailer],
                                s.session)], 0),
            ("kind", "an unknown kind, a MEASUREMENT to the rig",
             lambda s, n: [seal(good(s, n)[:6] + struct.pack("<H", 9) + good(s, n)[8:-trailer], s.session),
                           self.link.encode(proto.MEASUREMENT, s.session, n.seq, 0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0,
                                            0)],
             0),
            ("auth" if v2 else "crc", "damaged (a wrong tag), and tagged with another key" if v2 else "damaged",
             lambda s, n: [good(s, n)[:-4] + bytes(b ^ 0xFF for b in good(s, n)[-4:])]
             + ([self.link.encode(proto.COMMAND, s.session, n.seq, 0, 0.0, key=auth.new_nonce() * 2)] if v2 else []),
             0),
            ("session", "a COMMAND of another session",
             lambda s, n: [self.link.encode(proto.COMMAND, s.session ^ 0x5A5A5A5A, n.seq, 0, 0.0)], 0),
            ("future", "a COMMAND answering a measurement not sent yet",
             lambda s, n: [self.link.encode(proto.COMMAND, s.session, n.seq + 1000, 0, 0.0)], 1000),
            ("value", f"NaN, +-inf, +-{VALUE_FACTOR:g} x the {limit:g} V limit",
             lambda s, n: [self.link.encode(proto.COMMAND, s.session, n.seq, 0, v)
                           for v in (math.nan, math.inf, -math.inf, VALUE_FACTOR * limit, -VALUE_FACTOR * limit)], 0),
        ]
        if v2:
            drops.append(("address", "a COMMAND from another port than the ARM's",
                          lambda s, n: [(good(s, n), True)], 0))
        for reason, what, make, offset in drops:
            self.attempt([("§9.7" if reason in ("auth", "address") else "§5", f"drop {reason}: {what}")],
                       lambda s, make=make, offset=offset: [self._dropped(s, make, offset)])
        self.attempt([("§3.3", "a DISARM of another session is dropped, the test goes on")],
                   lambda s: [self._dropped(s, lambda s, n: [self.link.encode(proto.DISARM, s.session ^ 0x5A5A5A5A,
                                                                              0, 0)], None)])
        if v2:
            self.attempt([("§9.7", "drop auth: a DISARM tagged with another key, the test goes on")],
                         lambda s: [self._dropped(s, lambda s, n: [self.link.encode(proto.DISARM, s.session, 0, 0,
                                                                                    key=auth.new_nonce() * 2)], None)])
            self.attempt([("§9.1", "a HELLO without the key while armed: no answer, no session revealed")],
                         self._hello_without_key_armed)
        self.attempt([("§5", "drop stale: a duplicate, a command older than the one held")], self._stale)

    @staticmethod
    def _good(stream: Stream, rec: Received) -> bytes:
        return stream.link.encode(proto.COMMAND, stream.session, rec.seq, 0, 0.0)

    # --- probes on an armed stream: each returns [(ok, figure, detail)] -----------------------------------
    def _missed(self, s: Stream):
        s.steady(3)
        a = s.next()  # not answered
        b = s.next()
        s.answer(b)
        s.steady(2)
        problems = []
        if b.seq != a.seq + 1:
            problems.append(f"measurement {a.seq + 1} was lost")
        elif not b.status & STATUS_COMMAND_MISSED:
            problems.append(f"measurement {b.seq} does not carry COMMAND_MISSED though {a.seq} went unanswered")
        elif b["commands_missed"] != a["commands_missed"] + 1:
            problems.append(f"commands_missed went from {a['commands_missed']} to {b['commands_missed']}, not +1")
        if b["command_sequence"] >= a.seq:
            problems.append(f"command_sequence {b['command_sequence']} in {b.seq}: no command answered {a.seq}")
        if self.steady_miscount:
            problems.append(f"in the steady stream, commands_missed did not rise by exactly the COMMAND_MISSED flags "
                            f"at sequence(s) {self.steady_miscount[:5]}")
        return [(not problems, f"sequence {b.seq}: flag set, commands_missed {b['commands_missed']}",
                 "; ".join(problems))]

    def _late(self, s: Stream):
        s.steady(3)
        n = s.next()
        s.skip(1)
        s.on_time(s.next())  # the answer to n goes now, two periods late (late by more if this check was late)
        s.answer(n)
        after = []
        for _ in range(5):  # unanswered, until the rig reports it
            after.append(s.next())
            if after[-1]["command_sequence"] == n.seq:
                break
        s.answer(after[-1])
        s.steady(2)
        applied = after[-1]["command_sequence"] == n.seq
        return [(applied, f"answer to {n.seq} sent after {n.seq + 2}",
                 "" if applied else f"command_sequence never showed {n.seq}: "
                 f"{[x['command_sequence'] for x in after]} in {[x.seq for x in after]}")]

    def _hello_armed(self, s: Stream):
        s.steady(3)
        latest = s.last
        self.link.drain(aux=True)
        self.link.send(self.link.hello_packet(), aux=True)
        got = s.steady(3)
        rec = self.link.receive(time.perf_counter() + 0.1, aux=True)
        if rec is None:
            return [(False, "", "no answer to a HELLO sent while armed")]
        while got[-1].seq < rec.seq and len(got) < 30:  # the stream's measurement of the same sequence
            got += s.steady(1)
        problems = []
        if rec.packet.session != s.session:
            problems.append(f"session {rec.packet.session}, not the test's {s.session}")
        if not rec.status & STATUS_ARMED:
            problems.append("ARMED not set")
        same = [x for x in [latest, *got] if x.seq == rec.seq]
        if rec.seq < latest.seq or not same:
            problems.append(f"sequence {rec.seq}, not one of the stream's latest ({latest.seq} on)")
        elif same[0]["packets_rejected"] != rec["packets_rejected"]:
            problems.append(f"packets_rejected {rec['packets_rejected']}, the stream's {same[0]['packets_rejected']}")
        elif not 0 <= rec["commands_missed"] - same[0]["commands_missed"] <= 1:
            problems.append(f"commands_missed {rec['commands_missed']}, the stream's {same[0]['commands_missed']}")
        seqs = [latest.seq] + [x.seq for x in got]
        if any(b != a + 1 for a, b in zip(seqs, seqs[1:], strict=False)):
            problems.append(f"the stream's sequences around it: {seqs[:8]} (the answer goes to the HELLO's sender "
                            "only)")
        return [(not problems, f"sequence {rec.seq} (latest {latest.seq})", "; ".join(problems))]

    def _hello_without_key_armed(self, s: Stream):
        s.steady(3)
        n = s.last
        self.link.drain(aux=True)
        self.link.send(self.link.codec.encode(proto.HELLO, 0, 0, time.perf_counter_ns(), auth.new_nonce(),
                                              key=auth.new_nonce() * 2), aux=True)
        got = s.sync()
        answered = self.link.drain(aux=True)
        rose = got[-1]["packets_rejected"] - n["packets_rejected"] if got else 0
        problems = ([f"{len(answered)} answer(s) to it"] if answered else []) + \
            ([f"packets_rejected rose by {rose}, not 1"] if rose != 1 else [])
        return [(not problems, f"{len(answered)} answers, packets_rejected +{rose}", "; ".join(problems))]

    def _repeated_arm(self, s: Stream):
        s.steady(3)
        n = s.last
        self.link.send(s.arm_data)  # the host repeats its ARM (version 2: the same challenge)
        got = s.sync()
        problems = []
        if not got:
            problems.append("no command applied after it")
        elif any(x.seq <= n.seq for x in got):
            problems.append(f"the sequence started again: {[x.seq for x in got]} after {n.seq}")
        elif got[-1]["packets_rejected"] != n["packets_rejected"]:
            problems.append(f"counted as dropped (packets_rejected {n['packets_rejected']} -> "
                            f"{got[-1]['packets_rejected']})")
        return [(not problems, f"sequence {got[0].seq if got else '?'} after {n.seq}", "; ".join(problems))]

    def _busy(self, s: Stream):
        s.steady(3)
        n = s.last
        other = _new_session()
        foreign = s.foreign
        self.link.send(self.link.encode(proto.ARM, other, 0, time.perf_counter_ns(), self.supply_pa,
                                    self.vertical_load_n))
        try:
            got = s.sync()
        except Silent:
            Stream(self, other).disarm()
            s.armed = False
            return [(False, "", "the stream of the running test stopped: the rig took the other session")]
        problems = []
        if s.foreign != foreign:
            Stream(self, other).disarm()
            problems.append("measurements of the other session arrived")
        if not got:
            problems.append("no command of the running test applied after it")
        elif any(x.seq <= n.seq for x in got):
            problems.append(f"the sequence started again: {[x.seq for x in got]} after {n.seq}")
        rose = got[-1]["packets_rejected"] - n["packets_rejected"] if got else 0
        if rose != 1:
            problems.append(f"packets_rejected rose by {rose}, not 1")
        return [(not problems, f"packets_rejected +{rose}, the test goes on", "; ".join(problems))]

    def _dropped(self, s: Stream, make, offset: int | None) -> tuple[bool, str, str]:
        """Datagrams sent in place of the answer to measurement n: each counted once, none applied (no
        ``command_sequence`` n + ``offset``), the stream goes on and the next valid command is applied."""
        s.steady(3)
        n = s.next()
        datagrams = make(s, n)
        for data in datagrams:  # (data, True): from the HELLO socket, another port than the ARM's
            self.link.send(*data) if isinstance(data, tuple) else self.link.send(data)
        try:
            seen = s.skip(2) + s.sync()
        except Silent:
            s.armed = False
            return False, "", "the rig stopped sending after it"
        problems = []
        if offset is not None:
            applied = [x.seq for x in seen if x["command_sequence"] == n.seq + offset]
            if applied:
                problems.append(f"applied: command_sequence {n.seq + offset} in measurement {applied[0]}")
        if len(seen) == 2:
            return False, "", "; ".join(problems + ["the next valid command was not applied"])
        rose = seen[-1]["packets_rejected"] - n["packets_rejected"]
        if rose != len(datagrams):
            problems.append(f"packets_rejected rose by {rose}, not {len(datagrams)}")
        return not problems, f"packets_rejected +{rose}", "; ".join(problems)

    def _stale(self, s: Stream):
        s.steady(3)
        n = s.next()
        good = s.answer(n)
        self.link.send(good)  # a duplicate
        self.link.send(self.link.encode(proto.COMMAND, s.session, n.seq - 2, 0, 0.0))  # older than the one held
        after = s.sync()
        if not after:
            return [(False, "", "no valid command applied after them")]
        rose = after[-1]["packets_rejected"] - n["packets_rejected"]
        problems = []
        if rose != 2:
            problems.append(f"packets_rejected rose by {rose}, not 2")
        if any(b["command_sequence"] < a["command_sequence"] for a, b in zip(after, after[1:], strict=False)):
            problems.append("command_sequence went backwards")
        return [(not problems, f"packets_rejected +{rose}", "; ".join(problems))]

# --- the end of a test ----------------------------------------------------------------------------------
    def _finished_session(self) -> None:
        self.attempt([("§3.4", "DISARM: the stream stops, nothing more is sent"),
                    ("§1.7", "unarmed: a COMMAND is dropped and counted, nothing is sent")], self._disarm)
        if self.link.codec.version == 2 and self.last_disarmed_arm:
            self._replayed_arm(self.last_disarmed_arm)
        if self.last_disarmed is None:
            self.add("§3.2", "an ARM of a finished session starts it anew, at sequence 0", False, "",
                     "not checked: no session was disarmed")
            return
        stream = Stream(self, self.last_disarmed)
        try:
            first = stream.arm(0.5)
            stream.answer(first)
            stream.steady(3)
            ok = first.seq == 0 and bool(first.status & STATUS_ARMED)
            self.add("§3.2", "an ARM of a finished session starts it anew, at sequence 0", ok,
                     f"measurement {first.seq}", "" if ok else "it did not start at sequence 0")
        except Disturbed as exc:
            self.add("§3.2", "an ARM of a finished session starts it anew, at sequence 0", False, "",
                     f"no measurement after it: {exc}")
        finally:
            stream.disarm()
        self.stream = None

    def _disarm(self, s: Stream):
        s.steady(5)
        while (rec := self.link.receive(0.0)) is not None:  # what was queued before the DISARM
            s.last = rec
            s.answer(rec)
        last = s.last
        self.link.send(self.link.encode(proto.DISARM, s.session, 0, time.perf_counter_ns()))
        s.armed = False
        self.stream = None
        self.last_disarmed = s.session
        self.last_disarmed_arm = s.arm_data
        flight = []
        end = time.perf_counter() + 2 * SILENCE_S
        while (rec := self.link.receive(end)) is not None:
            flight.append(rec)
        ours = [x for x in flight if x.packet.session == s.session]
        problems = []
        if len(ours) > 2 or any(x.seq > last.seq + 2 for x in ours):
            problems.append(f"{len(ours)} measurement(s) after DISARM (sequences up to {max(x.seq for x in ours)})")
        answer = self.hello()
        if answer.status & STATUS_ARMED or answer.packet.session != 0 or answer.seq != 0:
            problems.append(f"a HELLO after it: status {answer.status:#x}, session {answer.packet.session}, "
                            f"sequence {answer.seq} (must be unarmed, 0, 0)")
        before = answer["packets_rejected"]
        for _ in range(2):  # the host sends DISARM three times
            self.link.send(self.link.encode(proto.DISARM, s.session, 0, time.perf_counter_ns()))
        self.link.send(self.link.encode(proto.COMMAND, s.session, last.seq + 1, 0, 0.0))
        unasked = self.silent(SILENCE_S, "while unarmed, after a COMMAND")
        rose = self.hello()["packets_rejected"] - before
        unarmed = []
        if rose != 1:
            unarmed.append(f"two repeated DISARMs and one COMMAND raised packets_rejected by {rose}, not 1 (the "
                           "DISARMs of the finished session are ignored, the COMMAND is dropped as session)")
        if unasked or self.unsolicited:
            unarmed.append("; ".join(self.unsolicited))
        return [(not problems, f"{len(ours)} measurement(s) in flight, then silence", "; ".join(problems)),
                (not unarmed, f"packets_rejected +{rose}", "; ".join(unarmed))]

    # --- the watchdog -----------------------------------------------------------------------------------------
    def _watchdog(self) -> None:
        lower = WATCHDOG_MIN_S - 0.0005
        upper = WATCHDOG_MAX_S + self.period_s + WATCHDOG_TOLERANCE_S
        bounds = f"[{lower * 1e3:g}, {upper * 1e3:g}] ms"
        ways = (("last command", "watchdog: 0 V and a last measurement 10-20 ms after the last command"),
                ("ARM", "watchdog starts at ARM (no command at all)"),
                ("stale commands", "a stale command does not feed the watchdog"))
        final_problems, n_trips = [], 0
        for since, rule in ways:
            trips, problems = [], []
            for _ in range(WATCHDOG_TRIPS):
                figure, found = self._watchdog_trip(since)
                trips.append(figure)
                problems += found
                if figure is None:
                    break  # no watchdog: once is enough
            measured = [t for t in trips if t is not None]
            n_trips += len(measured)
            median = statistics.median(measured) if len(measured) == len(trips) else None
            self.figures[f"watchdog_after_{since.replace(' ', '_')}_ms"] = [None if t is None else t * 1e3
                                                                            for t in trips]
            if since == "last command":
                self.watchdog_s = median
            listed = ", ".join("none" if t is None else f"{t * 1e3:.1f}" for t in trips)
            ok = median is not None and lower <= median <= upper
            self.add("§1.5", rule, ok, f"median {median * 1e3:.1f} ms ({listed})" if median is not None else "",
                     "" if ok else (f"{problems[0]}; " if problems and median is None else "")
                     + f"must be within {bounds} of the {since} (10-20 ms, plus the link and one period)")
            final_problems += [p for p in problems if "still armed" not in p]
            if median is None and any("still armed" in p for p in problems):
                self.watchdog_s = None
        self.add("§1.5", "watchdog's last measurement: session, last + 1, WATCHDOG, then silence",
                 not final_problems and self.watchdog_s is not None, f"{n_trips} trips",
                 "; ".join(dict.fromkeys(final_problems)) or ("" if self.watchdog_s is not None else
                                                              "no last measurement: the rig never tripped"))

    def _watchdog_trip(self, since: str) -> tuple[float | None, list[str]]:
        """(seconds from the last valid command, or the ARM, to the WATCHDOG measurement, or None; what was
        wrong). Commands stop at ``since``: "last command", "ARM", or "stale commands" (duplicates and old
        ones go on)."""
        for _attempt in range(TRIES):
            stream = Stream(self)
            try:
                first = stream.arm(self.timeout_s)
                if since != "ARM":
                    stream.answer(first)
                    stream.steady(20)
            except Disturbed:
                stream.disarm()  # this check was late and the watchdog took it: again
                continue
            start = stream.arm_sent_t if since == "ARM" else stream.last_answer_t
            kept, prev = stream.last_answer_data, stream.last
            try:
                while True:
                    if time.perf_counter() - start > WATCHDOG_GIVE_UP_S:
                        stream.disarm()
                        return None, [f"still armed {WATCHDOG_GIVE_UP_S * 1e3:g} ms after the {since}: no watchdog"]
                    prev = stream.next()
                    if since == "stale commands":
                        self.link.send(kept)  # a duplicate of the last valid command
                        self.link.send(self.link.encode(proto.COMMAND, stream.session, 0, 0, 0.0))  # an old one
            except Tripped as exc:
                final = exc.rec
            except Silent as exc:
                stream.disarm()
                return None, [f"the stream stopped without a WATCHDOG measurement ({exc})"]
            problems = []
            if not final.status & STATUS_WATCHDOG:
                problems.append(f"the last measurement lacks WATCHDOG (status {final.status:#x})")
            if not final.status & STATUS_COMMAND_MISSED:
                problems.append("the last measurement lacks COMMAND_MISSED")
            if final.seq != prev.seq + 1:
                problems.append(f"the last measurement has sequence {final.seq}, not {prev.seq + 1}")
            after = self.silent(SILENCE_S, "after the WATCHDOG measurement")
            if after:
                problems.append(f"{len(after)} measurement(s) after the WATCHDOG one")
            answer = self.hello()
            if answer.status & STATUS_ARMED or not answer.status & STATUS_WATCHDOG or answer.packet.session != 0:
                problems.append(f"a HELLO after it: status {answer.status:#x}, session {answer.packet.session} "
                                "(must be unarmed, WATCHDOG kept until the next ARM, session 0)")
            return final.t - final.late_s - start, problems  # as if read at once: this process's lateness aside
        return None, [f"this check was late {TRIES} times before the watchdog could be timed"]

    def _stale_age(self) -> None:
        needed = (STALE_PERIODS + 3) * self.period_s + 0.003
        rule = f"drop stale: a command more than {STALE_PERIODS} periods old"
        if self.watchdog_s is not None and self.watchdog_s < needed:
            self.add("§5", rule, None, "", f"not checked: the rig's watchdog ({self.watchdog_s * 1e3:.1f} ms) would "
                     f"trip in the {STALE_PERIODS + 3} periods without a command it takes")
            return
        self.attempt([("§5", rule)], self._old_command)
        if self.stream is not None:
            self.stream.disarm()
            self.stream = None

    def _old_command(self, s: Stream):
        s.steady(3)
        n0 = s.last
        held = s.skip(STALE_PERIODS + 2)
        target = held[0]  # the rig has sent held[-1] = target + 11 at least: more than 10 periods old
        self.link.send(self.link.encode(proto.COMMAND, s.session, target.seq, 0, 0.0))
        after = s.sync()
        problems = []
        if any(x["command_sequence"] == target.seq for x in after):
            problems.append(f"applied: command_sequence {target.seq}")
        if not after:
            problems.append("no valid command applied after it")
        rose = after[-1]["packets_rejected"] - n0["packets_rejected"] if after else 0
        if rose != 1:
            problems.append(f"packets_rejected rose by {rose}, not 1")
        return [(not problems, f"{held[-1].seq - target.seq}+ periods old, packets_rejected +{rose}",
                 "; ".join(problems))]

# --- motion -----------------------------------------------------------------------------------------------
    def _motion(self) -> None:
        rules = [("§1.2", f"a command of +-{self.motion_v:g} V moves the table towards +-y"),
                 ("§4.2", "load_pressure_pa is positive pushing towards +y"),
                 ("§4.2", "force_n: the specimen's, of the displacement's sign"),
                 ("§3.5", "HELLO reports the position after the table moved")]
        self.attempt(rules, self._move)

    def _push(self, s: Stream, command_v: float, y0: float, until) -> tuple[list[Received], bool]:
        """``command_v`` each period until ``until(y)`` (or 150 periods), 0 V at once beyond MOTION_STOP_M."""
        pushed, stopped = [], False
        for _ in range(150):
            rec = s.next()
            y = rec["position_m"]
            if abs(y - y0) > MOTION_STOP_M or not math.isfinite(y):
                s.answer(rec, 0.0)
                stopped = True
                break
            if until(y):
                s.answer(rec, 0.0)
                break
            s.answer(rec, command_v)
            pushed.append(rec)
        return pushed, stopped

    def _move(self, s: Stream):
        rest = s.steady(MOTION_REST_PERIODS + 10)[-MOTION_REST_PERIODS:]
        y0 = statistics.fmean(x["position_m"] for x in rest)
        f0 = statistics.fmean(x["force_n"] for x in rest)
        up, stop_up = self._push(s, self.motion_v, y0, lambda y: y - y0 >= MOTION_STEP_M)
        settled = s.steady(40)
        y1 = statistics.fmean(x["position_m"] for x in settled[-5:])
        f1 = statistics.fmean(x["force_n"] for x in settled[-5:])
        coast = max(0.0, y1 - y0 - MOTION_STEP_M)  # how far the table ran on after 0 V: stop back that much early
        down, stop_down = self._push(s, -self.motion_v, y0, lambda y: y <= y0 + coast)
        back = s.steady(40)
        y2 = statistics.fmean(x["position_m"] for x in back[-5:])
        last_y = back[-1]["position_m"]
        s.disarm()
        self.stream = None
        answer = self.hello()
        moved_up, moved_back = y1 - y0, y2 - y1
        self.figures["motion"] = {"up_m": moved_up, "back_m": moved_back, "up_ms": len(up) * self.period_s * 1e3}
        stopped = " (stopped at once: beyond 1 mm)" if stop_up or stop_down else ""
        direction = (moved_up >= 0.05e-3 and moved_back <= -0.05e-3,
                     f"{moved_up * 1e3:+.3f} mm in {len(up) * self.period_s * 1e3:.0f} ms at {self.motion_v:+g} V, "
                     f"{moved_back * 1e3:+.3f} mm at {-self.motion_v:+g} V{stopped}",
                     "" if moved_up > 0 and moved_back < 0 else "the table moved against the command (or not at all: "
                     "a dead zone wider than --motion-v?)")
        pressure = self._pressure_rule(rest, up, settled[-MOTION_REST_PERIODS:], down)
        df = f1 - f0
        self.figures["motion"]["force_change_n"] = df
        force_ok = df * moved_up > 0
        force = (force_ok, f"{df / 1e3:+.3f} kN for {moved_up * 1e3:+.3f} mm",
                 "" if force_ok else "force_n must rise with the displacement (the specimen's force, positive when "
                 "it is deformed towards +y)")
        dy = answer["position_m"] - last_y
        follows = (abs(dy) <= HELLO_FOLLOW_M, f"{answer['position_m'] * 1e3:+.3f} mm ({dy * 1e3:+.3f} mm from the "
                   "last measurement)", "" if abs(dy) <= HELLO_FOLLOW_M else "the HELLO's position is not the table's")
        return [direction, pressure, force, follows]

    def _pressure_rule(self, rest_up: list[Received], up: list[Received], rest_down: list[Received],
                       down: list[Received]) -> tuple[bool, str, str]:
        """Section 4.2: the mean load pressure over each push, from its rest just before (``pressure_change``),
        rises pushing towards +y and falls pushing towards -y, each beyond the noise."""
        def readings(recs):
            return [x["load_pressure_pa"] for x in recs]

        up_pa, up_min_pa = pressure_change(readings(rest_up), readings(up))
        down_pa, down_min_pa = pressure_change(readings(rest_down), readings(down))
        self.figures["motion"]["pressure_change_pa"] = {"up": up_pa, "down": down_pa, "up_min": up_min_pa,
                                                         "down_min": down_min_pa}
        figure = (f"{up_pa / 1e5:+.2f} bar pushing +y, {down_pa / 1e5:+.2f} bar pushing -y (mean change from the "
                  f"rest before; at least {up_min_pa / 1e5:.2f}, {down_min_pa / 1e5:.2f} bar)")
        rose, fell = up_pa >= up_min_pa, -down_pa >= down_min_pa  # False on NaN
        if rose and fell:
            return True, figure, ""
        if up_pa <= -up_min_pa and down_pa >= down_min_pa:
            why = ("P_L fell pushing towards +y and rose pushing towards -y: its sign is inverted (P_L = P_A - P_B, "
                   "positive when it pushes the table towards +y)")
        elif not (math.isfinite(up_pa) and math.isfinite(down_pa)):
            why = "no reading of a push to judge (the table did not move, or was stopped at once)"
        elif abs(up_pa) < up_min_pa and abs(down_pa) < down_min_pa:
            why = "P_L did not change beyond its noise while the valve pushed the table: is the channel P_A - P_B?"
        else:
            why = "P_L must rise while the valve pushes the table towards +y and fall while it pushes towards -y"
        return False, figure, why

    # --- the link ---------------------------------------------------------------------------------------------
    def _link_rules(self) -> None:
        link = self.link
        wrong = ", ".join(f"{ip}:{port}" for ip, port in sorted(link.wrong_sources))
        self.add("§2", "replies come from the address and port the host sent to", not wrong,
                 f"{link.addr[0]}:{link.addr[1]}", f"replies from {wrong}: a host's connected socket never sees them"
                 if wrong else "")
        bad = sum(link.invalid.values())
        size = self.link.codec.sizes[proto.MEASUREMENT]
        check = "CRC" if self.link.codec.version == 1 else "tag"
        self.add("§4", f"every datagram from the rig is a valid MEASUREMENT ({size} bytes, {check})", not bad,
                 f"{link.received} received, {bad} invalid",
                 ", ".join(f"{n} {reason}" for reason, n in link.invalid.items()))


CHECK_RR_PRIORITY = 10  # the worker's: the host's side of the loop (sim.realtime)


def check_rig(url: str, **options) -> RigCheckReport:
    """Check the rig at ``udp://HOST:PORT`` (see the module docstring and ``RigCheck`` for the options);
    ``RigUnreachable`` if nothing usable answers."""
    return RigCheck(url, **options).run()
