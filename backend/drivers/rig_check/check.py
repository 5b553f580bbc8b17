"""``RigCheck``: runs the probes the rules of ``RULES`` need, in the table's order, and judges each rule on its
probe's measurement (rules.py); ``check_rig(url)``."""

from __future__ import annotations

import gc
import math
import time
from itertools import groupby

from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.realtime import realtime_priority
from sim.rig import DEFAULT_RIG, RigParameters

from ..udp import parse_udp_url
from .link import Disturbed, Link, Received, RigUnreachable, Silent, Stream
from .probes import PROBES, TRIES, Probe
from .report import RigCheckReport, RuleResult
from .rules import CHECKS, RULE, RULES, Rule, watchdog_bounds_s

CHECK_RR_PRIORITY = 10  # the worker's: the host's side of the loop (sim.realtime)
MOTION_MAX_V = 3.0


class RigCheck:
    """The check of one rig (see the package's docstring); ``run()`` gives the report."""

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
        self.seen: dict[tuple[str, str | None], object] = {}  # each probe's measurement, by (probe, arg)
        self.unsolicited: list[str] = []  # what an unarmed rig sent without being asked
        self.last_disarmed: int | None = None
        self.last_disarmed_arm = b""

    # --- the rules ------------------------------------------------------------------------------------------
    def context(self) -> dict:
        """What a rule's name and message are formatted with."""
        version = self.security.protocol_version
        lower, upper = watchdog_bounds_s(self.period_s)
        return {"motion_v": self.motion_v, "limit_v": self.rig.command_limit_v,
                "size": proto.Codec(version).sizes[proto.MEASUREMENT], "integrity": "CRC" if version == 1 else "tag",
                "watchdog_bounds": f"[{lower * 1e3:g}, {upper * 1e3:g}] ms"}

    def applies(self, rule: Rule) -> bool:
        version = self.security.protocol_version
        return {"": True, "v1": version == 1, "v2": version == 2, "motion": self.motion}[rule.when]

    def measured(self, probe: str, arg: str | None = None):
        """The measurement of ``probe`` (None: it did not run, or was not measured)."""
        return self.seen.get((probe, arg))

    def add(self, rule: Rule, ok: bool | None, figure: str = "", detail: str = "") -> bool | None:
        context = self.context()
        self.report.results.append(RuleResult(rule.section, rule.text.format(**context), ok, figure, detail))
        return ok

    def judge(self, rule: Rule, measurement, again: str = "") -> bool | None:
        """The rule's check on ``measurement``: a failing row's detail ends with the rule's message."""
        verdict = CHECKS[rule.check_name](measurement, self)
        notes = list(verdict.notes)
        message = rule.fails.format(**self.context())
        if verdict.ok is False and message not in notes:
            notes.append(message)
        if again:
            notes.append(again)
        return self.add(rule, verdict.ok, verdict.figure, "; ".join(notes))

    def attempt(self, rules: list[Rule], probe: Probe, args: tuple) -> None:
        """Run ``probe`` on the armed stream and judge ``rules`` on it. If the rig's watchdog interrupts it (this
        process was late) or the stream stops, arm a new session and run it again, up to TRIES times."""
        note = ""
        for attempt in range(TRIES):
            try:
                if self.stream is None or not self.stream.armed:
                    self._rearm()
                measurement = probe.run(self, self.stream, *args)
            except Disturbed as exc:
                note = str(exc)
                if self.stream is not None:
                    self.stream.disarm()
                self.stream = None
                continue
            self.seen[(rules[0].probe, rules[0].arg)] = measurement
            for rule in rules:
                self.judge(rule, measurement, f"run {attempt + 1} times (before: {note})" if attempt else "")
            return
        for rule in rules:
            self.add(rule, False, "", f"could not be checked in {TRIES} tries: {note}")

    def _rearm(self) -> None:
        self.stream = Stream(self)
        try:
            self.stream.arm(self.timeout_s)
        except Silent:
            raise RigUnreachable(f"the rig at {self.url} stopped accepting ARM ({self.supply_pa / 1e5:g} bar, "
                                 f"{self.vertical_load_n:g} N) in the middle of the check") from None
        self.stream.steady(5)

    def probe(self, rules: list[Rule]) -> None:
        """Run the probe of ``rules`` (one probe, one arg) and judge them on its measurement."""
        probe, args = PROBES[rules[0].probe], (() if rules[0].arg is None else (rules[0].arg,))
        if probe.skip and (why := probe.skip(self)):
            for rule in rules:
                self.add(rule, None, "", why)
            return
        if probe.on_stream:
            self.attempt(rules, probe, args)
            if probe.end_session and self.stream is not None:
                self.stream.disarm()
                self.stream = None
            return
        measurement = probe.run(self, *args)
        if measurement is None:
            return  # nothing to judge
        self.seen[(rules[0].probe, rules[0].arg)] = measurement
        for rule in rules:
            self.judge(rule, measurement)

    # --- helpers of the probes ------------------------------------------------------------------------------
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
        """The probes in the order of ``RULES`` (the rules of one probe together). A ``RigUnreachable`` ends the
        check at once from a ``needed`` probe, else after a "ran to its end" row and the ``always`` probes."""
        gc_enabled = gc.isenabled()
        gc.disable()  # a collection in the middle of a probe would look like a late host to the rig's watchdog
        self.link = Link(self.host, self.port, self.security)
        unreachable = False
        try:
            for _, rules in groupby((r for r in RULES if r.probe and self.applies(r)), lambda r: (r.probe, r.arg)):
                rules = list(rules)
                probe = PROBES[rules[0].probe]
                if unreachable and not probe.always:
                    continue
                try:
                    self.probe(rules)
                except RigUnreachable as exc:
                    if probe.needed:
                        raise  # nothing to check
                    unreachable = True
                    self.judge(RULE["ran-to-end"], exc)
        finally:
            if self.stream is not None and self.stream.armed:
                self.stream.disarm()
            self.link.close()
            if gc_enabled:
                gc.enable()
        return self.report


def check_rig(url: str, **options) -> RigCheckReport:
    """Check the rig at ``udp://HOST:PORT`` (see the package's docstring and ``RigCheck`` for the options);
    ``RigUnreachable`` if nothing usable answers."""
    return RigCheck(url, **options).run()
