"""Tracking quality of a closed-loop run: per-cycle errors, fitted-sine amplitude and phase, saturation."""

from __future__ import annotations

import math

import numpy as np

from .measurement import measured_rows
from .rig import LITRE_PER_MIN_M3_S


def cycle_windows(scenario) -> list[tuple[int, int, int, float]]:
    """(block index, first sample, end sample, frequency) of every target cycle, from the profile."""
    from .loop import CONTROL_PERIOD_S

    windows = []
    start = 0.0
    for b_index, block in enumerate(scenario.profile):
        period = 1.0 / block.frequency_hz
        for c in range(block.cycles):
            t0 = start + c * period
            windows.append((b_index, int(round(t0 / CONTROL_PERIOD_S)),
                            int(round((t0 + period) / CONTROL_PERIOD_S)), block.frequency_hz))
        start += block.cycles * period
    return windows


STEADY = "steady"
PHASES = ("taper_in", STEADY, "taper_out", "ramp_out")  # what a cycle of a sine block is


def cycle_phase(index_in_block: int, cycles: int, taper_cycles: int, planned_cycles: int | None = None) -> str:
    """``taper_in``, ``steady``, ``taper_out`` or ``ramp_out`` (the taper of an operator's stop: the block was
    cut short of its ``planned_cycles``) for the 0-based cycle ``index_in_block`` of a sine block.

    Only steady cycles are at the block's amplitude: headline figures (sim.metrics.headline_figures) and
    acceptance use them alone; the others are shown, marked and left out."""
    if index_in_block < taper_cycles:
        return "taper_in"
    if index_in_block >= cycles - taper_cycles:
        return "ramp_out" if planned_cycles is not None and cycles < planned_cycles else "taper_out"
    return STEADY


def cycle_phases(profile) -> list[str]:
    """The phase of every target cycle of a profile (a list of SineProfile blocks), in order."""
    return [cycle_phase(c, b.cycles, b.taper_cycles) for b in profile for c in range(b.cycles)]


def fitted_sine(t: np.ndarray, y: np.ndarray, frequency_hz: float) -> tuple[float, float]:
    """Least-squares amplitude and phase (rad) of y ~ c + A sin(2 pi f t + phi)."""
    w = 2 * math.pi * frequency_hz
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return math.hypot(a, b), math.atan2(b, a)


def _peak_abs(x: np.ndarray) -> float:
    """Largest finite |x|; NaN where nothing is known (a real rig does not measure the flow)."""
    finite = x[np.isfinite(x)]
    return float(np.max(np.abs(finite))) if finite.size else float("nan")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def closed_loop_error(samples) -> dict:
    """RMS and peak |y - r| over the rows run in closed loop (those with a target: an open-loop valve ramp has
    none) whose measurement arrived (a lost one holds an older reading: sim.measurement.measured_rows), and the
    peak |valve command| there (None if unknown); {} when no such row."""
    closed = np.isfinite(samples["target_m"])  # three columns only: copying whole rows of a long test is slow
    if not closed.any():
        return {}
    judged = closed & measured_rows(samples["flags"])
    e = samples["displacement_m"][judged] - samples["target_m"][judged]
    if not e.size:
        return {}
    u_peak = _peak_abs(samples["voltage_v"][closed])
    return {"rms_y_minus_r_m": _rms(e), "peak_abs_y_minus_r_m": float(np.max(np.abs(e))),
            "peak_abs_voltage_v": u_peak if math.isfinite(u_peak) else None}


def tracking_summary(samples, scenario) -> dict:
    """Per-cycle RMS of y - y_m and y - r, and figures over the last two full-amplitude cycles.

    ``samples``: a ``sim.samples.Samples`` of the test's rows from period 0. Errors are taken over the rows
    whose measurement arrived (a lost period holds an older reading, not where the table was:
    sim.measurement.measured_rows); ``lost_periods`` says how many were left out.
    """
    n = len(samples)
    y, r, y_m = samples["displacement_m"], samples["target_m"], samples["model_m"]
    fresh = measured_rows(samples["flags"])
    limit = scenario.rig.command_limit_v
    per_cycle = []
    windows = cycle_windows(scenario)
    for number, (b_index, i0, i1, _f) in enumerate(windows, start=1):
        if i1 > n:
            break
        seen = fresh[i0:i1]
        e_model = (y[i0:i1] - y_m[i0:i1])[seen]
        e_target = (y[i0:i1] - r[i0:i1])[seen]
        if not e_target.size:  # every period of the cycle lost: nothing measured to judge
            continue
        per_cycle.append({
            "cycle": number,
            "block": b_index,
            "rms_y_minus_ym_m": _rms(e_model) if np.all(np.isfinite(e_model)) else None,
            "rms_y_minus_r_m": _rms(e_target),
            "peak_abs_y_minus_r_m": float(np.max(np.abs(e_target))),
        })
    finite = bool(np.all(np.isfinite(y)) and np.all(np.isfinite(samples["voltage_v"])) and np.all(np.isfinite(r)))
    summary = {
        "samples": n,
        "all_finite": finite,
        "saturated_share": float(np.mean(np.abs(samples["command_raw_v"]) >= limit)) if n else 0.0,
        "peak_flow_l_per_min": _peak_abs(samples["flow_m3_per_s"]) / LITRE_PER_MIN_M3_S,
        "rms_y_minus_r_m": _rms((y - r)[np.isfinite(r) & fresh]),  # closed loop only (a stop's ramp has no target)
        "lost_periods": int(np.count_nonzero(~fresh)),
        "cycles": per_cycle,
    }
    if not scenario.profile:  # a time history: no cycles (its figures: sim.hybrid_metrics)
        return summary
    # last two cycles at full amplitude (outside the taper) of the last block
    block = scenario.profile[-1]
    last_block = [w for w in windows if w[0] == len(scenario.profile) - 1]
    full = last_block[block.taper_cycles:block.cycles - block.taper_cycles]
    if len(full) >= 2 and full[-1][2] <= n:
        sel = np.arange(full[-2][1], full[-1][2])
        sel = sel[fresh[sel]]
        t = samples["time_s"][sel]
        amp_y, ph_y = fitted_sine(t, y[sel], block.frequency_hz)
        amp_r, ph_r = fitted_sine(t, r[sel], block.frequency_hz)
        dphi = math.degrees(math.atan2(math.sin(ph_y - ph_r), math.cos(ph_y - ph_r)))
        e = y[sel] - r[sel]
        summary["last_two_cycles"] = {
            "rms_y_minus_r_m": _rms(e),
            "rms_y_minus_r_over_amplitude": _rms(e) / block.amplitude_m,
            "amplitude_error": amp_y / amp_r - 1.0,
            "phase_error_deg": dphi,
        }
    return summary
