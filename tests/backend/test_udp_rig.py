"""The real-rig path: the rig protocol, the UDP driver and the rig emulator in its own process, with faults.

Every test here runs ``isorig rig-emulator`` as a separate process in real time and, where a whole test is
run, ``isorig simulate --rig udp://...`` as another: nothing is stepped in-process.
"""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import subprocess
import time

import numpy as np
import pytest
from emulator import ISORIG, Emulator, read_record, simulate_on

from backend.drivers import ArmConditions, RigFault, SimulatedRig
from backend.drivers.check import DriverCheckError, check_driver
from backend.drivers.udp import UdpRig, parse_udp_url, probe
from backend.settings import Settings
from backend.worker import CHECK_PERIODS
from sim.emulator import protocol as proto
from sim.isolator import PRESETS
from sim.measurement import (
    FLAG_LEARNING_HELD,
    FLAG_LOST,
    STATUS_ARMED,
    STATUS_COMMAND_MISSED,
    STATUS_WATCHDOG,
    measured_rows,
)

# real time against the rig emulator in its own process: scripts/test.sh runs these alone, after the others
pytestmark = pytest.mark.realtime

MISSED_PERIODS_MAX = 0.03  # a share of periods: what a loaded CI machine at normal priority may miss on loopback


# --- the protocol --------------------------------------------------------------------------------------------

def test_packets_round_trip_and_every_malformed_one_is_named():
    data = proto.encode(proto.MEASUREMENT, 7, 12, 99, 0.01, 2.0, 3.0, 4.0, STATUS_ARMED, 1, 2, 11, 250, 1_000_000)
    packet = proto.decode(data)
    assert (packet.kind, packet.session, packet.sequence, packet.time_ns) == (proto.MEASUREMENT, 7, 12, 99)
    assert packet.fields["position_m"] == 0.01 and packet.fields["period_ns"] == 1_000_000
    assert len(data) == proto.SIZES[proto.MEASUREMENT] == 84
    command = proto.encode(proto.COMMAND, 7, 12, 5, -3.5)
    assert proto.decode(command).fields == {"command_v": -3.5}
    bad = {
        "short": data[:20],
        "magic": b"XXXX" + data[4:],
        "version": data[:4] + (2).to_bytes(2, "little") + data[6:],
        "kind": data[:6] + (9).to_bytes(2, "little") + data[8:],
        "size": command[:-4] + b"\0" + command[-4:],
        "crc": data[:30] + bytes([data[30] ^ 1]) + data[31:],
    }
    for reason, datagram in bad.items():
        with pytest.raises(proto.PacketError) as exc:
            proto.decode(datagram)
        assert exc.value.reason == reason, (reason, str(exc.value))


@pytest.mark.parametrize("url", ["udp://localhost", "tcp://127.0.0.1:5", "udp://127.0.0.1:99999", "udp://:5"])
def test_udp_urls_are_checked(url):
    with pytest.raises(ValueError, match="udp://"):
        parse_udp_url(url)


# --- the conformance check -------------------------------------------------------------------------------------

def test_the_simulated_rig_conforms():
    report = check_driver(SimulatedRig(PRESETS["IUT_a"]),
                          inject_fault=lambda d: d.plant.state.__setitem__(0, math.nan))
    assert report.ok and len(report.results) > 25


class AcceptsNaN(SimulatedRig):
    def write(self, command_v):
        self.command_v = command_v


class GoesBackwards(SimulatedRig):
    def read(self):
        m = super().read()
        return dataclasses.replace(m, period=m.period - 2 * (m.period % 7 == 3), time_s=m.time_s)


class HangsAfterDisarm(SimulatedRig):
    def wait_next_period(self):
        while not self.armed:
            time.sleep(0.05)
        super().wait_next_period()


class WrongUnits(SimulatedRig):
    def describe(self):
        desc = super().describe()
        channels = tuple(dataclasses.replace(c, unit="mm") if c.name == "position_m" else c for c in desc.channels)
        return dataclasses.replace(desc, channels=channels)


@pytest.mark.parametrize(("driver_class", "failure"), [
    (AcceptsNaN, "write(nan V) is refused"), (GoesBackwards, "never backwards"),
    (HangsAfterDisarm, "never hangs"), (WrongUnits, "SI units"),
])
def test_the_check_finds_a_driver_that_does_not_conform(driver_class, failure):
    with pytest.raises(DriverCheckError, match=r"(?s)FAIL.*" + failure.replace("(", r"\(").replace(")", r"\)")):
        check_driver(driver_class(PRESETS["IUT_a"]), periods=50, fault_timeout_s=0.5)


def test_the_udp_driver_conforms_against_the_emulator_process(tmp_path):
    emulator = Emulator(tmp_path)
    try:
        report = check_driver(UdpRig("127.0.0.1", emulator.port), inject_fault=lambda d: emulator.kill())
        assert report.ok, str(report)
        assert "RigFault" in str(report) or "link lost" in str(report)
    finally:
        emulator.stop()


def test_probe_says_whether_the_rig_answers(tmp_path):
    emulator = Emulator(tmp_path)
    try:
        answer = probe(emulator.url)
        assert answer["connected"] and not answer["armed"] and answer["period_s"] == pytest.approx(1e-3)
    finally:
        emulator.stop()
    answer = probe(emulator.url, timeout_s=0.1)
    assert answer["connected"] is False and "nothing listens at 127.0.0.1" in answer["detail"]


# --- whole tests through the emulator ------------------------------------------------------------------------

def settled_tracking(record: dict) -> tuple[float, int]:
    """RMS |y - r| over the amplitude (10 mm) in the last two full cycles (2.5-3.5 s of the 8-cycle sine), over
    the rows whose measurement arrived and where the loop was not settling from a stall (FLAG_LEARNING_HELD: on a
    shared machine the host stalls now and then, and the table's error after a stall is the stall's, not the
    controller's); and how many rows that is."""
    t, flags = record["time_s"], record["flags"].astype(int)
    rows = (t >= 2.5 - 1e-9) & (t < 3.5 - 1e-9) & measured_rows(flags) & (flags & FLAG_LEARNING_HELD == 0)
    e = record["displacement_m"][rows] - record["target_m"][rows]
    return float(np.sqrt(np.mean(e * e)) / 0.01), int(np.count_nonzero(rows))


def local_tracking(tmp_path) -> float:
    code, local, _ = simulate_on("simulated", tmp_path / "local", cycles=8)
    assert code == 0
    return local["last_two_cycles"]["rms_y_minus_r_over_amplitude"]


def test_a_test_through_the_emulator_completes_and_tracks_like_the_simulated_rig(tmp_path):
    emulator = Emulator(tmp_path)
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "udp", cycles=8)  # the learning converges
    finally:
        status = emulator.stop()
    assert code == 0, output
    assert summary["status"] == "completed" and summary["reason"] is None and summary["rig"] == emulator.url
    record = read_record(tmp_path / "udp")
    assert len(record["time_s"]) == 4000 and np.all(np.diff(record["time_s"]) > 0)
    assert np.array_equal(record["displacement_m"], record["measured_displacement_m"])  # a real rig: the reading
    missed = np.count_nonzero(record["flags"].astype(int) & STATUS_COMMAND_MISSED)
    assert missed <= MISSED_PERIODS_MAX * 4000
    assert status["counters"]["arms"] == 1 and status["counters"]["disarms"] == 1 and not status["armed"]
    # what the emulator had loaded is frozen: a full collection over it stalled the rig's ticks by 9-12 ms
    assert status["collector"]["frozen_objects"] > 10_000, status["collector"]
    assert summary["link"]["received"] >= 3980 and summary["link"]["round_trip_p50_ms"] < 1.0
    through, rows = settled_tracking(record)
    assert rows >= 500, f"the host stalled through {1000 - rows} of the last 1000 periods: too disturbed to compare"
    assert abs(through - local_tracking(tmp_path)) < 1e-3  # 0.1 % of amplitude


def test_a_host_stalled_now_and_then_tracks_on_once_settled(tmp_path):
    """The link silent for 15 ms every 0.7 s (the emulator's outage: what a host stalled that long looks like): the
    rig holds its last command meanwhile and the table falls behind. The controller learns nothing from the error
    that follows (FLAG_LEARNING_HELD); once settled the table tracks as without the stalls. Before the hold, the
    settled rows of the last two cycles were 0.29 % off against 0.17 % (one run)."""
    emulator = Emulator(tmp_path, "--outage-every-s", "0.7", "--outage-ms", "15")
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "udp", cycles=8)
    finally:
        status = emulator.stop()
    assert code == 0, output
    # no trip in the test (a DISARM that falls into an outage is lost as on a real link: the watchdog then ends it)
    assert summary["status"] == "completed" and all(t["test_time_s"] > 4.0 for t in status["watchdog_trips"])
    # five outages (at 0.7-3.5 s of the 4 s test) of 14-15 ticks each (the 1 kHz ticks' phase against the 15 ms
    # window): each tick's measurement is dropped; the host answers measurements only, so few commands fall in one
    # (a clean-clone run dropped 73, which 5 * 15 failed); a tick the emulator itself lost to an overrun (its loop
    # late by a period or more) sends nothing to drop, so each lost tick may stand for one (a clean-clone run on a
    # noisy machine: 68 dropped)
    counters = status["counters"]
    assert counters["outage_dropped"] + counters["ticks_lost"] >= 5 * 14 and counters["outage_dropped"] >= 5 * 10
    record = read_record(tmp_path / "udp")
    flags = record["flags"].astype(int)
    lost = np.flatnonzero(flags & FLAG_LOST)
    assert len(lost) >= 5 * 14 and np.all(flags[lost] & FLAG_LEARNING_HELD)
    through, rows = settled_tracking(record)
    assert rows >= 500, f"only {rows} of the last 1000 periods settled"
    assert abs(through - local_tracking(tmp_path)) < 1e-3  # 0.1 % of amplitude


def test_link_silent_longer_than_the_timeout(tmp_path):
    """The link drops: the test fails with the reason, every sample before is kept, the rig's own watchdog
    closes the valve."""
    emulator = Emulator(tmp_path, "--drop-link-after-s", "0.6")
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "out", cycles=6)
        status = emulator.fresh_status()
    finally:
        emulator.stop()
    assert code == 1, output
    assert summary["status"] == "failed" and "link lost" in summary["reason"]
    record = read_record(tmp_path / "out")
    n = len(record["time_s"])
    # up to the drop, nothing after it: 0.6 s of the rig's ticks, less any it lost to its own overruns (a clean-clone
    # CI run on a noisy machine: 544 rows)
    dropped_at = status["counters"]["link_dropped_at_sequence"]
    assert 600 - status["counters"]["ticks_lost"] - 5 <= dropped_at <= 605
    assert dropped_at - 5 <= n <= dropped_at + 1
    np.testing.assert_allclose(record["time_s"], np.arange(n) * 1e-3, atol=1e-9)
    assert [e["kind"] for e in summary["events"]] == ["rig_fault"]
    trip = status["watchdog_trips"]
    assert len(trip) == 1 and trip[0]["after_last_command_ms"] <= emulator.watchdog_ms + 2.0
    assert status["command_v"] == 0.0 and not status["armed"]


def test_one_percent_packet_loss_goes_on_and_flags_the_lost_periods(tmp_path):
    emulator = Emulator(tmp_path, "--packet-loss-pct", "1", "--seed", "7")
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "out", cycles=4)
        status = emulator.stop()
    finally:
        emulator.stop()
    assert code == 0 and summary["status"] == "completed", output
    flags = read_record(tmp_path / "out")["flags"].astype(int)
    lost = int(np.count_nonzero(flags & FLAG_LOST))
    assert lost == summary["lost_periods"] >= 5  # about 1 % of 2000 measurements never arrived
    assert status["counters"]["measurements_dropped"] >= 5 and status["counters"]["incoming_dropped"] >= 5
    assert summary["link"]["lost"] >= status["counters"]["measurements_dropped"] - 2
    assert summary["last_two_cycles"]["rms_y_minus_r_over_amplitude"] < 0.01


def test_a_restarted_rig_moves_nothing_until_a_new_test(tmp_path):
    emulator = Emulator(tmp_path, "--restart-after-s", "0.6")
    try:
        code, summary, _ = simulate_on(emulator.url, tmp_path / "out", cycles=6)
        first = emulator.fresh_status()
        time.sleep(0.5)
        later = emulator.fresh_status()
        code2, summary2, output2 = simulate_on(emulator.url, tmp_path / "again", cycles=3)
        refused_at = emulator.status()["position_m"]
        moved = subprocess.run([*ISORIG, "move", "--rig", emulator.url, "--speed-m-per-s", "0.02"],
                               capture_output=True, text=True, timeout=60)
        zeroed = emulator.fresh_status()
        code3, summary3, output3 = simulate_on(emulator.url, tmp_path / "third", cycles=3)
    finally:
        emulator.stop()
    assert code == 1 and summary["status"] == "failed" and "link lost" in summary["reason"]
    assert first["counters"]["restarts"] == 1 and not first["armed"] and first["command_v"] == 0.0
    assert later["position_m"] == pytest.approx(first["position_m"], abs=1e-6)  # the table stays where it is
    assert abs(first["position_m"]) > 0.005  # mid-stroke: the restart came at the peak of a cycle
    # every test's target starts at zero: from mid-stroke the controller would drive the table back at full
    # flow, so no test starts until the table is back at zero; nothing moved
    assert code2 == 2 and "the table is at" in output2 and "nothing moved" in output2, output2
    assert refused_at == pytest.approx(first["position_m"], abs=1e-6)
    # isorig move brings it back to zero under control, and the next test runs
    assert moved.returncode == 0 and "move completed" in moved.stdout, moved.stdout + moved.stderr
    assert abs(zeroed["position_m"]) < 5e-4 and not zeroed["armed"] and zeroed["command_v"] == 0.0
    assert code3 == 0 and summary3["status"] == "completed", output3


def test_an_emulator_process_killed_and_started_again_mid_test(tmp_path):
    emulator = Emulator(tmp_path, name="first")
    run = simulate_on(emulator.url, tmp_path / "out", cycles=8, wait=False)
    try:
        deadline = time.monotonic() + 60
        while not (emulator.status()["armed"] and emulator.status()["sequence"] > 1000):  # a second into the test
            assert time.monotonic() < deadline and run.poll() is None, "the test did not start"
            time.sleep(0.1)
        emulator.kill()
        second = Emulator(tmp_path, port=emulator.port, name="second")
        output, _ = run.communicate(timeout=60)
        status = second.fresh_status()
        second.stop()
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 1, output
    assert "failed" in output and "link lost" in output
    assert status["counters"]["arms"] == 0 and not status["armed"] and status["command_v"] == 0.0
    assert len(read_record(tmp_path / "out")["time_s"]) > 200


@pytest.mark.parametrize(("fault", "detector", "words"), [
    ("nan", "non_finite", "non-finite"),
    ("out-of-range", "sensor_range", "out of range"),
    ("stuck", "position_frozen", "stuck sensor"),
])
def test_a_sensor_fault_closes_the_valve_at_once(tmp_path, fault, detector, words):
    """A reading that cannot be trusted: the command computed from it is not ramped from, the valve command
    is 0 V from the next period, and the true table (the emulator's) stays near the test's range."""
    emulator = Emulator(tmp_path, "--sensor-fault", fault, "--sensor-fault-after-s", "0.5")
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "out", cycles=6)
        table_m = emulator.fresh_status()["position_m"]
    finally:
        emulator.stop()
    assert code == 1 and summary["status"] == "aborted" and words in summary["reason"], output
    trips = [e for e in summary["events"] if e["kind"] == "limit_trip"]
    assert len(trips) == 1 and trips[0]["values"]["detector"] == detector
    record = read_record(tmp_path / "out")
    after = record["time_s"] > trips[0]["values"]["time_s"]
    tail = record["voltage_v"][after][CHECK_PERIODS:]  # the rest of the block in which the detectors found it
    assert tail.size > 0 and np.all(tail == 0.0), record["voltage_v"][after][:40]
    assert 0.5 < record["time_s"][-1] < 1.0  # stopped soon after the fault
    # 10 mm test: no run-away on a wrong reading (periods lost on a loaded host do not count towards the frozen
    # reading, so it may be found a few periods later)
    assert abs(table_m) < 0.025, table_m


def test_supply_pressure_loss_trips_a_controlled_stop(tmp_path):
    emulator = Emulator(tmp_path, "--supply-loss-after-s", "0.5")
    try:
        code, summary, output = simulate_on(emulator.url, tmp_path / "out", cycles=6)
    finally:
        emulator.stop()
    assert code == 1 and summary["status"] == "aborted" and "supply pressure lost" in summary["reason"], output
    assert 0.5 < read_record(tmp_path / "out")["time_s"][-1] < 1.0


# --- packets that must never be applied ---------------------------------------------------------------------------

def test_bad_commands_never_reach_the_emulators_valve(tmp_path):
    emulator = Emulator(tmp_path)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.connect(("127.0.0.1", emulator.port))
            sock.settimeout(1.0)
            session = 4242
            sock.send(proto.encode(proto.ARM, session, 0, 0, 100e5, 1.25e5))
            m = proto.decode(sock.recv(256))
            assert m.session == session and m.fields["status"] & STATUS_ARMED
            seq = m.sequence
            good = proto.encode(proto.COMMAND, session, seq, 0, 0.0)
            wrong_version = bytearray(proto.encode(proto.COMMAND, session, seq, 0, 9.0))
            wrong_version[4] = 2
            damaged = bytearray(proto.encode(proto.COMMAND, session, seq, 0, 9.0))
            damaged[30] ^= 0xFF
            for datagram in (bytes(wrong_version), bytes(damaged), good[:20],
                             proto.encode(proto.COMMAND, session + 1, seq, 0, 9.0),  # another session
                             proto.encode(proto.COMMAND, session, seq + 50, 0, 9.0),  # a future period
                             proto.encode(proto.COMMAND, session, seq, 0, math.nan),
                             good, good,  # the valid one, then the same packet again
                             proto.encode(proto.COMMAND, session, seq, 0, 9.0),  # stale: that period is answered
                             proto.encode(proto.DISARM, session, 0, 0)):  # at once, before the watchdog
                sock.send(datagram)
        status = emulator.fresh_status()
    finally:
        emulator.stop()
    rejected = status["rejected"]
    assert rejected == {"version": 1, "crc": 1, "short": 1, "session": 1, "future": 1, "value": 1, "stale": 2}
    assert status["counters"]["commands_applied"] == 1  # the valid 0 V command only
    assert status["command_v"] == 0.0 and abs(status["position_m"]) < 1e-6  # no 9 V ever reached the valve


def test_the_emulator_checks_a_packet_in_the_order_the_protocol_settles():
    """docs/rig-protocol.md sections 3 and 5, in-process (no timing): the first failing check names the drop,
    '10 periods old' is exact, ARMs and DISARMs again, and what a HELLO answer carries armed and unarmed."""
    from sim.emulator.server import EmulatorConfig, RigEmulator

    rig = RigEmulator(EmulatorConfig(PRESETS["IUT_a"], 0))
    host = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    host.bind(("127.0.0.1", 0))
    host.settimeout(1.0)
    addr = host.getsockname()

    def send(kind, session, sequence, *payload):
        rig.receive(proto.encode(kind, session, sequence, 0, *payload), addr, time.perf_counter())

    def hello():
        send(proto.HELLO, 0, 0)
        return proto.decode(host.recv(256))

    def dropped(kind, session, sequence, *payload):
        before = dict(rig.rejected)
        send(kind, session, sequence, *payload)
        return {k: v - before.get(k, 0) for k, v in rig.rejected.items() if v != before.get(k, 0)}

    try:
        assert dropped(proto.COMMAND, 7, 0, 0.0) == {"session": 1}  # unarmed: every command
        assert dropped(proto.ARM, 0, 0, 100e5, 0.0) == {"arm": 1}  # session 0
        assert dropped(proto.ARM, 7, 0, 300e5, 0.0) == {"arm": 1}  # beyond 210 bar
        assert dropped(proto.ARM, 7, 0, 100e5, math.nan) == {"arm": 1}
        unarmed = hello()
        assert (unarmed.session, unarmed.sequence, unarmed.fields["packets_rejected"]) == (0, 0, 4)
        assert not unarmed.fields["status"] & STATUS_ARMED
        assert dropped(proto.ARM, 7, 0, 100e5, 0.0) == {} and rig.armed and rig.rejected_count == 0  # from zero
        rig.sequence, rig.last_applied_seq = 20, 5  # as if measurements 0-20 were sent and 5 answered
        assert dropped(proto.ARM, 7, 0, 150e5, 1e5) == {} and rig.sequence == 20  # repeated: ignored
        assert rig.supply_set_pa == 100e5  # the first ARM's conditions hold
        assert dropped(proto.ARM, 8, 0, 100e5, 0.0) == {"busy": 1}
        assert dropped(proto.ARM, 8, 0, 300e5, 0.0) == {"arm": 1}  # the range is checked before busy
        armed = hello()
        assert (armed.session, armed.sequence) == (7, 20) and armed.fields["status"] & STATUS_ARMED
        assert armed.fields["packets_rejected"] == 2
        # a COMMAND: session, stale (not newer), future, stale (age), value, in that order
        assert dropped(proto.COMMAND, 8, 99, math.nan) == {"session": 1}
        assert dropped(proto.COMMAND, 7, 5, math.nan) == {"stale": 1}  # not newer than the one applied
        assert dropped(proto.COMMAND, 7, 21, math.nan) == {"future": 1}
        assert dropped(proto.COMMAND, 7, 9, 0.0) == {"stale": 1}  # 11 periods old (the latest is 20)
        assert dropped(proto.COMMAND, 7, 10, math.nan) == {"value": 1}  # 10 periods old: only its value is wrong
        assert dropped(proto.COMMAND, 7, 10, 0.0) == {} and rig.pending[2] == 10  # 10 periods old: applied
        assert dropped(proto.COMMAND, 7, 10, 0.0) == {"stale": 1}  # the same again: not newer than the pending
        assert dropped(proto.DISARM, 8, 0) == {"session": 1} and rig.armed
        assert dropped(proto.DISARM, 7, 0) == {} and not rig.armed
        assert dropped(proto.DISARM, 7, 0) == {}  # the host's second and third DISARM: ignored, not counted
        assert dropped(proto.COMMAND, 7, 20, 0.0) == {"session": 1}  # unarmed again
        after = hello()
        assert (after.session, after.sequence) == (0, 0) and not after.fields["status"] & STATUS_ARMED
        assert after.fields["packets_rejected"] == 10 and after.fields["command_sequence"] == 5  # the last test's
        assert dropped(proto.ARM, 7, 0, 100e5, 0.0) == {} and rig.armed and rig.sequence == -1  # anew, from 0
        # section 1.3: measurement n + 1 carries COMMAND_MISSED; 1.5: the watchdog runs from ARM, its last measurement
        rig.after_tick(time.perf_counter())
        first = proto.decode(host.recv(256))
        assert (first.session, first.sequence) == (7, 0) and not first.fields["status"] & STATUS_COMMAND_MISSED
        rig.after_tick(time.perf_counter())  # nothing answered measurement 0
        second = proto.decode(host.recv(256))
        assert second.sequence == 1 and second.fields["status"] & STATUS_COMMAND_MISSED
        assert second.fields["commands_missed"] == 1 and second.fields["command_sequence"] == 0
        rig.after_tick(rig.last_command_time + 0.0185)  # 18.5 ms since the ARM, no command
        final = proto.decode(host.recv(256))
        assert (final.session, final.sequence) == (7, 2) and not rig.armed and rig.command_v == 0.0
        status = final.fields["status"]
        assert status & STATUS_WATCHDOG and status & STATUS_COMMAND_MISSED and not status & STATUS_ARMED
        latched = hello()
        assert latched.session == 0 and latched.fields["status"] & STATUS_WATCHDOG  # until the next ARM
        assert dropped(proto.ARM, 9, 0, 100e5, 0.0) == {} and not hello().fields["status"] & STATUS_WATCHDOG
    finally:
        rig.close()
        host.close()


class FakeRig:
    """A rig played by the test: answers ARM with a good measurement, then sends what the test says."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(2.0)
        self.port = self.sock.getsockname()[1]

    def measurement(self, session, seq, position_m, version=None, crc_ok=True):
        data = bytearray(proto.encode(proto.MEASUREMENT, session, seq, 0, position_m, 0.0, 0.0, 100e5, STATUS_ARMED,
                                      0, 0, 0, 0, 1_000_000))
        if version is not None:
            data[4] = version
        if not crc_ok:
            data[-1] ^= 0xFF
        return bytes(data)


def test_bad_measurements_never_reach_the_loop():
    rig = FakeRig()
    driver = UdpRig("127.0.0.1", rig.port, timeout_s=1.0)
    try:
        import threading

        def play():
            data, host = rig.sock.recvfrom(256)
            arm = proto.decode(data)
            s = arm.session
            rig.sock.sendto(rig.measurement(s, 0, 0.001), host)
            time.sleep(0.1)  # the driver is armed and waits for period 1
            for datagram in (rig.measurement(s, 1, 0.5, version=2), rig.measurement(s, 1, 0.5, crc_ok=False),
                             rig.measurement(s + 1, 1, 0.5), rig.measurement(s, 0, 0.5),  # another session, stale
                             rig.measurement(s, 1, 0.002), rig.measurement(s, 1, 0.5)):  # good, then a duplicate
                rig.sock.sendto(datagram, host)

        player = threading.Thread(target=play)
        player.start()
        driver.arm(ArmConditions(100e5))
        assert driver.read().position_m == 0.001
        driver.write(0.0)
        time.sleep(0.2)  # everything has arrived
        driver.wait_next_period()
        m = driver.read()
        player.join()
        assert (m.period, m.position_m) == (1, 0.002)  # none of the 0.5 m readings was used
        assert driver.link_stats()["rejected_by_reason"] == {"version": 1, "crc": 1, "session": 1, "stale": 2}
        with pytest.raises(RigFault, match="link lost"):
            driver.wait_next_period()  # the fake rig is silent now
    finally:
        driver.disarm(success=False)
        rig.sock.close()


# --- the service on a UDP rig ------------------------------------------------------------------------------------

def test_the_service_runs_a_test_on_the_emulator_and_shows_the_link(tmp_path):
    from conftest import AUTH, make_settings, sine_test, wait_for
    from fastapi.testclient import TestClient

    from backend.app import create_app

    emulator = Emulator(tmp_path)
    try:
        with TestClient(create_app(make_settings(tmp_path, rig=emulator.url))) as client:
            rig = client.get("/api/rig").json()
            assert rig["rig"]["kind"] == "udp" and rig["rig"]["port"] == emulator.port
            assert rig["rig"]["control_period_s"] == 1e-3 and rig["rig"]["link_timeout_s"] == 0.05
            assert rig["link"]["connected"] and not rig["link"]["armed"]
            state = client.get("/api/rig/state").json()  # idle: where the rig says its table is
            assert state["status"] == "idle" and state["position_source"] == "the rig (probe)"
            assert abs(state["table_position_m"]) < 1e-3 and state["supply_pressure_pa"] >= 0 and not state["armed"]
            assert state["force_source"] == "the rig (probe)" and math.isfinite(state["force_n"])  # the rig's own
            assert state["command_v"] == 0.0 and "valve is closed" in state["command_source"]  # not armed
            assert emulator.fresh_status()["command_v"] == 0.0  # as the rig has it
            r = client.post("/api/tests", json=sine_test(speed=2.0), headers=AUTH)
            assert r.status_code == 422 and "real time" in r.json()["detail"]  # no faster than real time
            r = client.post("/api/tests", json=sine_test(speed=1.0, vertical_load_n=3e5), headers=AUTH)
            assert r.status_code == 201 and r.json()["driver"] == emulator.url
            test_id = r.json()["id"]
            assert client.post(f"/api/tests/{test_id}/start", headers=AUTH).status_code == 200
            deadline = time.monotonic() + 30  # the worker starts in a few seconds under pytest
            while True:
                live = client.get("/api/rig/link").json()
                if live.get("armed") and live.get("last_sequence", 0) > 100 or time.monotonic() > deadline:
                    break
                time.sleep(0.05)
            assert live["armed"] and live["test_id"] == test_id and live["last_sequence"] > 100, live
            assert live["round_trip_p50_ms"] < 1.0 and "lost" in live and "rejected" in live
            state = client.get("/api/rig/state").json()
            assert state["status"] == "running" and state["position_source"] == "live" and state["armed"]
            record = wait_for(client, test_id)
            assert record["status"] == "completed", record["reason"]
            assert record["samples_stored"] == 1500
            summary = record["summary"]
            assert summary["lost_periods"] >= 0 and summary["link"]["received"] >= 1490
            assert summary["link"]["rig"] == emulator.url and summary["pacing"]["realtime_rig"] is True
            idle = client.get("/api/rig/link").json()
            assert idle["armed"] is False and idle["last_test"]["test_id"] == test_id
            assert idle["last_test"]["received"] >= 1490
            emulator.stop()
            gone = client.get("/api/rig/state").json()
            assert gone["status"] == "not_connected"
            assert "no answer" in gone["detail"] or "nothing listens" in gone["detail"]
            assert gone["position_source"] == f"end of test {test_id} (completed)"  # the last known position
            # ... but no force or command: the rig's of before are not its now
            assert gone["force_n"] is None and gone["force_source"].startswith("no reading: the rig does not answer")
            assert gone["command_v"] is None and gone["command_source"].startswith("no reading")
    finally:
        status = emulator.stop()
    assert status["vertical_load_n"] == 3e5 and status["supply_pa"] == 100e5  # ARM carried the conditions


def test_the_service_starts_no_test_while_the_rigs_table_is_off_zero(tmp_path):
    from conftest import AUTH, make_settings, sine_test, wait_for
    from fastapi.testclient import TestClient

    from backend.app import create_app

    emulator = Emulator(tmp_path, "--restart-after-s", "0.6")  # the rig restarts mid-cycle: table left mid-stroke
    try:
        with TestClient(create_app(make_settings(tmp_path, rig=emulator.url))) as client:
            r = client.post("/api/tests?start=true", json=sine_test(speed=1.0, profile={"cycles": 6}), headers=AUTH)
            assert r.status_code == 201, r.text
            first = wait_for(client, r.json()["id"])
            assert first["status"] == "failed"
            position = emulator.fresh_status()["position_m"]
            # beyond the start tolerance (2 mm) with room to spare: the restart at 0.6 s of wall time leaves the table
            # about 5 mm out, less where the emulator itself overran meanwhile (its world pauses; a clean-clone run on
            # a noisy machine: 4.58 mm)
            assert abs(position) > 2 * Settings.model_fields["rig_start_tolerance_m"].default
            state = client.get("/api/rig/state").json()
            assert state["table_position_m"] == pytest.approx(position, abs=1e-6)
            r = client.post("/api/tests?start=true", json=sine_test(speed=1.0), headers=AUTH)
            assert r.status_code == 409 and f"the table is at {position * 1e3:.2f} mm" in r.json()["detail"]
            assert "nothing moved" in r.json()["detail"]
            assert [t["id"] for t in client.get("/api/tests").json()] == [first["id"]]  # nothing left behind
            assert emulator.fresh_status()["position_m"] == pytest.approx(position, abs=1e-6)
            # the operator brings the table back to zero through the same link, then the test runs
            r = client.post("/api/rig/zero", json={"speed_m_per_s": 0.02, "isolator": "IUT_a", "supply_bar": 100},
                            headers=AUTH)
            assert r.status_code == 201, r.text
            assert f"manual move {position * 1e3:.2f} mm -> 0.00 mm" in r.json()["label"]
            moved = wait_for(client, r.json()["id"])
            assert moved["status"] == "completed", moved["reason"]
            assert abs(emulator.fresh_status()["position_m"]) < 5e-4 and not emulator.status()["armed"]
            r = client.post("/api/tests?start=true", json=sine_test(speed=1.0), headers=AUTH)
            assert r.status_code == 201, r.text
            assert wait_for(client, r.json()["id"])["status"] == "completed"
    finally:
        emulator.stop()


def test_hybrid_simulation_on_the_emulator_matches_its_reference(tmp_path):
    """RTHS through the driver protocol: the building in the computer, the isolator on the rig emulator in its
    own process, in real time; J1-J5 as on the simulated rig."""
    t = np.arange(0.0, 3.0, 0.01)
    acc = 0.75 * np.sin(2 * np.pi * 1.0 * t) * np.sin(np.pi * t / 3.0) ** 2  # a 3 s burst, peak 0.076 g
    motion = tmp_path / "burst.csv"
    rows = "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(t, acc, strict=True))
    motion.write_text("time_s,acceleration_m_per_s2\n" + rows)
    emulator = Emulator(tmp_path, isolator="IUT_b")
    try:
        out = subprocess.run([*ISORIG, "hybrid", "--structure", "docs/examples/structure_3_storey.json",
                              "--ground-motion", str(motion), "--isolator", "IUT_b", "--supply-bar", "100",
                              "--rig", emulator.url, "--out", str(tmp_path / "out")],
                             capture_output=True, text=True, timeout=120)
    finally:
        emulator.stop()
    assert out.returncode == 0, out.stdout + out.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "completed", summary["reason"]
    j = summary["criteria"]
    # measured (IUT_b, 21 mm, 0.14 m/s peak: a third of the pump's 0.39 m/s, so that the velocity detector's
    # estimate across a few lost packets stays below its limit): J1 0.28 ms, J2 0.30 %, J3 0.50 %, J4 0.10 %,
    # J5 0.11 % (the simulated rig: 0.29 ms, 0.28 %, 0.47 %, 0.08 %, 0.08 %). A stall of this shared VM loses
    # periods; their rows hold an older reading, which J2 and J3 leave out (they read 5.6 % on a hogged run that
    # lost 12 periods at full speed, 0.50 % over the periods measured), so all are held to the targets
    assert abs(j["j1_delay_ms"]) <= 1.0 and j["j2_rms_percent"] <= 1.0 and j["j4_rms_percent"] <= 2.0, j
    assert j["j3_peak_percent"] <= 3.0 and j["j5_peak_percent"] <= 3.0, j
    assert isinstance(summary["lost_periods"], int) and summary["lost_periods"] >= 0
