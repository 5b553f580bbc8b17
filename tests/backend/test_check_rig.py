"""isorig check-rig against the rig emulator in its own process (``isorig rig-emulator``, real time): it passes on
the emulator, with and without --motion, and with --motion with a stiff specimen mounted; it fails, naming the
rule, on each emulator broken on purpose (--defect) and on a rig whose load pressure has the wrong sign; the
emulator plays a lab's rig file; and an emulator that overruns its period does what docs/rig-protocol.md section
1.6 says.
"""

from __future__ import annotations

import inspect
import json
import os
import select
import signal
import socket
import statistics
import subprocess
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from emulator import ISORIG, Emulator

from backend.drivers import ArmConditions, RigFault
from backend.drivers.rig_check import MOTION_PRESSURE_MIN_PA, check_rig, pressure_change
from backend.drivers.rig_check.probes import STEADY_PERIODS
from backend.drivers.udp import UdpRig
from sim.emulator import auth
from sim.emulator import protocol as proto
from sim.realtime import raise_priority
from sim.rigfile import load_rig_file

# real time against the rig emulator in its own process: scripts/test.sh runs these alone, after the others
pytestmark = [pytest.mark.realtime, pytest.mark.strict_timing]  # the 18 ms watchdog and the probes' timing

DROP_REASONS = ("short", "size", "magic", "version", "kind", "crc", "session", "stale", "future", "value", "busy",
                "arm")
SECTIONS = {"§1.1", "§1.2", "§1.3", "§1.4", "§1.5", "§1.7", "§2", "§3.1", "§3.2", "§3.3", "§3.4", "§3.5", "§4", "§5"}
#: each broken emulator, and the rules check-rig must fail on it (and no other): (section, start of the rule)
BROKEN = {
    "no-watchdog": {("§1.5", "watchdog: 0 V"), ("§1.5", "watchdog starts at ARM"),
                    ("§1.5", "a stale command does not feed"), ("§1.5", "watchdog's last measurement")},
    "echo-other-session": {("§5", "drop session")},
    "accept-stale": {("§5", "drop stale: a duplicate"), ("§5", "drop stale: a command more than 10")},
    "reply-from-other-port": {("§2", "replies come from the address and port")},
}
#: protocol 2 (section 9): each emulator broken on purpose, and the rule check-rig must fail on it (and no other)
V2_BROKEN = {
    "no-hello-rate": {("§9.6", "HELLO's rate")},
    "shared-hello-rate": {("§9.6", "HELLO under a flood")},  # issue 33: a flood from anyone starved the host
    "any-address": {("§9.7", "drop address")},
    "reuse-challenge": {("§9.5", "drop challenge")},
}
V2_DROP_REASONS = tuple(r for r in DROP_REASONS if r != "crc") + ("auth", "address", "challenge", "rate")
LAB_RIG = 'name = "Lab B rig"\nmax_supply_pa = 150e5\ncommand_limit_v = 5.0\n'


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    emulator = Emulator(tmp_path_factory.mktemp("good"), watchdog_ms=18.0)
    yield emulator
    emulator.stop()


@pytest.fixture(scope="class")
def others(tmp_path_factory):
    """The broken emulators and one playing a lab's rig, started side by side (each takes seconds to start), for
    the tests of one class: an idle emulator ticks at 1 kHz at real-time priority (about 10 % of a CPU), and a
    dozen left running beside the next tests starved them on a loaded machine."""
    path = tmp_path_factory.mktemp("others")
    (path / "lab.toml").write_text(LAB_RIG)
    flags = {name: ("--defect", name) for name in BROKEN}
    flags["lab"] = ("--plant-file", str(path / "lab.toml"), "--plant-set", "piston_area_m2=0.02")
    with ThreadPoolExecutor(len(flags)) as pool:
        started = dict(zip(flags, pool.map(lambda item: Emulator(path, *item[1], name=item[0], watchdog_ms=18.0),
                                           flags.items()), strict=True))
    started["lab_file"] = path / "lab.toml"
    yield started
    for name in flags:
        started[name].stop()


def failing_rows(out: str) -> str:
    """The failing rows of check-rig's JSON report (a CI log cuts a whole report short), else the output itself."""
    try:
        report = json.loads(out)
        return json.dumps([r for r in report["rules"] if not r["ok"]] + [report["figures"]], indent=1)
    except (ValueError, KeyError, TypeError):
        return out


def unexplained_failures(failures: list[tuple[str, str]], figures: dict, ticks_lost: int) -> list[tuple[str, str]]:
    """The failing rules (section, rule), less the period rule where the emulator's own overruns during the check
    explain its mean time between measurements (this VM on 2026-11-30: an idle emulator lost ~50 ticks a second to
    overruns, and a clean-clone run failed the period rule at a mean of 1.231 ms over the 500 steady periods)."""
    period_ms = figures.get("period_ns", 1e6) * 1e-6
    implied = (figures.get("inter_arrival_mean_ms", 0.0) / period_ms - 1.0) * STEADY_PERIODS  # ticks the mean lost
    return [(section, rule) for section, rule in failures
            if not (section == "§1.1" and rule.startswith("period:") and ticks_lost >= 0.8 * implied)]


def failed(report) -> set[tuple[str, str]]:
    return {(r.section, r.rule) for r in report.failures}


def matches(failures: set[tuple[str, str]], expected: set[tuple[str, str]]) -> bool:
    """Every expected rule failed, and nothing else."""
    named = {(s, prefix) for s, prefix in expected if any(f[0] == s and f[1].startswith(prefix) for f in failures)}
    others = {f for f in failures if not any(f[0] == s and f[1].startswith(p) for s, p in expected)}
    return named == expected and not others


def test_check_rig_passes_on_the_emulator_and_checks_every_rule(good):
    lost_before = good.fresh_status()["counters"]["ticks_lost"]
    out = subprocess.run([*ISORIG, "check-rig", good.url, "--json"], capture_output=True, text=True, timeout=60)
    assert out.stdout.lstrip().startswith("{"), out.stdout + out.stderr
    report = json.loads(out.stdout)
    lost = good.fresh_status()["counters"]["ticks_lost"] - lost_before
    failing = [(r["section"], r["rule"]) for r in report["rules"] if r["ok"] is False]
    assert out.returncode == (1 if failing else 0), out.stderr  # the exit code says what the report says
    assert not unexplained_failures(failing, report["figures"], lost), failing_rows(out.stdout) + out.stderr
    assert report["passed"] + len(failing) == len(report["rules"]) >= 34
    assert {r["section"] for r in report["rules"]} == SECTIONS
    for reason in DROP_REASONS:
        assert any(r["rule"].startswith(f"drop {reason}") for r in report["rules"]), reason
    figures = report["figures"]
    assert figures["period_ns"] == 1_000_000 and 0.9 < figures["inter_arrival_median_ms"] < 1.1
    for way in ("last_command", "ARM", "stale_commands"):  # the emulator's 18 ms, its period and the link
        trips = figures[f"watchdog_after_{way}_ms"]
        # never early; the median (what the rule judges: one late wake-up of a shared machine does not decide it,
        # and one of three came late in a CI run) within a period and the link of 18 ms
        assert len(trips) == 3 and min(trips) >= 18.0 and 18.0 <= statistics.median(trips) <= 24.0, (way, trips)
    status = good.fresh_status()
    # every drop reason reached the rig as that reason (its own counters by reason), and nothing moved: every
    # command was 0 V or refused
    assert set(DROP_REASONS) <= set(status["rejected"]), status["rejected"]
    assert not status["armed"] and status["command_v"] == 0.0 and abs(status["position_m"]) < 1e-6
    # three trips each way, and any timed again because the emulator itself overran in its window
    assert len(status["watchdog_trips"]) == 9 + figures.get("watchdog_trips_retimed_for_rig_stalls", 0)


def test_check_rig_with_motion_moves_the_table_both_ways_and_back(good):
    report = check_rig(good.url, motion=True)
    assert report.ok, report.table()
    motion = report.figures["motion"]
    assert motion["up_m"] > 0.2e-3 and motion["back_m"] < -0.2e-3 and motion["up_ms"] < 100
    assert max(abs(motion["up_m"]), abs(motion["back_m"])) < 1e-3  # small, bounded
    status = good.fresh_status()
    assert not status["armed"] and abs(status["position_m"]) < 0.2e-3  # left near where it was


@pytest.mark.parametrize("probe, rule, where", [
    ("future", "drop future", "skip"), ("stale", "drop stale: a duplicate", "sync"),
    # a CI run (2026-11-30) failed "drop stale: a command more than 10 periods old" with packets_rejected +2; another
    # "drop busy", its figure cut from the log
    # (the stall before its 12 unanswered periods: within them one would trip the 18 ms watchdog)
    ("old_command", "drop stale: a command more than 10", "steady"), ("busy", "drop busy", "sync")])
def test_a_check_stalled_in_a_counting_probe_runs_it_again_instead_of_failing_the_rig(good, monkeypatch, probe,
                                                                                      rule, where):
    """A CI run failed "drop future" on a conforming emulator (packets_rejected +3, not 1): this process stalled
    while it answered, its own answers arrived stale and were counted beside the probe's. A stall of 14 ms once in
    the probe (past the rig's stale age of 10 periods, short of its 18 ms watchdog) is now seen in its late reads,
    and the probe is run again. Whether a stall makes this process's own answers stale depends on the scheduler
    (3 of 6 runs on a quiet machine counted right), so the stall here also sends the answer such a stall leaves
    late: one to a measurement 20 periods old, which the rig must count as rejected."""
    import inspect

    from backend.drivers.rig_check import probes
    from backend.drivers.rig_check.link import proto

    stalled = {"done": False}
    original = getattr(probes.Stream, where)

    def after_a_stall(self, *args):
        caller = inspect.currentframe().f_back
        if not stalled["done"] and caller.f_code.co_name == ("dropped" if probe == "future" else probe) and \
                (probe != "future" or caller.f_locals.get("what") == "future"):
            stalled["done"] = True
            time.sleep(0.014)
            self.link.send(self.link.encode(proto.COMMAND, self.session, self.last.seq - 20, time.perf_counter_ns(),
                                            0.0))
        return original(self, *args)

    monkeypatch.setattr(probes.Stream, where, after_a_stall)
    assert_run_again_after_the_stall(good, stalled, rule)


def assert_run_again_after_the_stall(emulator, stalled: dict, rule: str) -> None:
    """check-rig on ``emulator`` with a stall patched in: it happened, the rule's probe ran again and passed, and no
    other rule failed but for the emulator's own overruns."""
    lost_before = emulator.fresh_status()["counters"]["ticks_lost"]
    report = check_rig(emulator.url)
    lost = emulator.fresh_status()["counters"]["ticks_lost"] - lost_before
    assert stalled["done"]
    row = next(r for r in report.results if r.rule.startswith(rule))
    assert row.ok and "run 2 times" in row.detail and "ms late" in row.detail, (row, report.table())
    assert not unexplained_failures(failed(report), report.figures, lost), report.table()


def test_a_check_stalled_before_its_armed_hello_runs_it_again_instead_of_failing_the_rig(good, monkeypatch):
    """A CI run failed "HELLO while armed" on an emulator that conforms there (packets_rejected 5 in the HELLO's
    answer, 4 in the stream's measurement of its sequence; the answer at sequence 525, the latest read 519): this
    process stalled before the HELLO went out, and the rig counted a datagram of it in between. Here the stall
    (14 ms, short of the 18 ms watchdog) also sends the answer such a stall leaves stale, one to a measurement 20
    periods old, just before the HELLO: the count is off and the probe runs again."""
    from backend.drivers.rig_check.link import Link, proto

    stalled = {"done": False}
    original = Link.drain

    def after_a_stall(self, aux=False):
        caller = inspect.currentframe().f_back
        if aux and not stalled["done"] and caller.f_code.co_name == "hello_armed":  # right before its HELLO
            stalled["done"] = True
            stream = caller.f_locals["s"]
            time.sleep(0.014)
            self.send(self.encode(proto.COMMAND, stream.session, stream.last.seq - 20, time.perf_counter_ns(), 0.0))
        return original(self, aux)

    monkeypatch.setattr(Link, "drain", after_a_stall)
    assert_run_again_after_the_stall(good, stalled, "HELLO while armed")


#: a specimen 50 times as stiff as IUT_a (k_d): at +0.3 mm it pulls back with about 20 kN, more than the 1.5 V
#: push holds at 20 bar, so the load pressure at rest there is about 15 bar
STIFF = {"name": "stiff_50x", "rho_bw_per_m": 141.0, "sigma_bw": 0.5, "n": 1.0, "kd_n_per_m": 50 * 1.25e6,
         "kw_n": 1.7e4}
PRESSURE_NOISE_PA = 0.2e5  # a real transducer's, per reading
#: the starts of the rows of check-rig --motion
MOTION_RULES = ("a command of", "load_pressure_pa", "force_n", "HELLO reports the position after")


@pytest.fixture(scope="class")
def stiff(tmp_path_factory):
    """An emulator with the stiff specimen mounted and 0.2 bar of noise on its load pressure readings."""
    path = tmp_path_factory.mktemp("stiff")
    (path / "stiff.json").write_text(json.dumps(STIFF))
    emulator = Emulator(path, "--plant-set", f"pressure_noise_rms_pa={PRESSURE_NOISE_PA:g}",
                        isolator=str(path / "stiff.json"), name="stiff", watchdog_ms=18.0)
    yield emulator
    emulator.stop()


class InvertedPressure:
    """A UDP relay in front of a rig that negates ``load_pressure_pa`` in every measurement it passes on (protocol
    1): a rig whose P_L has the wrong sign, everything else as the rig's. Each host socket gets its own socket to
    the rig, so the rig sees the host's sockets as distinct, and replies leave from the port the host sent to."""

    def __init__(self, rig_port: int):
        self.rig = ("127.0.0.1", rig_port)
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.url = f"udp://127.0.0.1:{self.front.getsockname()[1]}"
        self.back: dict[tuple, socket.socket] = {}
        self.host_of: dict[socket.socket, tuple] = {}
        self.inverted = 0
        self.running = True
        self.thread = threading.Thread(target=self._relay, daemon=True)
        self.thread.start()

    def _invert(self, data: bytes) -> bytes:
        try:
            packet = proto.decode(data)
        except proto.PacketError:
            return data
        if packet.kind != proto.MEASUREMENT:
            return data
        values = dict(packet.fields, load_pressure_pa=-packet.fields["load_pressure_pa"])
        self.inverted += 1
        return proto.encode(packet.kind, packet.session, packet.sequence, packet.time_ns,
                            *(values[name] for name in proto.MEASUREMENT_FIELDS))

    def _relay(self) -> None:
        raise_priority(10)  # this thread's, as the check's: a relay starved by other work trips the rig's watchdog
        while self.running:
            ready, _, _ = select.select([self.front, *self.host_of], [], [], 0.05)
            for sock in ready:
                if sock is self.front:
                    data, host = self.front.recvfrom(2048)
                    if host not in self.back:
                        back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                        back.connect(self.rig)
                        self.back[host], self.host_of[back] = back, host
                    self.back[host].send(data)
                else:
                    try:
                        data = sock.recv(2048)
                    except ConnectionRefusedError:
                        continue
                    self.front.sendto(self._invert(data), self.host_of[sock])

    def close(self) -> None:
        self.running = False
        self.thread.join(1.0)
        for sock in (self.front, *self.host_of):
            sock.close()


class TestStiffSpecimen:
    """The rule of section 4.2 on the sign of load_pressure_pa, with the specimen of ``stiff`` mounted."""

    def test_check_rig_with_motion_passes_with_a_stiff_specimen_mounted(self, stiff):
        """The rest reading at +0.3 mm holds the specimen: the push back lowers P_L from there, and a rule that
        judged its level (or its change from the rest before the first push) failed this correct rig."""
        report = check_rig(stiff.url, motion=True)
        assert report.ok, report.table()
        motion = report.figures["motion"]
        assert motion["force_change_n"] / motion["up_m"] > 40 * 1.25e6  # the specimen is that stiff
        change = motion["pressure_change_pa"]
        assert change["up"] > 10 * change["up_min"] and -change["down"] > 10 * change["down_min"], change
        assert change["up_min"] > MOTION_PRESSURE_MIN_PA  # the noise, seen at rest, raised the bar

    def test_check_rig_with_motion_fails_on_an_inverted_load_pressure_naming_the_rule(self, stiff):
        relay = InvertedPressure(stiff.port)
        try:
            report = check_rig(relay.url, motion=True)
        finally:
            relay.close()
        assert relay.inverted > 500
        # the motion's rows: only the pressure's fails (the relay's own timing, on a loaded machine, can fail a
        # timing row such as 1.1's period; those are not the rig's)
        motion = [r for r in report.results if r.rule.startswith(MOTION_RULES)]
        assert len(motion) == len(MOTION_RULES), report.table()
        failing = [r for r in motion if not r.ok]
        assert len(failing) == 1 and failing[0].section == "§4.2", report.table()
        assert failing[0].rule.startswith("load_pressure_pa") and "sign is inverted" in failing[0].detail, failing


def test_a_load_pressure_that_only_moves_by_its_noise_does_not_pass():
    """pressure_change: a change within the reading's noise is below the bar, whichever its sign."""
    import numpy as np

    noise = np.random.default_rng(1).normal(0.0, PRESSURE_NOISE_PA, 200)
    change, least = pressure_change(list(noise[:20]), list(noise[20:]))
    assert abs(change) < least and least > MOTION_PRESSURE_MIN_PA
    change, least = pressure_change([0.0] * 20, [0.05e5] * 30)  # no noise at all: the floor
    assert least == MOTION_PRESSURE_MIN_PA and change < least


@pytest.fixture
def cli(monkeypatch, capsys):
    """``isorig ARGS...`` in this process (the subprocess's imports cost seconds): (exit code, stdout, stderr)."""
    from isorig.cli import main

    monkeypatch.setattr("sim.realtime.raise_priority", lambda _priority: "normal")  # not the test process's

    def run(*args: str) -> tuple[int, str, str]:
        code = main(list(args))
        out = capsys.readouterr()
        return code, out.out, out.err

    return run


def test_check_rig_says_in_one_line_that_nothing_answers(cli):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    code, out, err = cli("check-rig", f"udp://127.0.0.1:{port}", "--timeout-s", "0.3")
    assert code == 1 and out == "", out + err
    assert err.count("\n") == 1 and "no answer to HELLO" in err and "nothing listens" in err
    code, out, err = cli("check-rig", f"udp://127.0.0.1:{port}", "--supply-bar", "300")
    assert code == 2 and "300 bar is outside the rig's range [10, 210] bar" in err


class TestOthers:
    """The emulators of ``others``: started for this class, stopped when its tests are done."""

    @pytest.mark.parametrize("defect", sorted(BROKEN))
    def test_check_rig_fails_on_a_broken_emulator_naming_the_rule(self, others, defect, cli):
        emulator = others[defect]
        assert emulator.status()["defects"] == [defect]
        if defect != "reply-from-other-port":
            report = check_rig(emulator.url)
            assert matches(failed(report), BROKEN[defect]), report.table()
            return
        code, out, err = cli("check-rig", emulator.url)  # the table, as a lab reads it
        assert code == 1 and err == "", out + err
        rows = [line for line in out.splitlines() if line.startswith("FAIL")]
        assert len(rows) == 1 and rows[0].split()[1] == "§2" and "replies come from the address and port" in rows[0]
        assert "FAILED: §2 replies come from" in out.splitlines()[-1]

    def test_the_emulator_plays_the_rig_of_a_lab_rig_file(self, others):
        lab = others["lab"]
        plant = lab.status()["plant"]
        assert plant["name"] == "Lab B rig"
        assert plant["source"] == f"{others['lab_file']}, --plant-set piston_area_m2=0.02"
        assert plant["changed"] == {"piston_area_m2": 0.02, "max_supply_pa": 150e5, "command_limit_v": 5.0}
        # its ranges are the lab's: the check with the lab's rig file passes (165 bar and 6 V refused), ...
        report = check_rig(lab.url, rig=load_rig_file(others["lab_file"]).parameters)
        assert report.ok, report.table()
        # ... and the host says why an ARM at 160 bar, within isorig's default range, goes unanswered
        rig = UdpRig("127.0.0.1", lab.port, arm_timeout_s=0.3)
        with pytest.raises(RigFault, match=r"answers HELLO but refused the ARM \(160 bar.*outside the rig's own range"):
            rig.arm(ArmConditions(160e5))
        rig.disarm()


def test_an_emulator_that_overruns_its_period_does_not_catch_up(good):
    """Section 1.6: stopped for 60 ms (SIGSTOP), the emulator sends nothing for the lost periods, no burst
    after, numbers on by one, and (its world paused with it) its watchdog does not trip."""
    before = good.status()["counters"]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.connect(("127.0.0.1", good.port))
        sock.settimeout(1.0)
        session = 777
        sock.send(proto.encode(proto.ARM, session, 0, 0, 20e5, 0.0))
        got = []
        while len(got) < 300:
            m = proto.decode(sock.recv(256))
            if m.session != session:
                continue
            got.append(m)
            sock.send(proto.encode(proto.COMMAND, session, m.sequence, 0, 0.0))
            if len(got) == 100:
                os.kill(good.proc.pid, signal.SIGSTOP)
                time.sleep(0.06)
                os.kill(good.proc.pid, signal.SIGCONT)
        sock.send(proto.encode(proto.DISARM, session, 0, 0))
    assert [m.sequence for m in got] == list(range(300))  # +1 each, no gap, nothing twice
    assert all(m.fields["status"] & 1 for m in got)  # armed throughout: the stall did not trip the watchdog
    sent_ms = [(b.time_ns - a.time_ns) / 1e6 for a, b in zip(got, got[1:], strict=False)]
    stall = max(range(len(sent_ms)), key=sent_ms.__getitem__)
    assert 55 < sent_ms[stall] < 200 and 95 <= stall <= 105, sent_ms[stall]
    # no burst of late ones: catching up the ~60 lost periods would send them within a millisecond or two; one
    # period sent late and the next on time (a loaded machine) is not a burst
    after = sent_ms[stall + 1: stall + 21]
    assert sum(after) > 15.0 and sum(gap < 0.5 for gap in after) <= 3, after
    counters = good.fresh_status()["counters"]
    assert counters["overruns"] > before["overruns"] and counters["ticks_lost"] >= before["ticks_lost"] + 50


def test_a_watchdog_trip_in_which_the_rig_overran_is_timed_again_not_judged(tmp_path):
    """A CI run failed "a stale command does not feed the watchdog" on a conforming emulator (median 27.6 ms of
    18.9, 27.6, 30.0): the emulator itself overran for about 10 ms in two of the trips' windows, and the last
    measurement comes when the rig wakes, whatever its valve did. The emulator here overruns 10 ms, 30 ms after
    every other ARM: inside the window of every other trip timed from a last command (ARM, 20 answered periods,
    then the 18 ms), after the trip of one timed from the ARM. Those trips are seen in the rig's clock (time_ns)
    and timed again; the figures are the watchdog's own."""
    emulator = Emulator(tmp_path, "--overrun-ms", "10", name="overrunning", watchdog_ms=18.0)
    try:
        report = check_rig(emulator.url)
        status = emulator.fresh_status()
    finally:
        emulator.stop()
    assert report.ok, report.table()
    assert report.figures["watchdog_trips_retimed_for_rig_stalls"] >= 2, report.figures
    for way in ("last_command", "ARM", "stale_commands"):
        trips = report.figures[f"watchdog_after_{way}_ms"]
        assert len(trips) == 3 and 18.0 <= min(trips) and max(trips) <= 24.0, (way, trips)
    assert status["counters"]["overruns"] >= report.figures["watchdog_trips_retimed_for_rig_stalls"]


# --- protocol 2 --------------------------------------------------------------------------------------------------

@pytest.fixture(scope="class")
def keyed(tmp_path_factory):
    """Emulators speaking protocol 2 with the lab's key: a good one and the ones of V2_BROKEN."""
    path = tmp_path_factory.mktemp("keyed")
    key = auth.write_key_file(path / "lab.key")
    flags = {"good": (), **{name: ("--defect", name) for name in V2_BROKEN}}
    with ThreadPoolExecutor(len(flags)) as pool:
        started = dict(zip(flags, pool.map(lambda item: Emulator(path, "--rig-key-file", str(key), *item[1],
                                                                 name=item[0], watchdog_ms=18.0), flags.items()),
                           strict=True))
    yield started, key
    for emulator in started.values():
        emulator.stop()


class TestProtocol2:
    """The emulators of ``keyed``: started for this class, stopped when its tests are done."""

    def test_check_rig_v2_passes_on_a_keyed_emulator_and_checks_the_authentication(self, keyed, cli):
        emulators, key = keyed
        good = emulators["good"]
        code, out, err = cli("check-rig", good.url, "--rig-key-file", str(key), "--json")
        assert code == 0, failing_rows(out) + err
        report = json.loads(out)
        assert report["ok"] and report["passed"] == len(report["rules"]) >= 40
        assert {"§9.1", "§9.5", "§9.6", "§9.7"} <= {r["section"] for r in report["rules"]}
        status = good.fresh_status()
        assert status["protocol_version"] == 2 and status["authenticated"]
        assert set(V2_DROP_REASONS) <= set(status["rejected"]), status["rejected"]
        assert not status["armed"] and status["command_v"] == 0.0 and abs(status["position_m"]) < 1e-6
        # without the key, the check says in one line that the rig does not answer this host's protocol
        code, out, err = cli("check-rig", good.url, "--rig-protocol", "1", "--timeout-s", "0.3")
        assert code == 1 and "no answer to HELLO" in err and err.count("\n") == 1


    @pytest.mark.parametrize("defect", sorted(V2_BROKEN))
    def test_check_rig_v2_fails_on_a_broken_emulator_naming_the_rule(self, keyed, defect):
        emulators, key = keyed
        report = check_rig(emulators[defect].url, security=auth.resolve_security("127.0.0.1", key))
        assert matches(failed(report), V2_BROKEN[defect]), report.table()
