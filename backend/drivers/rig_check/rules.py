"""The rules of ``isorig check-rig`` as data: ``RULES``, one row each (its id, the section of docs/rig-protocol.md
it checks, its name in the report, what it tells a lab when it fails, the probe whose measurement feeds it), in
the order they are checked; and ``CHECKS``, the small functions that judge a probe's measurement (probes.py)
for a rule: ``check(measurement, rc) -> Verdict``. They send nothing and time nothing.

A rule's name and message are ``str.format``-ed with the check's context (``RigCheck.context``: ``motion_v``,
``limit_v``, ``size``, ``integrity``, ``watchdog_bounds``). A failing row's detail is the check's notes, then the
rule's message.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from sim.measurement import STATUS_ARMED, STATUS_COMMAND_MISSED, STATUS_WATCHDOG

from .probes import (
    HELLO_BURST,
    HELLO_BURST_SENT,
    HELLO_FLOOD_SENT,
    HELLO_RATE_PER_S,
    STALE_PERIODS,
    STALE_SENT,
    VALUE_FACTOR,
    Trip,
    watchdog_s,
)

if TYPE_CHECKING:
    from .check import RigCheck

WATCHDOG_MIN_S, WATCHDOG_MAX_S = 0.010, 0.020  # section 1.5
WATCHDOG_TOLERANCE_S = 0.004  # plus one period: the figure adds the link both ways and the rig's tick
POSITION_AGREE_M = 0.5e-3  # a HELLO's position and the armed stream's, at rest
HELLO_FOLLOW_M = 0.05e-3  # a HELLO after the motion: where the last measurement left the table
MOTION_MOVED_M = 0.05e-3  # --motion: the least a push must move the table
CHANNELS = ("position_m", "force_n", "load_pressure_pa", "supply_pressure_pa")


@dataclass(frozen=True)
class Rule:
    """One rule: ``id``; ``section`` of docs/rig-protocol.md; ``text``, its name in the report; ``fails``, what it
    tells a lab when it fails; ``probe`` (probes.PROBES, with ``arg``) whose measurement ``check`` (CHECKS, the id
    if not named) judges ("": none, the exception that ended the check feeds it); ``when``: "v1", "v2" (the link's
    protocol version) or "motion" (--motion) only. The rules of one probe (and arg) are next to each other."""

    id: str
    section: str
    text: str
    fails: str
    probe: str
    arg: str | None = None
    when: str = ""
    check: str = ""

    @property
    def check_name(self) -> str:
        return self.check or self.id


def _drop(reason: str, what: str, section: str = "§5", when: str = "") -> Rule:
    """A rule that datagrams in place of a command are dropped, counted and never applied (``probes.DROPS``)."""
    return Rule(f"drop-{reason}", section, f"drop {reason}: {what}",
                f"each is dropped and counted once ({reason}), never applied, and the test goes on",
                "dropped", reason, when, check="dropped")


_WATCHDOG_FAILS = "must be within {watchdog_bounds} of the %s (10-20 ms, plus the link and one period)"

RULES: tuple[Rule, ...] = (
    Rule("hello-unarmed", "§3.5", "HELLO answered unarmed: a measurement, session 0, sequence 0",
         "an unarmed rig answers a HELLO with one MEASUREMENT: session 0, sequence 0, its period_ns, finite channels",
         "hello_unarmed"),
    Rule("hello-without-key", "§9.6", "drop auth: a HELLO without the key gets no answer (no session revealed)",
         "a HELLO with a wrong tag must be dropped in silence and counted once (auth)", "hello_without_key",
         when="v2"),
    Rule("hello-rate", "§9.6", f"HELLO's rate: a burst of {HELLO_BURST_SENT} answered in part, the rest counted (rate)",
         f"a rig answers about {HELLO_BURST} HELLOs at once and {HELLO_RATE_PER_S:g} a second from one source, and "
         "drops and counts the rest (rate)", "hello_rate", when="v2"),
    Rule("hello-under-flood", "§9.6", f"HELLO under a flood: answered after {HELLO_FLOOD_SENT} keyless HELLOs from "
         "another socket, the flood counted",
         "a HELLO must be rated per source (address and port): a flood from others must not use up the host's "
         f"HELLOs; every keyless one dropped and counted ({2 * HELLO_FLOOD_SENT})", "hello_under_flood", when="v2"),
    Rule("drop-arm", "§5", "drop arm: an ARM outside the rig's ranges, in silence",
         "an ARM outside the rig's ranges (or NaN) gets no answer, arms nothing and is counted once (arm)",
         "refused_arms"),
    Rule("arm-session-0", "§3.2", "an ARM with session 0 is refused (arm), in silence",
         "an ARM with session 0 gets no answer, arms nothing and is counted once (arm)", "refused_arms"),
    Rule("arm-accepted", "§3.1", "ARM accepted: measurement 0 of its session, armed, counters from zero",
         "an accepted ARM starts its session at measurement 0, ARMED, without COMMAND_MISSED, its counters from 0",
         "main_arm"),
    Rule("hello-position", "§3.5", "HELLO reports the table's position",
         f"a HELLO reports the table's real position (within {POSITION_AGREE_M * 1e3:g} mm of the armed stream's at "
         "rest)", "main_arm"),
    Rule("sequence", "§1.1", "sequence +1 per period",
         "the sequence rises by 1 each period: never repeated or back, at most 1 % lost", "steady"),
    Rule("period", "§1.1", "period: period_ns, and measurements that far apart",
         "period_ns is the host's period, and a measurement comes every period_ns", "steady"),
    Rule("command-sequence", "§1.2", "command_sequence: the last command applied",
         "measurement n + 1 without COMMAND_MISSED must carry command_sequence n, with it less than n", "steady"),
    Rule("command-missed", "§1.3", "COMMAND_MISSED in n + 1 when n went unanswered, counted",
         "measurement n + 1 carries COMMAND_MISSED when no command answered n, and commands_missed counts each flag",
         "missed"),
    Rule("late-command", "§1.4", "a late command (2 periods) is still applied",
         "a command up to 10 periods late is applied if it is newer than the one held", "late"),
    Rule("hello-armed", "§3.5", "HELLO while armed: the session, latest sequence, counters",
         "armed, a HELLO's answer (to its sender only) carries the test's session, ARMED, the sequence of the latest "
         "measurement and the counters as of now", "hello_armed"),
    Rule("repeated-arm", "§3.2", "a repeated ARM of the running session is ignored",
         "a repeated ARM of the running session is ignored: no reset, not counted, the test goes on",
         "repeated_arm"),
    Rule("drop-busy", "§5", "drop busy: an ARM of another session while armed",
         "an ARM of another session while armed is dropped and counted once (busy): the running test keeps the rig",
         "busy"),
    _drop("short", "fewer bytes than a header"),
    _drop("size", "not the size of its kind"),
    _drop("magic", "another protocol"),
    _drop("version", "another version"),
    _drop("kind", "an unknown kind, a MEASUREMENT to the rig"),
    _drop("crc", "damaged", when="v1"),
    _drop("auth", "damaged (a wrong tag), and tagged with another key", "§9.7", when="v2"),
    _drop("session", "a COMMAND of another session"),
    _drop("future", "a COMMAND answering a measurement not sent yet"),
    _drop("value", f"NaN, +-inf, +-{VALUE_FACTOR:g} x the {{limit_v:g}} V limit"),
    _drop("address", "a COMMAND from another port than the ARM's", "§9.7", when="v2"),
    Rule("disarm-other-session", "§3.3", "a DISARM of another session is dropped, the test goes on",
         "a DISARM of another session is dropped and counted once (session), and the test goes on", "dropped",
         "disarm-session", check="dropped"),
    Rule("disarm-other-key", "§9.7", "drop auth: a DISARM tagged with another key, the test goes on",
         "a DISARM with a wrong tag is dropped and counted once (auth), and the test goes on", "dropped",
         "disarm-auth", when="v2", check="dropped"),
    Rule("hello-without-key-armed", "§9.1", "a HELLO without the key while armed: no answer, no session revealed",
         "a HELLO with a wrong tag gets no answer and is counted once (auth), armed or not",
         "hello_without_key_armed", when="v2"),
    Rule("drop-stale", "§5", "drop stale: a duplicate, a command older than the one held",
         "a duplicate and a command older than the one held are dropped and counted once each (stale)", "stale"),
    Rule("disarm", "§3.4", "DISARM: the stream stops, nothing more is sent",
         "a DISARM of the running session disarms: nothing more is sent (at most what is on its way), and a HELLO "
         "says unarmed, session 0, sequence 0", "disarm"),
    Rule("unarmed", "§1.7", "unarmed: a COMMAND is dropped and counted, nothing is sent",
         "unarmed, the rig sends nothing unasked, ignores a DISARM of the session that last ran and drops a COMMAND "
         "(session)", "disarm"),
    Rule("replayed-arm", "§9.5", "drop challenge: a finished session's ARM sent again arms nothing",
         "an ARM whose challenge was spent must be dropped in silence and counted (challenge)", "replayed_arm",
         when="v2"),
    Rule("arm-finished-session", "§3.2", "an ARM of a finished session starts it anew, at sequence 0",
         "the rig remembers no finished session: an ARM of it is a new ARM, from sequence 0", "arm_finished"),
    Rule("watchdog-after-command", "§1.5", "watchdog: 0 V and a last measurement 10-20 ms after the last command",
         _WATCHDOG_FAILS % "last command", "watchdog"),
    Rule("watchdog-after-arm", "§1.5", "watchdog starts at ARM (no command at all)", _WATCHDOG_FAILS % "ARM",
         "watchdog"),
    Rule("watchdog-stale-commands", "§1.5", "a stale command does not feed the watchdog",
         _WATCHDOG_FAILS % "stale commands", "watchdog"),
    Rule("watchdog-last-measurement", "§1.5", "watchdog's last measurement: session, last + 1, WATCHDOG, then silence",
         "the watchdog's last measurement: the test's session, the last sequence + 1, WATCHDOG and COMMAND_MISSED "
         "without ARMED, nothing after it, WATCHDOG in a HELLO's answer until the next ARM", "watchdog"),
    Rule("drop-stale-old", "§5", f"drop stale: a command more than {STALE_PERIODS} periods old",
         f"a command answering a measurement more than {STALE_PERIODS} periods old is dropped and counted once "
         "(stale), never applied", "old_command"),
    Rule("motion-direction", "§1.2", "a command of +-{motion_v:g} V moves the table towards +-y",
         "a positive command drives the table towards +y, a negative one back (moved the other way, or not at "
         "all: a dead zone wider than --motion-v?)", "move", when="motion"),
    Rule("load-pressure-sign", "§4.2", "load_pressure_pa is positive pushing towards +y",
         "P_L must rise while the valve pushes the table towards +y and fall while it pushes towards -y", "move",
         when="motion"),
    Rule("force-sign", "§4.2", "force_n: the specimen's, of the displacement's sign",
         "force_n must rise with the displacement (the specimen's force, positive when it is deformed towards +y)",
         "move", when="motion"),
    Rule("hello-after-motion", "§3.5", "HELLO reports the position after the table moved",
         f"a HELLO reports the table's real position, also after it moved (within {HELLO_FOLLOW_M * 1e3:g} mm of "
         "the last measurement)", "move", when="motion"),
    Rule("ran-to-end", "§8", "the check ran to its end",
         "the rig must answer HELLO and accept ARM to the end of the check", ""),
    Rule("reply-address", "§2", "replies come from the address and port the host sent to",
         "a rig sends every datagram from the address and port the host sent to", "link"),
    Rule("valid-measurements", "§4", "every datagram from the rig is a valid MEASUREMENT ({size} bytes, {integrity})",
         "every datagram a rig sends is a valid packet of the link's protocol version", "link"),
)

RULE = {rule.id: rule for rule in RULES}


class Verdict(NamedTuple):
    """A check's judgement: passed (None: not checked), the figure measured, notes for the row's detail."""

    ok: bool | None
    figure: str
    notes: list[str] | tuple[str, ...] = ()


def judged(problems: list[str], figure: str) -> Verdict:
    """Passed if there are no problems."""
    return Verdict(not problems, figure, problems)


CHECKS: dict[str, Callable[[object, RigCheck], Verdict]] = {}


def check(name: str):
    """Register ``fn(measurement, rc) -> Verdict`` as the check of ``name``."""
    def register(fn):
        CHECKS[name] = fn
        return fn
    return register


def watchdog_bounds_s(period_s: float) -> tuple[float, float]:
    """The watchdog's time within which a rig passes: 10-20 ms (section 1.5), plus the link and one period."""
    return WATCHDOG_MIN_S - 0.0005, WATCHDOG_MAX_S + period_s + WATCHDOG_TOLERANCE_S


# --- unarmed, version 2's HELLO, refused ARMs -----------------------------------------------------------------
@check("hello-unarmed")
def _hello_unarmed(m, rc):
    rec, f = m.rec, m.rec.packet.fields
    problems = []
    if rec.packet.session != 0 or rec.seq != 0:
        problems.append(f"session {rec.packet.session} and sequence {rec.seq}, not 0 and 0")
    if f["period_ns"] <= 0:
        problems.append(f"period_ns {f['period_ns']}")
    if not all(math.isfinite(f[name]) for name in CHANNELS):
        problems.append("a channel is not finite")
    return judged(problems, f"{m.after_s * 1e3:.2f} ms round trip, {rec.size} bytes")


@check("hello-without-key")
def _hello_without_key(m, rc):
    return Verdict(m.answers == 0 and m.rejected == 1, f"{m.answers} answer(s), packets_rejected +{m.rejected}")


@check("replayed-arm")
def _replayed_arm(m, rc):
    return Verdict(m.answers == 0 and m.rejected == 1, f"{m.answers} measurement(s), packets_rejected +{m.rejected}")


@check("hello-rate")
def _hello_rate(m, rc):
    most = 2 * (HELLO_BURST + HELLO_RATE_PER_S * m.sent_s) + 1
    problems = []
    if not 5 <= m.answers <= most:
        problems.append(f"{m.answers} of {HELLO_BURST_SENT} answered: at least 5 and at most {most:.0f} (a burst of "
                        f"{HELLO_BURST} and {HELLO_RATE_PER_S:g}/s, within a factor of 2)")
    if m.rejected != HELLO_BURST_SENT - m.answers:
        problems.append(f"packets_rejected rose by {m.rejected}, not the {HELLO_BURST_SENT - m.answers} unanswered "
                        "(rate)")
    return judged(problems, f"{m.answers} answered, packets_rejected +{m.rejected}")


@check("hello-under-flood")
def _hello_under_flood(m, rc):
    ok = m.answered and m.rejected == 2 * HELLO_FLOOD_SENT and not m.flood_answered
    return Verdict(ok, f"{'answered' if m.answered else 'no answer'}, packets_rejected +{m.rejected}")


def refusal_problems(r) -> str:
    """What an ARM the rig must refuse did wrong ('' if nothing)."""
    problems = []
    if r.answered:
        problems.append(f"the rig answered with {r.answered} measurement(s) (it armed)")
    if r.armed:
        problems.append("a HELLO says it is armed")
    if r.rejected != 1:
        problems.append(f"packets_rejected rose by {r.rejected}, not 1")
    return "; ".join(problems)


@check("drop-arm")
def _drop_arm(m, rc):
    rig = rc.rig
    failures = [f"{name}: {refusal_problems(r)}" for name, r in m.outside if refusal_problems(r)]
    ranges = (f"supply [{rig.min_supply_pa / 1e5:g}, {rig.max_supply_pa / 1e5:g}] bar, vertical load "
              f"[0, {rig.max_vertical_load_n / 1e3:g}] kN")
    figure = f"{len(m.outside)} refused, packets_rejected +{sum(r.rejected for _, r in m.outside)}"
    return Verdict(not failures, figure, failures or [f"ranges: {ranges}"])


@check("arm-session-0")
def _arm_session_0(m, rc):
    failure = refusal_problems(m.session_0)
    return judged([failure] if failure else [], f"packets_rejected +{m.session_0.rejected}")


# --- the main session ---------------------------------------------------------------------------------------
@check("arm-accepted")
def _arm_accepted(m, rc):
    first, f = m.rec, m.rec.packet.fields
    problems = [what for what, bad in (
        (f"sequence {first.seq}, not 0", first.seq != 0),
        ("not ARMED", not first.status & STATUS_ARMED),
        ("COMMAND_MISSED set", first.status & STATUS_COMMAND_MISSED),
        (f"counters not from zero (command_sequence {f['command_sequence']}, commands_missed "
         f"{f['commands_missed']}, packets_rejected {f['packets_rejected']})",
         f["command_sequence"] or f["commands_missed"] or f["packets_rejected"])) if bad]
    return judged(problems, f"{m.after_s * 1e3:.1f} ms from ARM to measurement 0")


@check("hello-position")
def _hello_position(m, rc):
    hello_m = rc.measured("hello_unarmed").rec["position_m"]
    dy = m.rec["position_m"] - hello_m
    return Verdict(abs(dy) <= POSITION_AGREE_M, f"{hello_m * 1e3:+.3f} mm (armed: {dy * 1e3:+.3f} mm from it)")


def _steps(seqs: list[int]) -> list[int]:
    return [b - a for a, b in zip(seqs, seqs[1:], strict=False)]


def _pairs(recs) -> list:
    """Consecutive measurements (n, n + 1)."""
    return [(a, b) for a, b in zip(recs, recs[1:], strict=False) if b.seq == a.seq + 1]


@check("sequence")
def _sequence(m, rc):
    steps = _steps([x.seq for x in m.recs])
    back = sum(1 for step in steps if step <= 0)
    lost = sum(step - 1 for step in steps if step > 1)
    return Verdict(back == 0 and lost <= 0.01 * len(m.recs), f"{len(m.recs)} measurements, {lost} lost, {back} "
                   "repeated or back", [] if back == 0 else ["a sequence repeated or went backwards"])


@check("period")
def _period(m, rc):
    period_ns, period_s = m.recs[0]["period_ns"], rc.period_s
    problems = []
    if abs(period_ns * 1e-9 - period_s) > 1e-9:
        problems.append(f"period_ns says {period_ns * 1e-6:g} ms; the host is set for {period_s * 1e3:g} ms "
                        "(--period-s, ISORIG_RIG_PERIOD_S): it refuses this rig at ARM")
    if not abs(m.median_s - period_s) <= 0.1 * period_s:
        problems.append("the median time between measurements is more than 10 % off period_ns")
    if not abs(m.mean_s - period_s) <= 0.2 * period_s:
        problems.append("the mean time between measurements is more than 20 % off period_ns")
    return judged(problems, f"period_ns {period_ns * 1e-6:g} ms; between measurements median "
                  f"{m.median_s * 1e3:.3f} ms, mean {m.mean_s * 1e3:.3f} ms")


def _missed_flag(rec) -> bool:
    return bool(rec.status & STATUS_COMMAND_MISSED)


@check("command-sequence")
def _command_sequence(m, rc):
    pairs = _pairs(m.recs)
    wrong = [b.seq for a, b in pairs if (_missed_flag(b) and b["command_sequence"] >= a.seq)
             or (not _missed_flag(b) and b["command_sequence"] != a.seq)]
    in_time = sum(1 for _, b in pairs if not _missed_flag(b))
    return judged([f"at sequence(s) {wrong[:5]}"] if wrong else [], f"{in_time} of {len(pairs)} answered in time")


@check("command-missed")
def _command_missed(m, rc):
    a, b = m.n, m.next
    problems = []
    if b.seq != a.seq + 1:
        problems.append(f"measurement {a.seq + 1} was lost")
    elif not _missed_flag(b):
        problems.append(f"measurement {b.seq} does not carry COMMAND_MISSED though {a.seq} went unanswered")
    elif b["commands_missed"] != a["commands_missed"] + 1:
        problems.append(f"commands_missed went from {a['commands_missed']} to {b['commands_missed']}, not +1")
    if b["command_sequence"] >= a.seq:
        problems.append(f"command_sequence {b['command_sequence']} in {b.seq}: no command answered {a.seq}")
    steady = rc.measured("steady")
    miscount = [b.seq for a, b in _pairs(steady.recs if steady else [])
                if b["commands_missed"] - a["commands_missed"] != (1 if _missed_flag(b) else 0)]
    if miscount:
        problems.append(f"in the steady stream, commands_missed did not rise by exactly the COMMAND_MISSED flags "
                        f"at sequence(s) {miscount[:5]}")
    return judged(problems, f"sequence {b.seq}: flag set, commands_missed {b['commands_missed']}")


@check("late-command")
def _late_command(m, rc):
    applied = m.after[-1]["command_sequence"] == m.n.seq
    return Verdict(applied, f"answer to {m.n.seq} sent after {m.n.seq + 2}", [] if applied else [
        f"command_sequence never showed {m.n.seq}: {[x['command_sequence'] for x in m.after]} in "
        f"{[x.seq for x in m.after]}"])


@check("hello-armed")
def _hello_armed(m, rc):
    rec, latest = m.answer, m.latest
    if rec is None:
        return Verdict(False, "", ["no answer to a HELLO sent while armed"])
    problems = []
    if rec.packet.session != m.session:
        problems.append(f"session {rec.packet.session}, not the test's {m.session}")
    if not rec.status & STATUS_ARMED:
        problems.append("ARMED not set")
    same = [x for x in [latest, *m.got] if x.seq == rec.seq]
    if rec.seq < latest.seq or not same:
        problems.append(f"sequence {rec.seq}, not one of the stream's latest ({latest.seq} on)")
    elif same[0]["packets_rejected"] != rec["packets_rejected"]:
        problems.append(f"packets_rejected {rec['packets_rejected']}, the stream's {same[0]['packets_rejected']}")
    elif not 0 <= rec["commands_missed"] - same[0]["commands_missed"] <= 1:
        problems.append(f"commands_missed {rec['commands_missed']}, the stream's {same[0]['commands_missed']}")
    seqs = [latest.seq] + [x.seq for x in m.got]
    if any(step != 1 for step in _steps(seqs)):
        problems.append(f"the stream's sequences around it: {seqs[:8]} (the answer goes to the HELLO's sender only)")
    return judged(problems, f"sequence {rec.seq} (latest {latest.seq})")


def _rejected_since(m) -> int:
    """The rise of packets_rejected from ``m.n`` to the last measurement after it (0: none)."""
    return m.after[-1]["packets_rejected"] - m.n["packets_rejected"] if m.after else 0


@check("hello-without-key-armed")
def _hello_without_key_armed(m, rc):
    rose = _rejected_since(m)
    problems = ([f"{m.answers} answer(s) to it"] if m.answers else []) + \
        ([f"packets_rejected rose by {rose}, not 1"] if rose != 1 else [])
    return judged(problems, f"{m.answers} answers, packets_rejected +{rose}")


def _restarted(m) -> list[str]:
    """The stream started again after ``m.n`` (or no valid command was applied after it)."""
    if any(x.seq <= m.n.seq for x in m.after):
        return [f"the sequence started again: {[x.seq for x in m.after]} after {m.n.seq}"]
    return []


@check("repeated-arm")
def _repeated_arm(m, rc):
    n, got = m.n, m.after
    problems = ["no command applied after it"] if not got else _restarted(m)
    if got and not problems and got[-1]["packets_rejected"] != n["packets_rejected"]:
        problems.append(f"counted as dropped (packets_rejected {n['packets_rejected']} -> "
                        f"{got[-1]['packets_rejected']})")
    return judged(problems, f"sequence {got[0].seq if got else '?'} after {n.seq}")


@check("drop-busy")
def _drop_busy(m, rc):
    if m.after is None:
        return Verdict(False, "", ["the stream of the running test stopped: the rig took the other session"])
    problems = ["measurements of the other session arrived"] if m.foreign else []
    problems += ["no command of the running test applied after it"] if not m.after else _restarted(m)
    rose = _rejected_since(m)
    if rose != 1:
        problems.append(f"packets_rejected rose by {rose}, not 1")
    return judged(problems, f"packets_rejected +{rose}, the test goes on")


@check("dropped")
def _dropped(m, rc):
    if m.seen is None:
        return Verdict(False, "", ["the rig stopped sending after it"])
    problems = []
    applied = [x.seq for x in m.seen if m.applied_if is not None and x["command_sequence"] == m.applied_if]
    if applied:
        problems.append(f"applied: command_sequence {m.applied_if} in measurement {applied[0]}")
    if len(m.seen) == 2:
        return Verdict(False, "", problems + ["the next valid command was not applied"])
    rose = m.seen[-1]["packets_rejected"] - m.n["packets_rejected"]
    if rose != m.sent:
        problems.append(f"packets_rejected rose by {rose}, not {m.sent}")
    return judged(problems, f"packets_rejected +{rose}")


@check("drop-stale")
def _drop_stale(m, rc):
    if not m.after:
        return Verdict(False, "", ["no valid command applied after them"])
    rose = _rejected_since(m)
    problems = [f"packets_rejected rose by {rose}, not {STALE_SENT}"] if rose != STALE_SENT else []
    if any(b["command_sequence"] < a["command_sequence"] for a, b in zip(m.after, m.after[1:], strict=False)):
        problems.append("command_sequence went backwards")
    return judged(problems, f"packets_rejected +{rose}")


# --- the end of a test ---------------------------------------------------------------------------------------
@check("disarm")
def _disarm(m, rc):
    problems = []
    if len(m.ours) > 2 or any(x.seq > m.last.seq + 2 for x in m.ours):
        problems.append(f"{len(m.ours)} measurement(s) after DISARM (sequences up to {max(x.seq for x in m.ours)})")
    hello = m.hello
    if hello.status & STATUS_ARMED or hello.packet.session != 0 or hello.seq != 0:
        problems.append(f"a HELLO after it: status {hello.status:#x}, session {hello.packet.session}, "
                        f"sequence {hello.seq} (must be unarmed, 0, 0)")
    return judged(problems, f"{len(m.ours)} measurement(s) in flight, then silence")


@check("unarmed")
def _unarmed(m, rc):
    problems = []
    if m.rejected != 1:
        problems.append(f"two repeated DISARMs and one COMMAND raised packets_rejected by {m.rejected}, not 1 (the "
                        "DISARMs of the finished session are ignored, the COMMAND is dropped as session)")
    if m.unsolicited:
        problems.append("; ".join(m.unsolicited))
    return judged(problems, f"packets_rejected +{m.rejected}")


@check("arm-finished-session")
def _arm_finished_session(m, rc):
    if m.first is None:
        return Verdict(False, "", [m.why])
    return Verdict(m.first.seq == 0 and bool(m.first.status & STATUS_ARMED), f"measurement {m.first.seq}")


# --- the watchdog ---------------------------------------------------------------------------------------------
def trip_problems(t: Trip) -> list[str]:
    """What one trip of the watchdog did wrong (why it was not timed, if it was not)."""
    if t.seconds is None:
        return [t.why]
    problems = []
    if not t.final.status & STATUS_WATCHDOG:
        problems.append(f"the last measurement lacks WATCHDOG (status {t.final.status:#x})")
    if not _missed_flag(t.final):
        problems.append("the last measurement lacks COMMAND_MISSED")
    if t.final.seq != t.previous.seq + 1:
        problems.append(f"the last measurement has sequence {t.final.seq}, not {t.previous.seq + 1}")
    if t.after:
        problems.append(f"{t.after} measurement(s) after the WATCHDOG one")
    hello = t.hello
    if hello.status & STATUS_ARMED or not hello.status & STATUS_WATCHDOG or hello.packet.session != 0:
        problems.append(f"a HELLO after it: status {hello.status:#x}, session {hello.packet.session} "
                        "(must be unarmed, WATCHDOG kept until the next ARM, session 0)")
    return problems


def _watchdog_time(trips: list[Trip], rc) -> Verdict:
    """The median time of the trips (each timed) within the bounds."""
    timed = [t.seconds for t in trips if t.seconds is not None]
    median = statistics.median(timed) if len(timed) == len(trips) else None
    lower, upper = watchdog_bounds_s(rc.period_s)
    listed = ", ".join("none" if t.seconds is None else f"{t.seconds * 1e3:.1f}" for t in trips)
    problems = [p for t in trips for p in trip_problems(t)]
    return Verdict(median is not None and lower <= median <= upper,
                   f"median {median * 1e3:.1f} ms ({listed})" if median is not None else "",
                   problems[:1] if problems and median is None else [])


@check("watchdog-after-command")
def _watchdog_after_command(m, rc):
    return _watchdog_time(m["last command"], rc)


@check("watchdog-after-arm")
def _watchdog_after_arm(m, rc):
    return _watchdog_time(m["ARM"], rc)


@check("watchdog-stale-commands")
def _watchdog_stale_commands(m, rc):
    return _watchdog_time(m["stale commands"], rc)


@check("watchdog-last-measurement")
def _watchdog_last_measurement(m, rc):
    trips = [t for way in m.values() for t in way]
    problems = list(dict.fromkeys(p for t in trips if not t.no_watchdog for p in trip_problems(t)))
    tripped = watchdog_s(m) is not None
    return Verdict(not problems and tripped, f"{sum(t.seconds is not None for t in trips)} trips",
                   problems or ([] if tripped else ["no last measurement: the rig never tripped"]))


@check("drop-stale-old")
def _drop_stale_old(m, rc):
    problems = []
    if any(x["command_sequence"] == m.target.seq for x in m.after):
        problems.append(f"applied: command_sequence {m.target.seq}")
    if not m.after:
        problems.append("no valid command applied after it")
    rose = m.after[-1]["packets_rejected"] - m.n["packets_rejected"] if m.after else 0
    if rose != 1:
        problems.append(f"packets_rejected rose by {rose}, not 1")
    return judged(problems, f"{m.newest.seq - m.target.seq}+ periods old, packets_rejected +{rose}")


# --- motion ---------------------------------------------------------------------------------------------------
@check("motion-direction")
def _motion_direction(m, rc):
    stopped = " (stopped at once: beyond 1 mm)" if m.stopped else ""
    return Verdict(m.moved_up_m >= MOTION_MOVED_M and m.moved_back_m <= -MOTION_MOVED_M,
                   f"{m.moved_up_m * 1e3:+.3f} mm in {len(m.up) * rc.period_s * 1e3:.0f} ms at {rc.motion_v:+g} V, "
                   f"{m.moved_back_m * 1e3:+.3f} mm at {-rc.motion_v:+g} V{stopped}")


@check("load-pressure-sign")
def _load_pressure_sign(m, rc):
    """Section 4.2: the mean load pressure over each push, from its rest just before (``pressure_change``),
    rises pushing towards +y and falls pushing towards -y, each beyond the noise."""
    p = m.pressure_pa
    up_pa, up_min_pa, down_pa, down_min_pa = p["up"], p["up_min"], p["down"], p["down_min"]
    figure = (f"{up_pa / 1e5:+.2f} bar pushing +y, {down_pa / 1e5:+.2f} bar pushing -y (mean change from the "
              f"rest before; at least {up_min_pa / 1e5:.2f}, {down_min_pa / 1e5:.2f} bar)")
    if up_pa >= up_min_pa and -down_pa >= down_min_pa:  # False on NaN
        return Verdict(True, figure)
    if up_pa <= -up_min_pa and down_pa >= down_min_pa:
        why = ["P_L fell pushing towards +y and rose pushing towards -y: its sign is inverted (P_L = P_A - P_B, "
               "positive when it pushes the table towards +y)"]
    elif not (math.isfinite(up_pa) and math.isfinite(down_pa)):
        why = ["no reading of a push to judge (the table did not move, or was stopped at once)"]
    elif abs(up_pa) < up_min_pa and abs(down_pa) < down_min_pa:
        why = ["P_L did not change beyond its noise while the valve pushed the table: is the channel P_A - P_B?"]
    else:
        why = []
    return Verdict(False, figure, why)


@check("force-sign")
def _force_sign(m, rc):
    return Verdict(m.force_change_n * m.moved_up_m > 0,
                   f"{m.force_change_n / 1e3:+.3f} kN for {m.moved_up_m * 1e3:+.3f} mm")


@check("hello-after-motion")
def _hello_after_motion(m, rc):
    dy = m.hello["position_m"] - m.last_position_m
    return Verdict(abs(dy) <= HELLO_FOLLOW_M,
                   f"{m.hello['position_m'] * 1e3:+.3f} mm ({dy * 1e3:+.3f} mm from the last measurement)")


# --- the check and the link -------------------------------------------------------------------------------------
@check("ran-to-end")
def _ran_to_end(exc, rc):
    return Verdict(False, "", [str(exc)])


@check("reply-address")
def _reply_address(m, rc):
    wrong = ", ".join(f"{ip}:{port}" for ip, port in sorted(m.wrong_sources))
    return Verdict(not wrong, f"{m.addr[0]}:{m.addr[1]}",
                   [f"replies from {wrong}: a host's connected socket never sees them"] if wrong else [])


@check("valid-measurements")
def _valid_measurements(m, rc):
    bad = sum(m.invalid.values())
    return Verdict(not bad, f"{m.received} received, {bad} invalid",
                   [", ".join(f"{n} {reason}" for reason, n in m.invalid.items())] if bad else [])
