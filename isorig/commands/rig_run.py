"""A run on a real-time rig from the command line (`simulate --rig`, `hybrid --rig`, `move`): the job the
service's worker would get, the check that the table rests where the run starts, and Ctrl-C, then the same
loop, detectors and stop paths as the service (backend.worker.run_here). Not a command itself."""

from __future__ import annotations

import signal
import time

from isorig.cli import UsageError


def rig_job(rig: str, scenario, link_timeout_s: float = 0.05, security: dict | None = None, **extra) -> dict:
    """The worker's job for ``scenario`` on ``rig`` (udp://HOST:PORT), with the rig's default limits and the
    link's protection ``security`` (rig_key.link_options: the key file's path, never the key); ``extra`` adds
    to the job's scenario (``motion``, ``history_target``) or the job (``hybrid``)."""
    from backend.safety import default_limits
    from sim.follow import commissioning_facts

    # the rig file's commissioning goes with the job: the worker's follow monitor then blames an oscillation on the
    # controller, not on a rig "not commissioned", and judges the latency within its uncertainty (foreign rig 204
    # through UDP at e85e39a: "commission it", with the rig file it had just written)
    spec = {"isolator": scenario.isolator.to_dict(), "supply_pa": scenario.supply_pa,
            "vertical_load_n": scenario.effective_vertical_load_n,
            "profile": [b.to_dict() for b in scenario.profile], "controller": scenario.controller,
            "controller_options": scenario.controller_options, "history_target": scenario.history,
            "rig_changes": scenario.describe()["rig_changes"],
            "rig_commissioning": commissioning_facts(getattr(scenario, "rig_commissioning", None))}
    job = {"test_id": None, "rig": rig, "speed": 1.0,
           "link": {"period_s": 1e-3, "timeout_s": link_timeout_s, "arm_timeout_s": 2.0, **(security or {})},
           "scenario": spec, "limits": default_limits(scenario.rig).to_dict()}
    for key, value in extra.items():
        (job if key == "hybrid" else spec)[key] = value
    return job


def check_start_position(command: str, rig: str, expected_m: float = 0.0, security: dict | None = None) -> None:
    """One HELLO: refuse (exit 2) while the table rests off where the run starts; nothing moves."""
    from backend.drivers.udp import start_position_problem

    problem = start_position_problem(rig, expected_m=expected_m, **(security or {}))
    if problem is not None:
        raise UsageError(f"isorig {command}: not started on {rig}: {problem}")


def resting_position_m(command: str, rig: str, security: dict | None = None) -> float:
    """Where the rig's table rests, from one HELLO; refuse (exit 2) a rig that does not answer or is armed."""
    from backend.drivers.udp import probe

    answer = probe(rig, timeout_s=0.5, **(security or {}))
    if not answer["connected"]:
        raise UsageError(f"isorig {command}: {answer['detail']}; nothing moved")
    if answer["armed"]:
        raise UsageError(f"isorig {command}: the rig at {rig} is armed: another test or move runs on it (wait for "
                         "it to end); nothing moved")
    return float(answer["position_m"])


def run_job(job: dict, interrupt: str = "abort"):
    """Run ``job`` here; Ctrl-C sends ``interrupt`` (``abort``: valve closed at once; ``stop``). Returns
    (run, what it sent, status, reason, wall time in s)."""
    from backend.worker import AbortSwitch, run_here

    switch = AbortSwitch()
    previous = signal.signal(signal.SIGINT, lambda *_: switch.pending.append(interrupt))
    t0 = time.perf_counter()
    try:
        run, sent, status, reason = run_here(job, switch)
    finally:
        signal.signal(signal.SIGINT, previous)
    return run, sent, status, reason, time.perf_counter() - t0
