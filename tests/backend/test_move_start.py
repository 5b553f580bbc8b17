"""A manual move starts gently from rest where the table reads at arming (not from an older reading), and a table
that runs away from a move anyway is stopped by the move guard, valve closed, before the rig's velocity limit
(sim.motion.MoveGuard, backend.worker.Run.start_move_where_read). Against the simulated rig in this process and
the rig emulator in its own process."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from emulator import Emulator

from backend.worker import WORKER_RR_PRIORITY, AbortSwitch, Collector, Run
from foreign_rigs import draw_rig
from isorig.commands.rig_run import resting_position_m, rig_job
from sim.commission.foreign_campaign import declared_rig
from sim.engine import Scenario
from sim.isolator import PRESETS
from sim.motion import MOVE_GUARD, move_guard_m_per_s, move_target
from sim.realtime import realtime_priority
from sim.rig import DEFAULT_RIG
from sim.safety import default_limits, measured_velocity, velocity_readings

#: what a move that starts at rest and follows its target may reach: its speed twice over plus 2 mm/s (a table
#: that follows peaks within a few % of the speed; the start transient reached 56.8 mm/s on a 5 mm/s move)
MARGIN_FACTOR, MARGIN_M_PER_S = 2.0, 0.002
LATE = {"position_latency_s": 0.0015}  # a late position reading: the sensors keep a delay line


def peak_velocity_m_per_s(samples) -> float:
    """The largest measured |velocity| of a move's closed-loop periods (as the limits judge it: 5 ms of readings)."""
    v = measured_velocity(velocity_readings(samples))
    return float(np.nanmax(np.abs(v)))


def move_job(rig_url: str, rig, start_m: float, end_m: float, speed_m_per_s: float, **job) -> dict:
    scenario = Scenario(PRESETS["IUT_a"], 1e7, [], "servo", rig=rig, history=move_target(start_m, end_m, speed_m_per_s))
    motion = {"start_m": start_m, "end_m": end_m, "speed_m_per_s": speed_m_per_s}
    return {**rig_job(rig_url, scenario, motion=motion, history_target=None), **job}


def test_a_move_planned_from_an_older_reading_starts_at_rest_where_the_table_is():
    """The table moved since the move was asked (it rests 1 mm from where it read then, within the 2 mm start
    tolerance): the move starts where it reads at arming. Planned from the older reading, the servo closed a 1 mm
    step first (66 mm/s on this rig, then an oscillation)."""
    lab = {"mass_kg": 3000.0, "bulk_modulus_pa": 4.5e8, "valve_natural_frequency_rad_s": 300.0}
    rig = DEFAULT_RIG.with_changes(**lab)  # told exactly (a commissioned rig)
    for planned_m, table_m in ((0.002, 0.001), (-0.0005, 0.0005)):
        job = move_job("simulated", rig, planned_m, 0.0, 0.005, table_position_m=table_m, speed=1000.0)
        out = Collector()
        status, reason = Run(job, out, AbortSwitch()).execute()
        s = out.samples()
        assert status == "completed", reason
        assert s["target_m"][0] == pytest.approx(table_m, abs=1e-9)  # the target begins where the table is
        assert peak_velocity_m_per_s(s) < MARGIN_FACTOR * 0.005 + MARGIN_M_PER_S
        assert abs(s["measured_displacement_m"][-1]) < 5e-5
        started = [e for k, e in out.messages if k == "event" and e["values"].get("planned_start_m") is not None]
        assert len(started) == 1 and started[0]["values"]["start_m"] == pytest.approx(table_m)


class StopAfter(Collector):
    """What a run sends, kept; the operator's stop ``stop_after_s`` after the run has started (None: none)."""

    def __init__(self, switch: AbortSwitch, stop_after_s: float | None):
        super().__init__()
        self.switch, self.stop_after_s = switch, stop_after_s

    def send(self, message) -> None:
        super().send(message)
        if message[0] == "started" and self.stop_after_s is not None:
            threading.Timer(self.stop_after_s, self.switch.pending.append, ("stop",)).start()


def run_move(url: str, rig, end_m: float, speed_m_per_s: float, stop_after_s: float | None = None,
             planned_m: float | None = None):
    """A move on the rig at ``url`` from where its table rests (one HELLO, as ``isorig move``), in this process:
    (status, reason, samples, the resting position read before, the limit trips). ``stop_after_s``: the operator's
    stop then; ``planned_m``: where the move is planned from, instead of the resting reading."""
    start_m = resting_position_m("move", url) if planned_m is None else planned_m
    switch = AbortSwitch()
    sent = StopAfter(switch, stop_after_s)
    run = Run(move_job(url, rig, start_m, end_m, speed_m_per_s), sent, switch)
    with realtime_priority(WORKER_RR_PRIORITY):  # as isorig move runs it (backend.worker.run_here)
        status, reason = run.execute()
    trips = [e for e in sent.of_kind("event") if e["kind"] == "limit_trip"]
    return status, reason, sent.samples(), start_m, trips


@pytest.mark.realtime
def test_a_move_from_where_a_stop_left_the_table_starts_at_rest_on_the_emulator(tmp_path):
    """A rig with a late position reading (a delay line in its sensors): a 20 mm/s move stopped part way, then a
    5 mm/s move back. The rig's readings after the pause between them are the table's, not what its delay line
    held from before the pause (it read up to 2 mm off, so the move was planned from a stale position and its
    first readings jumped), and the move back stays near its speed from its first period."""
    rig = DEFAULT_RIG.with_changes(**LATE)
    emulator = Emulator(tmp_path, *[f"--plant-set={k}={v}" for k, v in LATE.items()])
    try:
        status, reason, first, _, _ = run_move(emulator.url, rig, 0.02, 0.02, stop_after_s=0.6)
        assert status == "stopped", reason
        assert 0.002 < first["measured_displacement_m"][-1] < 0.018  # stopped part way
        for _ in range(2):  # two pauses of different lengths: a stale reading shows at most phases of the pause
            time.sleep(0.7)
            status, reason, back, rested_m, _ = run_move(emulator.url, rig, 0.0, 0.005)
            assert status == "completed", reason
            y = back["measured_displacement_m"]
            assert abs(y[0] - rested_m) < 2e-5  # the resting reading is where the table is
            assert np.max(np.abs(y[:20] - y[0])) < 2e-5  # and the first readings do not jump: it is at rest
            assert back["target_m"][0] == pytest.approx(y[0], abs=1e-9)
            peak = peak_velocity_m_per_s(back)
            assert peak < MARGIN_FACTOR * 0.005 + MARGIN_M_PER_S, peak
            status, reason, _, _, _ = run_move(emulator.url, rig, 0.008, 0.02, stop_after_s=0.5)
            assert status == "stopped", reason
        # a table that moved since the move was asked (here: the move planned 0.5 mm off where it rests): the move
        # is planned again from the reading at arming, the valve held at 0 V meanwhile
        rested_m = resting_position_m("move", emulator.url)
        status, reason, s, _, _ = run_move(emulator.url, rig, 0.0, 0.005, planned_m=rested_m + 0.0005)
        assert status == "completed", reason
        assert s["target_m"][0] == pytest.approx(rested_m, abs=2e-5)
        assert peak_velocity_m_per_s(s) < MARGIN_FACTOR * 0.005 + MARGIN_M_PER_S
    finally:
        status = emulator.stop()
    assert not status["armed"] and status["command_v"] == 0.0


FOREIGN_SEED = 8  # a double-rod, underlapped 127 Hz valve, 5177 kg: uncommissioned, a 5 mm/s move runs away


@pytest.mark.realtime
def test_the_move_guard_stops_a_runaway_on_an_uncommissioned_foreign_rig_before_its_velocity_limit(tmp_path):
    """Told only what its lab knows (not commissioned), the servo's loop on this foreign rig is unstable: without
    the guard a 5 mm/s move reached 127 mm/s, past the rig's 91 mm/s velocity limit, before the limit closed the
    valve. The guard stops it at 15 mm/s, valve closed at once, the reason recorded, and the table never passes
    the rig's limit on its way to rest."""
    rig = declared_rig(draw_rig(FOREIGN_SEED).lab_knows())
    rig_limit = default_limits(rig).velocity_m_per_s
    emulator = Emulator(tmp_path, "--foreign-rig", str(FOREIGN_SEED))
    try:
        status, reason, s, _, trips = run_move(emulator.url, rig, 0.003, 0.005)
    finally:
        em = emulator.stop()
    assert status == "aborted" and reason.startswith("move guard tripped"), reason
    assert "commission it" in reason
    guard = move_guard_m_per_s(0.005)
    assert f"{guard * 1e3:.4g} mm/s" in reason
    assert peak_velocity_m_per_s(s) < rig_limit  # never past the rig's limit, the coast to rest included
    assert [t["values"]["detector"] for t in trips] == [MOVE_GUARD]
    assert trips[0]["values"]["velocity_m_per_s"] == pytest.approx(guard, rel=2.0)  # stopped near the guard
    assert s["voltage_v"][-1] == 0.0 and not em["armed"] and em["command_v"] == 0.0


def test_a_rig_job_carries_the_rig_files_commissioning_to_the_worker():
    """`isorig simulate --rig udp://... --rig-file F` ran the worker without F's commissioning: an oscillation on a
    commissioned rig (foreign rig 204 through UDP) was reported as "commission it", and the verdict did not judge
    the latency within its uncertainty."""
    from backend.worker import scenario_from_job
    from sim.engine import Scenario

    scenario = Scenario.sine("IUT_a", 100, 0.002, 1.0, 3)
    assert scenario_from_job(rig_job("udp://127.0.0.1:9", scenario)).rig_commissioning is None
    scenario.rig_commissioning = {"trusted": True, "date": "2026-11-29T23:00:00+00:00", "max_velocity_m_per_s": 0.02,
                                  "estimates": {"position_latency_s": {"value": 1.7e-3, "std": 1e-4}}}
    facts = scenario_from_job(rig_job("udp://127.0.0.1:9", scenario)).rig_commissioning
    assert facts is not None
    assert facts["position_latency_s"] == 1.7e-3 and facts["position_latency_std_s"] == 1e-4
    scenario.rig_commissioning = {"trusted": False}  # a refused fit is no commissioning
    assert scenario_from_job(rig_job("udp://127.0.0.1:9", scenario)).rig_commissioning is None
