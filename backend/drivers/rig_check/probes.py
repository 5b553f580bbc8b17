"""The probes of ``isorig check-rig``: what is sent to the rig, when, and what came back. Each probe returns a
measurement (the dataclasses here) and judges nothing: the rules (rules.py) do. ``PROBES`` names them; a probe
``on_stream`` runs on an armed session and is run again on a new one when the rig's watchdog interrupts it.

Every command a probe sends is 0.0 V, except the ones a conforming rig must refuse (``DROPS``: NaN, infinite,
1.2 x the command limit: never applied), and, in ``move``, +-``motion_v`` until the table has moved 0.3 mm
(stopped at once beyond 1 mm). ARMs outside the rig's ranges are sent too: a conforming rig refuses them.
"""

from __future__ import annotations

import math
import select
import statistics
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.measurement import STATUS_ARMED

from ..udp import probe as hello_probe
from .link import SILENT_S, Disturbed, Link, Received, RigUnreachable, Silent, Stream, Tripped, new_session

if TYPE_CHECKING:
    from .check import RigCheck

TRIES = 3  # a probe the rig's watchdog interrupts (this process was late) is run this many times at most
SILENCE_S = 0.05  # a refused ARM, a disarmed rig: nothing may arrive for this long
STEADY_PERIODS = 500
STALE_PERIODS = 10  # section 5
VALUE_FACTOR = 1.2  # a command this far beyond the limit must be refused
WATCHDOG_GIVE_UP_S = 0.3  # still armed this long after the last command: the rig has no watchdog
WATCHDOG_TRIPS = 3  # the figure is their median: one late wake-up of a shared machine does not decide it
RIG_STALL_S = 0.002  # a trip in whose window the rig overran this long (its clock) is timed again ...
STALL_TRIES = 6  # ... this many times at most
WATCHDOG_WAYS = ("last command", "ARM", "stale commands")  # what the watchdog's time runs from
HELLO_BURST_SENT = 40  # version 2: HELLOs sent at once to see the rate limit (section 9.6) ...
HELLO_BURST, HELLO_RATE_PER_S = 10, 100.0  # ... which answers about this many at once and per second
HELLO_FLOOD_SENT = 30  # version 2: keyless HELLOs from a third socket before the host's HELLO, and as many after
MOTION_STEP_M = 0.3e-3  # --motion: how far the table is pushed
MOTION_STOP_M = 1e-3  # ... and where the command goes to 0 V at once
MOTION_REST_PERIODS = 20  # readings at rest before each push: the load pressure's level and noise there
MOTION_PRESSURE_MIN_PA = 0.1e5  # a push changes the mean load pressure by at least this much ...
MOTION_PRESSURE_SIGMAS = 4.0  # ... and by this many standard errors of the reading's noise (seen at rest)


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


# --- the measurements -------------------------------------------------------------------------------------------
@dataclass
class Answered:
    """A measurement ``rec`` and how long after the probe's start it arrived."""

    rec: Received
    after_s: float


@dataclass
class Unanswered:
    """Datagrams sent to an idle rig: answers to them within SILENCE_S, the rise of packets_rejected."""

    answers: int
    rejected: int


@dataclass
class HelloRate:
    answers: int  # of HELLO_BURST_SENT sent at once
    rejected: int
    sent_s: float  # how long sending them took


@dataclass
class HelloFlood:
    answered: bool  # the host's HELLO, sent in the middle of 2 x HELLO_FLOOD_SENT keyless ones from another socket
    rejected: int
    flood_answered: int  # answers to the keyless ones


@dataclass
class Refusal:
    """An ARM the rig must refuse: measurements in answer, whether a HELLO then says armed, the rise of
    packets_rejected."""

    answered: int
    armed: bool
    rejected: int


@dataclass
class RefusedArms:
    outside: list[tuple[str, Refusal]]  # ARMs outside the rig's ranges, by name
    session_0: Refusal


@dataclass
class Steady:
    recs: list[Received]  # STEADY_PERIODS measurements answered at once with 0 V
    median_s: float  # the time between consecutive ones
    mean_s: float


@dataclass
class Pair:
    """Measurement n left unanswered, and n + 1."""

    n: Received
    next: Received


@dataclass
class Late:
    n: Received  # answered after n + 2 had arrived
    after: list[Received]  # from then until command_sequence showed n (5 at most)


@dataclass
class HelloArmed:
    session: int
    latest: Received  # the stream's latest measurement when the HELLO was sent
    got: list[Received]  # the stream's measurements after it
    answer: Received | None


@dataclass
class Synced:
    """Sent something instead of or besides the answer to measurement ``n``; ``after``: the measurements until the
    rig reported a valid command after it applied ([]: never; None: the stream stopped)."""

    n: Received
    after: list[Received] | None
    answers: int = 0  # answers to what was sent (a HELLO)
    foreign: bool = False  # measurements of another session arrived (an ARM of another session)


@dataclass
class Dropped:
    """Datagrams sent in place of the answer to ``n``; ``seen``: the measurements after them, the last one showing
    the next valid command applied (only 2: never; None: the stream stopped)."""

    n: Received
    seen: list[Received] | None
    sent: int
    applied_if: int | None  # the command_sequence that would show a sent command applied (None: no command)


@dataclass
class Disarmed:
    last: Received  # the last measurement before the DISARM
    ours: list[Received]  # the session's measurements after it
    hello: Received  # a HELLO's answer after it
    rejected: int  # the rise of packets_rejected for 2 repeated DISARMs and a COMMAND, unarmed
    unsolicited: list[str]  # what the unarmed rig sent unasked


@dataclass
class Anew:
    """An ARM of the session last disarmed: its first measurement, or why there is none."""

    first: Received | None
    why: str = ""


@dataclass
class Trip:
    """One trip of the watchdog: seconds from the last valid command (or the ARM) to the WATCHDOG measurement,
    as if read at once; None, and why, if none came."""

    seconds: float | None
    why: str = ""
    no_watchdog: bool = False  # still armed WATCHDOG_GIVE_UP_S after it
    final: Received | None = None  # the measurement without ARMED
    previous: Received | None = None  # the one before it
    after: int = 0  # measurements after it, within SILENCE_S
    hello: Received | None = None  # a HELLO's answer after it


@dataclass
class OldCommand:
    n: Received  # the last measurement answered
    target: Received  # the one answered STALE_PERIODS + 2 measurements late
    newest: Received  # the rig's latest when that answer went
    after: list[Received]


@dataclass
class Motion:
    """``move``: the table pushed +MOTION_STEP_M and back, what it read, and a HELLO's answer after."""

    up: list[Received]
    down: list[Received]
    stopped: bool  # beyond MOTION_STOP_M: the command went to 0 V at once
    moved_up_m: float
    moved_back_m: float
    force_change_n: float  # at rest after the push towards +y, less before it
    pressure_pa: dict  # pressure_change over each push: up, down, and their up_min, down_min
    last_position_m: float
    hello: Received


@dataclass
class LinkSeen:
    addr: tuple
    wrong_sources: set
    received: int
    invalid: dict[str, int]


# --- the probes -------------------------------------------------------------------------------------------------
def hello_unarmed(rc: RigCheck) -> Answered:
    """A HELLO to the idle rig; ``RigUnreachable`` if nothing usable answers or the rig is armed."""
    t0 = time.perf_counter()
    rec = rc.link.hello(rc.timeout_s)
    if rec is None:
        if rc.link.invalid:
            bad = ", ".join(f"{n} {reason}" for reason, n in rc.link.invalid.items())
            raise RigUnreachable(f"{rc.host}:{rc.port} answers, but not with a valid packet of the isorig rig "
                                 f"protocol v{rc.security.protocol_version} (dropped: {bad})")
        answer = hello_probe(rc.url, timeout_s=0.2, security=rc.security)
        detail = answer["detail"] if not answer["connected"] else "it answered only a later HELLO"
        raise RigUnreachable(f"no answer to HELLO from the rig at {rc.url} within {rc.timeout_s:g} s: {detail}")
    rc.figures["hello_round_trip_ms"] = (rec.t - t0) * 1e3
    if rec.status & STATUS_ARMED:
        raise RigUnreachable(f"the rig at {rc.url} is armed (session {rec.packet.session}): another test or "
                             "move runs on it; check-rig needs an idle rig")
    return Answered(rec, rec.t - t0)


def unanswered(rc: RigCheck, datagrams: list[bytes], aux: bool = True) -> Unanswered:
    """``datagrams`` sent to an idle rig (from the HELLO socket, or the stream's)."""
    before = rc.hello()["packets_rejected"]
    for data in datagrams:
        rc.link.send(data, aux=aux)
    answers = 0
    end = time.perf_counter() + SILENCE_S
    while rc.link.receive(end, aux=aux) is not None:
        answers += 1
    return Unanswered(answers, rc.hello()["packets_rejected"] - before)


def _keyless_hello(rc: RigCheck, time_ns: int) -> bytes:
    return rc.link.codec.encode(proto.HELLO, 0, 0, time_ns, auth.new_nonce(), key=auth.new_nonce() * 2)


def hello_without_key(rc: RigCheck) -> Unanswered:
    return unanswered(rc, [_keyless_hello(rc, time.perf_counter_ns())])


def hello_rate(rc: RigCheck) -> HelloRate:
    """HELLO_BURST_SENT HELLOs at once to a rig whose bucket is full."""
    time.sleep(HELLO_BURST / HELLO_RATE_PER_S)  # a full bucket
    before = rc.hello()["packets_rejected"]
    time.sleep(HELLO_BURST / HELLO_RATE_PER_S)
    t0 = time.perf_counter()
    for _ in range(HELLO_BURST_SENT):
        rc.link.send(rc.link.hello_packet(), aux=True)
    sent_s = time.perf_counter() - t0
    answers = 0
    end = time.perf_counter() + SILENT_S  # every answer, however late this process reads them
    while rc.link.receive(end, aux=True) is not None:
        answers += 1
    time.sleep(2 * HELLO_BURST / HELLO_RATE_PER_S)  # the bucket fills again for the rest of the check
    return HelloRate(answers, rc.hello()["packets_rejected"] - before, sent_s)


def hello_under_flood(rc: RigCheck) -> HelloFlood:
    """The host's HELLO between two floods of HELLO_FLOOD_SENT keyless HELLOs from another socket."""
    before = rc.hello()["packets_rejected"]
    junk = _keyless_hello(rc, 0)
    nonce = auth.new_nonce()
    with Link._socket() as flood:
        for i in range(2 * HELLO_FLOOD_SENT):
            if i == HELLO_FLOOD_SENT:
                rc.link.send(rc.link.hello_packet(nonce), aux=True)
            flood.sendto(junk, rc.link.addr)
        rec = rc.link.receive(time.perf_counter() + SILENT_S, aux=True)
        answered = rec is not None and rec.packet.fields["nonce"] == nonce
        rose = rc.hello()["packets_rejected"] - before
        flood_answered = len(select.select([flood], [], [], 0.0)[0])
    return HelloFlood(answered, rose, flood_answered)


def refused_arms(rc: RigCheck) -> RefusedArms:
    """ARMs just outside the rig's ranges (and NaN), then one with session 0."""
    rig = rc.rig
    below = rig.min_supply_pa * 0.5 if rig.min_supply_pa > 0 else -1e5
    above_load = rig.max_vertical_load_n * 1.1 if rig.max_vertical_load_n > 0 else 1e3
    cases = [(f"supply {below / 1e5:g} bar", below, rc.vertical_load_n),
             (f"supply {rig.max_supply_pa * 1.1 / 1e5:g} bar", rig.max_supply_pa * 1.1, rc.vertical_load_n),
             ("supply NaN", math.nan, rc.vertical_load_n),
             ("vertical load -1 kN", rc.supply_pa, -1e3),
             (f"vertical load {above_load / 1e3:g} kN", rc.supply_pa, above_load),
             ("vertical load NaN", rc.supply_pa, math.nan)]
    before = rc.hello()["packets_rejected"]
    outside = []
    for name, supply, load in cases:
        refusal, before = refused(rc, new_session(), supply, load, before)
        outside.append((name, refusal))
    return RefusedArms(outside, refused(rc, 0, rc.supply_pa, rc.vertical_load_n, before)[0])


def refused(rc: RigCheck, session: int, supply: float, load: float, before: int) -> tuple[Refusal, int]:
    """(what an ARM the rig must refuse got, packets_rejected now)."""
    rc.link.send(rc.link.encode(proto.ARM, session, 0, time.perf_counter_ns(), supply, load))
    end = time.perf_counter() + SILENCE_S
    answered = 0
    while rc.link.receive(end) is not None:
        answered += 1
    if answered:
        rc.link.challenge = None  # the rig armed: its challenge is spent
        Stream(rc, session).disarm()
    answer = rc.hello()
    now = answer["packets_rejected"]
    return Refusal(answered, bool(answer.status & STATUS_ARMED), now - before), now


def main_arm(rc: RigCheck) -> Answered:
    """The ARM of the main session (``rc.stream``, left armed for the probes after it), its measurement 0."""
    stream = rc.stream = Stream(rc)
    try:
        first = stream.arm(rc.timeout_s)
    except Silent:
        raise RigUnreachable(f"the rig at {rc.url} answers HELLO but did not arm within {rc.timeout_s:g} s "
                             f"of ARM at {rc.supply_pa / 1e5:g} bar and {rc.vertical_load_n:g} N: are they "
                             "within its ranges (--supply-bar, --vertical-load-n, --rig-file)?") from None
    stream.answer(first)
    rc.figures["arm_to_first_measurement_ms"] = stream.first_ms
    return Answered(first, stream.first_ms * 1e-3)


def steady(rc: RigCheck, s: Stream) -> Steady:
    """STEADY_PERIODS measurements answered at once with 0 V, and the time between them."""
    recs = s.steady(STEADY_PERIODS)
    gaps = [(b.t - a.t) for a, b in zip(recs, recs[1:], strict=False) if b.seq == a.seq + 1]
    median = statistics.median(gaps) if gaps else math.nan
    mean = (recs[-1].t - recs[0].t) / max(1, recs[-1].seq - recs[0].seq)
    rc.figures.update(period_ns=recs[0]["period_ns"], inter_arrival_median_ms=median * 1e3,
                      inter_arrival_mean_ms=mean * 1e3)
    return Steady(recs, median, mean)


def missed(rc: RigCheck, s: Stream) -> Pair:
    s.steady(3)
    n = s.next()  # not answered
    after = s.next()
    s.answer(after)
    s.steady(2)
    return Pair(n, after)


def late(rc: RigCheck, s: Stream) -> Late:
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
    return Late(n, after)


def hello_armed(rc: RigCheck, s: Stream) -> HelloArmed:
    """A HELLO from the HELLO socket while armed, and the stream around it."""
    s.steady(3)
    latest = s.last
    rc.link.drain(aux=True)
    rc.link.send(rc.link.hello_packet(), aux=True)
    got = s.steady(3)
    rec = rc.link.receive(time.perf_counter() + 0.1, aux=True)
    while rec is not None and got[-1].seq < rec.seq and len(got) < 30:  # the stream's of the same sequence
        got += s.steady(1)
    same = [x for x in [latest, *got] if rec is not None and x.seq == rec.seq]
    if same and same[0]["packets_rejected"] != rec["packets_rejected"]:
        # the HELLO's counters are those of the moment it is answered: an answer of this check's own that arrived
        # stale in between is counted there and not yet in the stream's measurement (a CI run: 5 against 4, this
        # check 6 periods behind); only a check that read on time may judge that
        s.recent_on_time()
    return HelloArmed(s.session, latest, got, rec)


def _counted(s: Stream, n: Received, after: list[Received], rejected: int) -> list[Received]:
    """``after``, once it is sure the rig's count of dropped datagrams since ``n`` is the probe's. Where the count
    rose by anything but ``rejected`` (or no command was seen applied) and this check read any of its last
    RECENT_READS measurements late (those before ``n`` too: an answer to one of them that arrived stale is counted
    after ``n``), its own answers may have been counted beside the probe's datagrams (CI runs: "future" +3 where one
    was sent, "a command more than 10 periods old" +2): ``Disturbed``, and the probe runs again. Only where the count
    is wrong, so that a late read with the right count is judged."""
    if not after or after[-1]["packets_rejected"] - n["packets_rejected"] != rejected:
        s.recent_on_time()
    return after


def hello_without_key_armed(rc: RigCheck, s: Stream) -> Synced:
    s.steady(3)
    n = s.last
    rc.link.drain(aux=True)
    rc.link.send(_keyless_hello(rc, time.perf_counter_ns()), aux=True)
    after = _counted(s, n, s.sync(), 1)
    return Synced(n, after, answers=len(rc.link.drain(aux=True)))


def repeated_arm(rc: RigCheck, s: Stream) -> Synced:
    s.steady(3)
    n = s.last
    rc.link.send(s.arm_data)  # the host repeats its ARM (version 2: the same challenge)
    return Synced(n, _counted(s, n, s.sync(), 0))


def busy(rc: RigCheck, s: Stream) -> Synced:
    """An ARM of another session while armed (that session disarmed again if the rig took it)."""
    s.steady(3)
    n = s.last
    other = new_session()
    foreign = s.foreign
    rc.link.send(rc.link.encode(proto.ARM, other, 0, time.perf_counter_ns(), rc.supply_pa, rc.vertical_load_n))
    try:
        after = s.sync()
    except Silent:
        Stream(rc, other).disarm()
        s.armed = False
        return Synced(n, None)
    took = s.foreign != foreign
    if took:
        Stream(rc, other).disarm()
    else:
        _counted(s, n, after, 1)
    return Synced(n, after, foreign=took)


def _good(rc: RigCheck, s: Stream, n: Received) -> bytes:
    """The valid answer to ``n`` (0 V)."""
    return rc.link.encode(proto.COMMAND, s.session, n.seq, 0, 0.0)


def _body(rc: RigCheck, s: Stream, n: Received) -> bytes:
    """That answer without its CRC or tag."""
    return _good(rc, s, n)[:-rc.link.codec.trailer]


def _flipped(rc: RigCheck, s: Stream, n: Received) -> bytes:
    """That answer with its CRC or tag damaged."""
    good = _good(rc, s, n)
    return good[:-4] + bytes(b ^ 0xFF for b in good[-4:])


def _other_version(rc: RigCheck) -> bytes:
    return struct.pack("<H", 1 if rc.link.codec.version == 2 else 2)


_OTHER_SESSION = 0x5A5A5A5A  # xor'ed with the running session

#: each drop probe: (the datagrams sent in place of the answer to measurement n, sealed right unless the probe
#: breaks the seal; the offset from n of the command_sequence that would show one applied, None: no command)
DROPS: dict[str, tuple[Callable[[RigCheck, Stream, Received], list], int | None]] = {
    "short": (lambda rc, s, n: [_good(rc, s, n)[:20]], None),
    "size": (lambda rc, s, n: [rc.link.seal(_body(rc, s, n) + b"\0", s.session)], 0),
    "magic": (lambda rc, s, n: [rc.link.seal(b"ISRX" + _body(rc, s, n)[4:], s.session)], 0),
    "version": (lambda rc, s, n: [rc.link.seal(_body(rc, s, n)[:4] + _other_version(rc) + _body(rc, s, n)[6:],
                                               s.session)], 0),
    "kind": (lambda rc, s, n: [rc.link.seal(_body(rc, s, n)[:6] + struct.pack("<H", 9) + _body(rc, s, n)[8:],
                                            s.session),
                               rc.link.encode(proto.MEASUREMENT, s.session, n.seq, 0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0,
                                              0, 0, 0)], 0),
    "crc": (lambda rc, s, n: [_flipped(rc, s, n)], 0),
    "auth": (lambda rc, s, n: [_flipped(rc, s, n),
                               rc.link.encode(proto.COMMAND, s.session, n.seq, 0, 0.0, key=auth.new_nonce() * 2)], 0),
    "session": (lambda rc, s, n: [rc.link.encode(proto.COMMAND, s.session ^ _OTHER_SESSION, n.seq, 0, 0.0)], 0),
    "future": (lambda rc, s, n: [rc.link.encode(proto.COMMAND, s.session, n.seq + 1000, 0, 0.0)], 1000),
    "value": (lambda rc, s, n: [rc.link.encode(proto.COMMAND, s.session, n.seq, 0, v)
                                for v in (math.nan, math.inf, -math.inf, VALUE_FACTOR * rc.rig.command_limit_v,
                                          -VALUE_FACTOR * rc.rig.command_limit_v)], 0),
    "address": (lambda rc, s, n: [(_good(rc, s, n), True)], 0),  # (data, True): from the HELLO socket
    "disarm-session": (lambda rc, s, n: [rc.link.encode(proto.DISARM, s.session ^ _OTHER_SESSION, 0, 0)], None),
    "disarm-auth": (lambda rc, s, n: [rc.link.encode(proto.DISARM, s.session, 0, 0, key=auth.new_nonce() * 2)],
                    None),
}


def dropped(rc: RigCheck, s: Stream, what: str) -> Dropped:
    """The datagrams of ``DROPS[what]`` in place of the answer to measurement n, then the stream on until a valid
    command is applied."""
    make, offset = DROPS[what]
    s.steady(3)
    n = s.next()
    datagrams = make(rc, s, n)
    for data in datagrams:  # (data, True): from the HELLO socket, another port than the ARM's
        rc.link.send(*data) if isinstance(data, tuple) else rc.link.send(data)
    applied_if = None if offset is None else n.seq + offset
    try:
        seen = s.skip(2)
        seen += _counted(s, n, s.sync(), len(datagrams))
    except Silent:
        s.armed = False
        return Dropped(n, None, len(datagrams), applied_if)
    return Dropped(n, seen, len(datagrams), applied_if)


#: what the stale probe sends that a rig must drop: a duplicate of the answer and an answer older than it
STALE_SENT = 2


def stale(rc: RigCheck, s: Stream) -> Synced:
    """The answer to n, then it again and an answer to n - 2 (STALE_SENT)."""
    s.steady(3)
    n = s.next()
    good = s.answer(n)
    rc.link.send(good)  # a duplicate
    rc.link.send(rc.link.encode(proto.COMMAND, s.session, n.seq - 2, 0, 0.0))  # older than the one held
    return Synced(n, _counted(s, n, s.sync(), STALE_SENT))


def disarm(rc: RigCheck, s: Stream) -> Disarmed:
    """DISARM of the running session, what arrives after it; then, unarmed, 2 DISARMs more and a COMMAND."""
    s.steady(5)
    while (rec := rc.link.receive(0.0)) is not None:  # what was queued before the DISARM
        s.last = rec
        s.answer(rec)
    last = s.last
    rc.link.send(rc.link.encode(proto.DISARM, s.session, 0, time.perf_counter_ns()))
    s.armed = False
    rc.stream = None
    rc.last_disarmed = s.session
    rc.last_disarmed_arm = s.arm_data
    flight = []
    end = time.perf_counter() + 2 * SILENCE_S
    while (rec := rc.link.receive(end)) is not None:
        flight.append(rec)
    answer = rc.hello()
    before = answer["packets_rejected"]
    for _ in range(2):  # the host sends DISARM three times
        rc.link.send(rc.link.encode(proto.DISARM, s.session, 0, time.perf_counter_ns()))
    rc.link.send(rc.link.encode(proto.COMMAND, s.session, last.seq + 1, 0, 0.0))
    rc.silent(SILENCE_S, "while unarmed, after a COMMAND")
    rose = rc.hello()["packets_rejected"] - before
    return Disarmed(last, [x for x in flight if x.packet.session == s.session], answer, rose, list(rc.unsolicited))


def replayed_arm(rc: RigCheck) -> Unanswered | None:
    """Version 2: the ARM of the session ``disarm`` ended, sent again (None: no session was disarmed)."""
    data = rc.last_disarmed_arm
    if not data:
        return None
    got = unanswered(rc, [data], aux=False)
    if got.answers:  # it armed: end that session, or the rules after this one would see it running
        Stream(rc, int.from_bytes(data[8:12], "little")).disarm()
        rc.link.challenge = None
    return got


def arm_finished(rc: RigCheck) -> Anew:
    """An ARM of the session ``disarm`` ended (version 2: with a fresh challenge)."""
    if rc.last_disarmed is None:
        return Anew(None, "not checked: no session was disarmed")
    stream = Stream(rc, rc.last_disarmed)
    try:
        first = stream.arm(0.5)
        stream.answer(first)
        stream.steady(3)
        got = Anew(first)
    except Disturbed as exc:
        got = Anew(None, f"no measurement after it: {exc}")
    finally:
        stream.disarm()
    rc.stream = None
    return got


def watchdog(rc: RigCheck) -> dict[str, list[Trip]]:
    """WATCHDOG_TRIPS trips of the watchdog (one if it never trips) by each of WATCHDOG_WAYS."""
    trips: dict[str, list[Trip]] = {}
    for since in WATCHDOG_WAYS:
        trips[since] = []
        for _ in range(WATCHDOG_TRIPS):
            trips[since].append(trip := watchdog_trip(rc, since))
            if trip.seconds is None:
                break  # no watchdog: once is enough
        rc.figures[f"watchdog_after_{since.replace(' ', '_')}_ms"] = [
            None if t.seconds is None else t.seconds * 1e3 for t in trips[since]]
    return trips


def rig_stall_s(recs: list[Received], period_s: float) -> float:
    """How long the rig itself did not run between these consecutive measurements, by its own clock (time_ns):
    the waits beyond 1.5 periods, less a period each (docs/rig-protocol.md 1.6: an overrun is one long wait)."""
    gaps = [(b.packet.time_ns - a.packet.time_ns) * 1e-9 for a, b in zip(recs, recs[1:], strict=False)]
    return sum(gap - period_s for gap in gaps if gap > 1.5 * period_s)


def watchdog_trip(rc: RigCheck, since: str) -> Trip:
    """Commands stop at ``since``: "last command", "ARM", or "stale commands" (duplicates and old ones go on).

    A trip is timed again when this check was late (the watchdog took the stream before ``since``) or when the
    rig overran in the timed window (more than RIG_STALL_S, by its clock): its last measurement then comes when
    the rig wakes, whenever its valve closed, and the figure would be the machine's, not the watchdog's."""
    late = stalled = 0
    while late < TRIES and stalled < STALL_TRIES:
        stream = Stream(rc)
        try:
            first = stream.arm(rc.timeout_s)
            if since != "ARM":
                stream.answer(first)
                stream.steady(20)
        except Disturbed:
            stream.disarm()  # this check was late and the watchdog took it: again
            late += 1
            continue
        start = stream.arm_sent_t if since == "ARM" else stream.last_answer_t
        kept, prev = stream.last_answer_data, stream.last
        window = [prev]
        try:
            while True:
                if time.perf_counter() - start > WATCHDOG_GIVE_UP_S:
                    stream.disarm()
                    return Trip(None, f"still armed {WATCHDOG_GIVE_UP_S * 1e3:g} ms after the {since}: no watchdog",
                                no_watchdog=True)
                prev = stream.next()
                window.append(prev)
                if since == "stale commands":
                    rc.link.send(kept)  # a duplicate of the last valid command
                    rc.link.send(rc.link.encode(proto.COMMAND, stream.session, 0, 0, 0.0))  # an old one
        except Tripped as exc:
            final = exc.rec
        except Silent as exc:
            stream.disarm()
            return Trip(None, f"the stream stopped without a WATCHDOG measurement ({exc})")
        after = rc.silent(SILENCE_S, "after the WATCHDOG measurement")
        answer = rc.hello()
        stall = rig_stall_s([*window, final], rc.period_s) if stream.clock else 0.0
        if stall > RIG_STALL_S:
            stalled += 1
            rc.figures["watchdog_trips_retimed_for_rig_stalls"] = \
                rc.figures.get("watchdog_trips_retimed_for_rig_stalls", 0) + 1
            continue
        # as if read at once: this process's lateness aside
        return Trip(final.t - final.late_s - start, final=final, previous=prev, after=len(after), hello=answer)
    if stalled >= STALL_TRIES:
        return Trip(None, f"the rig overran (stalled more than {RIG_STALL_S * 1e3:g} ms by its own clock) in "
                          f"{STALL_TRIES} trips: the watchdog could not be timed")
    return Trip(None, f"this check was late {TRIES} times before the watchdog could be timed")


def watchdog_s(trips: dict[str, list[Trip]] | None) -> float | None:
    """The watchdog's time after the last command, the median of its trips (None: a trip was not timed, or by
    any way the rig showed no watchdog)."""
    if trips is None:
        return None
    timed = [t.seconds for t in trips["last command"] if t.seconds is not None]
    if len(timed) < len(trips["last command"]) or any(t.no_watchdog for way in trips.values() for t in way):
        return None
    return statistics.median(timed)


def stale_age_skip(rc: RigCheck) -> str:
    """Why ``old_command`` cannot run ('' if it can): the rig's watchdog is shorter than its wait."""
    needed = (STALE_PERIODS + 3) * rc.period_s + 0.003
    time_s = watchdog_s(rc.measured("watchdog"))
    if time_s is not None and time_s < needed:
        return (f"not checked: the rig's watchdog ({time_s * 1e3:.1f} ms) would trip in the {STALE_PERIODS + 3} "
                "periods without a command it takes")
    return ""


def old_command(rc: RigCheck, s: Stream) -> OldCommand:
    """STALE_PERIODS + 2 measurements unanswered, then an answer to the first of them."""
    s.steady(3)
    n = s.last
    held = s.skip(STALE_PERIODS + 2)
    target = held[0]  # the rig has sent held[-1] = target + 11 at least: more than 10 periods old
    rc.link.send(rc.link.encode(proto.COMMAND, s.session, target.seq, 0, 0.0))
    return OldCommand(n, target, held[-1], _counted(s, n, s.sync(), 1))


def _push(s: Stream, command_v: float, y0: float, until) -> tuple[list[Received], bool]:
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


def _mean(recs: list[Received], name: str) -> float:
    return statistics.fmean(x[name] for x in recs)


def move(rc: RigCheck, s: Stream) -> Motion:
    """+motion_v until the table has moved MOTION_STEP_M, rest, -motion_v back to where it started (less how far
    it ran on), rest; then DISARM and a HELLO. The load pressure's change over each push is from the rest just
    before it (``pressure_change``)."""
    rest = s.steady(MOTION_REST_PERIODS + 10)[-MOTION_REST_PERIODS:]
    y0, f0 = _mean(rest, "position_m"), _mean(rest, "force_n")
    up, stop_up = _push(s, rc.motion_v, y0, lambda y: y - y0 >= MOTION_STEP_M)
    settled = s.steady(40)
    y1, f1 = _mean(settled[-5:], "position_m"), _mean(settled[-5:], "force_n")
    coast = max(0.0, y1 - y0 - MOTION_STEP_M)  # how far the table ran on after 0 V: stop back that much early
    down, stop_down = _push(s, -rc.motion_v, y0, lambda y: y <= y0 + coast)
    back = s.steady(40)
    y2 = _mean(back[-5:], "position_m")
    s.disarm()
    rc.stream = None
    answer = rc.hello()
    figures = rc.figures["motion"] = {"up_m": y1 - y0, "back_m": y2 - y1, "up_ms": len(up) * rc.period_s * 1e3}

    def readings(recs):
        return [x["load_pressure_pa"] for x in recs]

    up_pa, up_min_pa = pressure_change(readings(rest), readings(up))
    down_pa, down_min_pa = pressure_change(readings(settled[-MOTION_REST_PERIODS:]), readings(down))
    figures["pressure_change_pa"] = {"up": up_pa, "down": down_pa, "up_min": up_min_pa, "down_min": down_min_pa}
    figures["force_change_n"] = f1 - f0
    return Motion(up, down, stop_up or stop_down, y1 - y0, y2 - y1, f1 - f0, figures["pressure_change_pa"],
                  back[-1]["position_m"], answer)


def link_seen(rc: RigCheck) -> LinkSeen:
    """What the link saw in the whole check: replies from elsewhere, invalid datagrams."""
    link = rc.link
    return LinkSeen(link.addr, set(link.wrong_sources), link.received, dict(link.invalid))


@dataclass(frozen=True)
class Probe:
    """A probe: ``run(rc, *args)``, or on an armed stream ``run(rc, stream, *args)`` (run again on a new session
    when disturbed, up to TRIES times; ``end_session``: that session disarmed after it); ``skip(rc)``: why it
    cannot run ('' if it can); ``needed``: its ``RigUnreachable`` ends the check (nothing to check);
    ``always``: it runs even after a ``RigUnreachable``. A probe that returns None has nothing to judge."""

    run: Callable
    on_stream: bool = False
    end_session: bool = False
    skip: Callable[[RigCheck], str] | None = None
    needed: bool = False
    always: bool = False


PROBES: dict[str, Probe] = {
    "hello_unarmed": Probe(hello_unarmed, needed=True),
    "hello_without_key": Probe(hello_without_key),
    "hello_rate": Probe(hello_rate),
    "hello_under_flood": Probe(hello_under_flood),
    "refused_arms": Probe(refused_arms),
    "main_arm": Probe(main_arm),
    "steady": Probe(steady, on_stream=True),
    "missed": Probe(missed, on_stream=True),
    "late": Probe(late, on_stream=True),
    "hello_armed": Probe(hello_armed, on_stream=True),
    "repeated_arm": Probe(repeated_arm, on_stream=True),
    "busy": Probe(busy, on_stream=True),
    "dropped": Probe(dropped, on_stream=True),
    "hello_without_key_armed": Probe(hello_without_key_armed, on_stream=True),
    "stale": Probe(stale, on_stream=True),
    "disarm": Probe(disarm, on_stream=True),
    "replayed_arm": Probe(replayed_arm),
    "arm_finished": Probe(arm_finished),
    "watchdog": Probe(watchdog),
    "old_command": Probe(old_command, on_stream=True, end_session=True, skip=stale_age_skip),
    "move": Probe(move, on_stream=True),
    "link": Probe(link_seen, always=True),
}
