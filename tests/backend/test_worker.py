"""The worker loop and the driver seam, in-process (no server): generic loop, ramp-out, fault handling."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from backend import worker
from backend.drivers import SimulatedRig
from backend.safety import default_limits
from backend.worker import Pacer, Run, ramp_out_profile
from sim.engine import C_TARGET, C_U, C_Y, CSV_COLUMNS, Scenario
from sim.isolator import PRESETS
from sim.profiles import SineProfile, pack_profile, target_series
from sim.rig import DEFAULT_RIG


class Pipe:
    """Collects what the worker sends; answers commands from a list."""

    def __init__(self, commands=()):
        self.sent = []
        self.commands = list(commands)

    def send(self, message):
        self.sent.append(message)

    def poll(self, *_):
        return bool(self.commands) and self.commands[0][0] <= self.now()

    def recv(self):
        return self.commands.pop(0)[1]

    def now(self):
        samples = [m for k, m in self.sent if k == "samples"]
        return samples[-1][-1, 0] if samples else 0.0


def job(speed=50.0, cycles=3, controller="pid"):
    return {"test_id": 1, "driver": "simulated", "speed": speed,
            "scenario": {"isolator": PRESETS["IUT_a"].to_dict(), "supply_pa": 100e5,
                         "profile": [SineProfile(0.01, 2.0, cycles, 1).to_dict()], "controller": controller},
            "limits": default_limits(DEFAULT_RIG).to_dict()}


class PythonLoopRig(SimulatedRig):
    """The simulated plant driven through the generic, one-period-at-a-time loop of RigDriver."""

    def run_closed_loop(self, n_periods):
        return super(SimulatedRig, self).run_closed_loop(n_periods)


def test_generic_driver_loop_matches_the_compiled_engine():
    scenario = Scenario.sine("IUT_a", 100, 0.01, 2.0, 2, controller="pid")
    fast, slow = SimulatedRig(), PythonLoopRig()
    fast.arm(scenario)
    slow.arm(scenario)
    a = fast.run_closed_loop(300)
    b = slow.run_closed_loop(300)
    assert a.shape == b.shape
    np.testing.assert_allclose(b[:, : len(CSV_COLUMNS)], a[:, : len(CSV_COLUMNS)], rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(a[:, C_Y])) > 1e-3


def test_run_sends_everything_and_completes():
    out = Pipe()
    run = Run(job(), out, Pipe())
    status, reason = run.execute()
    assert (status, reason) == ("completed", None)
    samples = np.concatenate([m for k, m in out.sent if k == "samples"])
    assert samples.shape[0] == 1500 and np.allclose(np.diff(samples[:, 0]), 1e-3)
    assert [m["cycle"] for k, m in out.sent if k == "cycle"] == [1, 2, 3]
    assert out.sent[0][0] == "started"
    stats = run.pacer.stats()
    assert stats["chunks"] == len([1 for k, _ in out.sent if k == "samples"])


def test_non_finite_state_trips_a_controlled_stop():
    class FaultyRig(SimulatedRig):
        def run_closed_loop(self, n):
            rows = super().run_closed_loop(n)
            if self.time_s > 0.3:
                rows[-1, C_Y] = np.nan
            return rows

    out = Pipe()
    run = Run(job(), out, Pipe(), driver=FaultyRig())
    status, reason = run.execute()
    assert status == "aborted" and "non-finite" in reason
    trip = [m for k, m in out.sent if k == "event" and m["kind"] == "limit_trip"]
    assert len(trip) == 1 and trip[0]["values"]["detector"] == "non_finite"
    samples = np.concatenate([m for k, m in out.sent if k == "samples"])
    assert samples[-1, C_U] == 0.0 and 0.3 < samples[-1, 0] < 0.5


def test_ramp_out_profile_is_continuous_and_ends_at_a_cycle():
    blocks = pack_profile([SineProfile(0.02, 1.0, 10, 2), SineProfile(0.01, 2.0, 4, 1)])
    for t_stop, end_expected in ((0.3, 3.0), (3.27, 6.0), (7.9, 10.0), (9.5, 10.0)):
        new, total = ramp_out_profile(blocks, t_stop)
        assert new.shape[0] == 1  # the later block is dropped
        end = total * 1e-3
        assert abs(end - end_expected) < 1e-9
        t = np.arange(0.0, end + 1e-9, 1e-3)
        before, after = target_series(blocks, t), target_series(new, t)
        assert np.allclose(before[t <= t_stop], after[t <= t_stop])
        assert abs(after[-1]) < 1e-9 and np.max(np.abs(np.diff(after))) < 2 * np.pi * 0.02 * 1e-3 * 1.5
    # a stop inside the last block's own taper-out changes nothing
    new, total = ramp_out_profile(blocks, 11.9)
    assert new.shape == blocks.shape and total == 12000


def test_stop_command_ends_stopped_with_target_tapered():
    run = Run(job(cycles=10), Pipe(), Pipe())
    commands = Pipe(commands=[(1.1, "stop")])
    commands.now = lambda: run.driver.time_s
    run.commands = commands
    out = run.out
    status, _ = run.execute()
    assert status == "stopped"
    samples = np.concatenate([m for k, m in out.sent if k == "samples"])
    assert 1.1 < samples[-1, 0] < 2.1 + 0.02 and abs(samples[-1, C_TARGET]) < 1e-6


class FakeClock:
    """Stands in for the time module in backend.worker: each clock reading takes ``poll_s``, each sleep lasts
    ``oversleep_s`` longer than asked (the OS's wake-up delay)."""

    def __init__(self, oversleep_s=0.0, poll_s=1e-5):
        self.t = 1000.0
        self.oversleep_s, self.poll_s = oversleep_s, poll_s
        self.slept = []
        self.module = SimpleNamespace(perf_counter=self.perf_counter, sleep=self.sleep, time=lambda: 0.0)

    def perf_counter(self):
        self.t += self.poll_s
        return self.t

    def sleep(self, s):
        self.slept.append(s)
        self.t += s + self.oversleep_s


@pytest.mark.parametrize("oversleep_s, late_s", [(0.0, 0.0), (0.0008, 0.0), (0.003, 0.002)])
def test_pacer_sleeps_until_spin_s_before_the_deadline_then_polls(monkeypatch, oversleep_s, late_s):
    clock = FakeClock(oversleep_s)
    monkeypatch.setattr(worker, "time", clock.module)
    pacer = Pacer(speed=2.0, spin_s=0.001)
    pacer.wait_until(0.04)  # due 20 ms of wall time after the start
    assert clock.slept == [pytest.approx(0.02 - 0.001, abs=3 * clock.poll_s)]
    assert pacer.lateness_s == [pytest.approx(late_s, abs=clock.poll_s)]
    assert clock.t >= pacer.t0 + 0.02  # never released early


def test_pacer_polls_without_sleeping_inside_spin_s_and_counts_a_missed_deadline(monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr(worker, "time", clock.module)
    pacer = Pacer(speed=1.0, spin_s=0.001)
    pacer.wait_until(0.0005)  # due within spin_s: poll only
    assert clock.slept == [] and clock.t >= pacer.t0 + 0.0005 and pacer.lateness_s[-1] <= clock.poll_s
    clock.t += 0.01  # the chunk took too long: the next deadline has passed
    pacer.wait_until(0.005)
    assert clock.slept == [] and pacer.lateness_s[-1] == pytest.approx(0.0055, abs=2 * clock.poll_s)
