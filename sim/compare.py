"""The controller comparison grid of issue 7: every controller on every isolator, supply pressure, frequency
and rig variant, with the tracking figures a lab judges a sine test by.

Grid: isolators IUT_a, IUT_b, LRB_example, HDRB_soft; supply 50, 100, 150 bar; 0.25, 0.5, 1, 1.5 Hz; the
nominal rig and a rig whose valve passes twice the flow (twice the loop gain; the controllers are not
told: a plant-only change, ``Scenario.plant_changes``). Amplitude: ``AMPLITUDE_SHARE`` of the largest amplitude
the envelope of the nominal rig allows (sim.profiles.max_amplitude_m: stroke, pump flow, force A_p P_s, valve
capacity), capped at ``AMPLITUDE_CAP_M``. ``CYCLES`` cycles with a one-cycle taper in and out.

Robust corners: the learning controller's nominal rig values (piston area, valve flow gain, dead zone)
each off by -30 % or +30 % (8 corners); mrac and pid use no nominal values.

The nominal rig is ``sim.rig.DEFAULT_RIG`` unless a lab's rig is given (``base_rig``: ``isorig compare
--rig-file``, ``--rig-set``): the controllers assume it and the plant is it, with ``plant`` (``--plant-set``)
changing the plant alone in every run.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .engine import CONTROL_PERIOD_S, ISOLATOR_PARAMETERS, Scenario, run_batch
from .isolator import load_isolator
from .profiles import max_amplitude_m
from .rig import BAR_PA, DEFAULT_RIG, LITRE_PER_MIN_M3_S, RigParameters
from .tracking import cycle_windows, tracking_summary

ISOLATORS = ("IUT_a", "IUT_b", "LRB_example", "HDRB_soft")
SUPPLIES_BAR = (50.0, 100.0, 150.0)
FREQUENCIES_HZ = (0.25, 0.5, 1.0, 1.5)
AMPLITUDE_SHARE = 0.8
AMPLITUDE_CAP_M = 0.05
CYCLES = 10
TAPER_CYCLES = 1
RIG_VARIANTS = ("nominal", "2x_flow_gain")
CONTROLLERS = ("servo", "mrac", "pid")
ROBUST_SHARE = 0.3
LIMIT_CYCLE_BAND_HZ = 5.0  # non-repeating error above this frequency reveals a limit cycle
LIMIT_CYCLE_SHARE = 0.001  # ... when its RMS exceeds this share of the amplitude

# Targets of issue 7 (shares, degrees).
TARGETS = {
    "rms_last2": 0.01,
    "rms_from_cycle3": 0.02,
    "amplitude_error": 0.01,
    "phase_error_deg": 1.0,
    "saturated_share": 0.01,
}


def variant_plant_changes(name: str, base: RigParameters = DEFAULT_RIG, plant: dict | None = None) -> dict:
    """The plant-only changes of a rig variant over ``base`` and the plant changes ``plant``: the controllers
    assume ``base`` and are not told."""
    plant = dict(plant or {})
    if name == "nominal":
        return plant
    if name == "2x_flow_gain":
        key = "flow_gain_m3_per_s_v_sqrt_pa"
        return {**plant, key: 2.0 * plant.get(key, getattr(base, key))}
    raise ValueError(f"unknown rig variant {name!r}; allowed: {', '.join(RIG_VARIANTS)}")


def rig_variant(name: str, base: RigParameters = DEFAULT_RIG) -> RigParameters:
    """The simulated rig of a variant (what the plant is; the controllers assume ``base``)."""
    rig_changes = {k: v for k, v in variant_plant_changes(name, base).items() if k not in ISOLATOR_PARAMETERS}
    return base.with_changes(**rig_changes) if rig_changes else base


def grid_amplitude_m(isolator: str, supply_bar: float, frequency_hz: float, rig: RigParameters = DEFAULT_RIG) -> float:
    """The grid's amplitude: a share of the envelope's largest amplitude, capped."""
    a_max = max_amplitude_m(frequency_hz, rig, load_isolator(isolator), supply_bar * BAR_PA)
    return min(AMPLITUDE_SHARE * a_max, AMPLITUDE_CAP_M)


def robust_corners(base: RigParameters = DEFAULT_RIG) -> list[dict]:
    """The 8 corners of +-30 % on the nominal piston area, flow gain and dead zone."""
    out = []
    for sa, sk, sd in itertools.product((-1, 1), repeat=3):
        out.append({
            "label": f"A_p{sa * 30:+d}% K_q{sk * 30:+d}% DZ{sd * 30:+d}%",
            "options": {
                "piston_area_m2": base.piston_area_m2 * (1 + sa * ROBUST_SHARE),
                "flow_gain_m3_per_s_v_sqrt_pa": base.flow_gain_m3_per_s_v_sqrt_pa * (1 + sk * ROBUST_SHARE),
                "dead_zone_v": base.dead_zone_v * (1 + sd * ROBUST_SHARE),
            },
        })
    return out


ABLATIONS = (
    ("full design", {}),
    ("no harmonic learning", {"learning_gain": 0.0}),
    ("no flow-gain estimate", {"gain_min": 1.0, "gain_max": 1.0}),
    ("no velocity lead", {"velocity_lead_s": 0.0}),
    ("no dead-zone inverse", {"dead_zone_share": 0.0}),
    ("no load-pressure linearisation", {"load_pressure_share": 0.0}),
    ("fixed-gain loop: flow linearisation + P only", {"learning_gain": 0.0, "gain_min": 1.0, "gain_max": 1.0}),
)


@dataclass
class GridPoint:
    controller: str
    isolator: str
    supply_bar: float
    frequency_hz: float
    amplitude_m: float
    rig: str
    corner: str = "exact"
    options: dict | None = None
    base_rig: RigParameters = DEFAULT_RIG  # the nominal rig: what the controllers assume
    plant: dict = field(default_factory=dict)  # plant-only changes of every run (--plant-set)
    #: judged by the service's detectors with the rig's default limits, as every test the service runs: the row's
    #: status and reason are the service's, its figures run on past a trip (sim.engine.run_judged; False:
    #: ``isorig compare --no-limit-detectors``, not judged)
    detectors: bool = True

    def scenario(self, cycles: int = CYCLES) -> Scenario:
        s = Scenario.sine(self.isolator, self.supply_bar, self.amplitude_m, self.frequency_hz, cycles,
                          controller=self.controller, taper_cycles=TAPER_CYCLES,
                          controller_options=dict(self.options or {}), rig=self.base_rig,
                          plant_changes=variant_plant_changes(self.rig, self.base_rig, self.plant))
        s.label = self.label
        return s

    @property
    def label(self) -> str:
        return (f"{self.controller} {self.isolator} {self.supply_bar:g} bar {self.frequency_hz:g} Hz "
                f"{self.amplitude_m * 1e3:.1f} mm {self.rig} {self.corner}")


def grid_points(controllers=CONTROLLERS, robust: bool = False, isolators=ISOLATORS, supplies_bar=SUPPLIES_BAR,
                frequencies_hz=FREQUENCIES_HZ, rigs=RIG_VARIANTS, base_rig: RigParameters = DEFAULT_RIG,
                plant: dict | None = None) -> list[GridPoint]:
    """Every grid point; with ``robust`` the learning controller at each +-30 % corner instead. ``base_rig``: the
    nominal rig (amplitudes from its envelope), ``plant``: plant-only changes of every run."""
    points = []
    corners = robust_corners(base_rig) if robust else [{"label": "exact", "options": {}}]
    for iso, bar, f in itertools.product(isolators, supplies_bar, frequencies_hz):
        amp = grid_amplitude_m(iso, bar, f, base_rig)
        for rig in rigs:
            for name in controllers:
                if robust and name != "servo":
                    continue
                for corner in corners:
                    points.append(GridPoint(name, iso, bar, f, amp, rig, corner["label"], corner["options"],
                                            base_rig=base_rig, plant=dict(plant or {})))
    return points


ABLATION_CORNERS = ("exact", "A_p+30% K_q-30% DZ-30%", "A_p-30% K_q+30% DZ+30%")


def ablation_points(base_rig: RigParameters = DEFAULT_RIG, plant: dict | None = None,
                    supplies_bar=SUPPLIES_BAR) -> list[GridPoint]:
    """The learning controller on the whole grid with one piece switched off at a time, with exact nominal values
    and at the two extreme corners (loop gain x 1.86 with the dead zone under-compensated; x 0.54 with it
    over-compensated). The label goes in ``corner``: "<ablation> / <corner>"."""
    corners = {"exact": {}, **{c["label"]: c["options"] for c in robust_corners(base_rig)}}
    points = []
    for label, options in ABLATIONS:
        for corner in ABLATION_CORNERS:
            for p in grid_points(controllers=("servo",), base_rig=base_rig, plant=plant, supplies_bar=supplies_bar):
                p.corner = f"{label} / {corner}"
                p.options = {**corners[corner], **options}
                points.append(p)
    return points


def grid_description(cycles: int = CYCLES, robust: bool = False, ablation: bool = False) -> dict:
    return {
        "isolators": list(ISOLATORS), "supply_bar": list(SUPPLIES_BAR), "frequency_hz": list(FREQUENCIES_HZ),
        "rig_variants": list(RIG_VARIANTS), "cycles": cycles, "taper_cycles": TAPER_CYCLES,
        "amplitude": f"min({AMPLITUDE_SHARE:g} x sim.profiles.max_amplitude_m, {AMPLITUDE_CAP_M:g} m) on the "
                     "nominal rig",
        "robust_corners": [c["label"] for c in robust_corners()] if robust else [],
        "ablations": [a[0] for a in ABLATIONS] if ablation else [],
        "targets": TARGETS, "limit_cycle": {"band_hz": LIMIT_CYCLE_BAND_HZ, "share": LIMIT_CYCLE_SHARE},
    }


def jsonable(rows: list[dict]) -> list[dict]:
    """Rows with NaN and infinities as None (JSON has no NaN)."""
    return [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()} for r in rows]


def limit_cycle_rms_m(samples, scenario: Scenario) -> float:
    """RMS of the error that does not repeat from cycle to cycle, above LIMIT_CYCLE_BAND_HZ (m).

    A converged periodic response repeats every cycle; a limit cycle (a self-sustained oscillation at
    the loop's own frequency) does not. The difference of the error over the last two full cycles,
    high-passed above LIMIT_CYCLE_BAND_HZ (slow convergence is not an oscillation), divided by sqrt(2).
    """
    block = scenario.profile[-1]
    windows = cycle_windows(scenario)
    full = windows[block.taper_cycles:block.cycles - block.taper_cycles]
    if len(full) < 2 or full[-1][2] > len(samples):
        return float("nan")
    (_, a0, a1, _), (_, b0, b1, _) = full[-2], full[-1]
    n = min(a1 - a0, b1 - b0)
    e = samples["displacement_m"] - samples["target_m"]
    e_prev, e_last = e[a0:a0 + n], e[b0:b0 + n]
    spectrum = np.fft.rfft(e_last - e_prev)
    freqs = np.fft.rfftfreq(n, CONTROL_PERIOD_S)
    spectrum[freqs <= LIMIT_CYCLE_BAND_HZ] = 0.0
    return float(np.sqrt(np.mean(np.fft.irfft(spectrum, n) ** 2)) / math.sqrt(2.0))


def point_figures(point: GridPoint, result) -> dict:
    """The comparison columns of one run."""
    scenario = result.scenario
    summary = tracking_summary(result.samples, scenario)
    amp = point.amplitude_m
    cycles = summary["cycles"]
    last = summary.get("last_two_cycles", {})
    from3 = [c["rms_y_minus_r_m"] for c in cycles[2:]]
    u = result.samples["voltage_v"]
    return {
        "controller": point.controller,
        "isolator": point.isolator,
        "supply_bar": point.supply_bar,
        "frequency_hz": point.frequency_hz,
        "amplitude_m": amp,
        "rig": point.rig,
        "corner": point.corner,
        "diverged": bool(result.diverged or not summary["all_finite"]),
        "status": result.status,  # as the service would end it (the figures run on past a trip)
        "reason": result.reason,
        "rms_last2": last.get("rms_y_minus_r_over_amplitude", float("nan")),
        "rms_from_cycle3": (max(from3) / amp) if from3 else float("nan"),
        "first_cycle_peak_m": cycles[0]["peak_abs_y_minus_r_m"] if cycles else float("nan"),
        "amplitude_error": last.get("amplitude_error", float("nan")),
        "phase_error_deg": last.get("phase_error_deg", float("nan")),
        "saturated_share": float(np.mean(np.abs(result.samples["command_raw_v"]) >= scenario.rig.command_limit_v)),
        "peak_flow_l_per_min": summary["peak_flow_l_per_min"],
        "pump_flow_l_per_min": scenario.rig.pump_max_flow_m3_per_s / LITRE_PER_MIN_M3_S,
        "limit_cycle_rms_m": limit_cycle_rms_m(result.samples, scenario),
        "rms_command_v": float(np.sqrt(np.mean(u * u))) if u.size else float("nan"),
        **(point.extra_figures(result) if hasattr(point, "extra_figures") else {}),
    }


def meets_targets(row: dict) -> bool:
    if row["diverged"] or row.get("status", "completed") != "completed":  # a detector stopped it: the service would
        return False
    values = {k: abs(row[k]) for k in TARGETS}
    if any(not math.isfinite(v) for v in values.values()):
        return False
    return all(values[k] < TARGETS[k] for k in TARGETS) and not limit_cycle(row)


def limit_cycle(row: dict) -> bool:
    """A non-repeating oscillation above LIMIT_CYCLE_BAND_HZ larger than LIMIT_CYCLE_SHARE of the amplitude."""
    v = row["limit_cycle_rms_m"]
    return (not math.isfinite(v)) or v > LIMIT_CYCLE_SHARE * row["amplitude_m"]


def run_point(point: GridPoint, cycles: int = CYCLES):
    """One point's run (sim.engine.Result), with the service's detectors unless the point says otherwise."""
    from .engine import run_judged

    return run_judged(point.scenario(cycles), point.detectors)


def run_grid(points: list[GridPoint], cycles: int = CYCLES, processes: int | None = None) -> tuple[list[dict], float]:
    """Run every point on all cores; returns (rows, wall time in s)."""
    t0 = time.perf_counter()
    scenarios = [p.scenario(cycles) for p in points]
    results = run_batch(scenarios, processes=processes, detectors=[p.detectors for p in points])
    rows = [point_figures(p, r) for p, r in zip(points, results, strict=True)]
    return rows, time.perf_counter() - t0


def worst_case(rows: list[dict]) -> dict:
    """Largest magnitude of each figure over the rows, and how many rows meet every target."""
    out = {"runs": len(rows), "meet_targets": sum(meets_targets(r) for r in rows),
           "diverged": sum(r["diverged"] for r in rows), "limit_cycles": sum(limit_cycle(r) for r in rows)}
    for key in ("rms_last2", "rms_from_cycle3", "first_cycle_peak_m", "amplitude_error", "phase_error_deg",
                "saturated_share", "peak_flow_l_per_min", "limit_cycle_rms_m"):
        vals = [abs(r[key]) for r in rows]
        out[key] = float("nan") if any(not math.isfinite(v) for v in vals) else max(vals)
    return out


HEADER = ("isolator", "bar", "Hz", "amp mm", "rig", "corner", "RMS last2 %", "max RMS c3+ %", "1st peak mm",
          "amp err %", "phase deg", "sat %", "peak flow l/min", "LC um", "ok")


def format_row(r: dict) -> tuple:
    def pct(x):
        return f"{100 * x:.2f}" if math.isfinite(x) else "nan"

    return (r["isolator"], f"{r['supply_bar']:g}", f"{r['frequency_hz']:g}", f"{r['amplitude_m'] * 1e3:.1f}",
            r["rig"], r["corner"], pct(r["rms_last2"]), pct(r["rms_from_cycle3"]),
            f"{r['first_cycle_peak_m'] * 1e3:.2f}", pct(r["amplitude_error"]), f"{r['phase_error_deg']:.2f}",
            pct(r["saturated_share"]), f"{r['peak_flow_l_per_min']:.0f}", f"{r['limit_cycle_rms_m'] * 1e6:.1f}",
            "yes" if meets_targets(r) else ("DIVERGED" if r["diverged"] else
                                            "ABORTED" if r.get("status", "completed") != "completed" else "no"))


def markdown_table(rows: list[dict]) -> str:
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(format_row(r)) + " |" for r in rows]
    return "\n".join(lines)


def text_table(rows: list[dict]) -> str:
    cells = [HEADER] + [format_row(r) for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(HEADER))]
    return "\n".join("  ".join(c[i].rjust(widths[i]) for i in range(len(HEADER))) for c in cells)


SUMMARY_HEADER = ("group", "runs", "meet all targets", "RMS last2 %", "max RMS c3+ %", "1st peak mm", "amp err %",
                  "phase deg", "sat %", "peak flow l/min", "limit cycles", "diverged")


def summary_table(groups: dict[str, list[dict]], markdown: bool = True) -> str:
    """One line per group (controller, corner or ablation): the worst case of each column over its runs."""
    cells = [SUMMARY_HEADER]
    for name, rows in groups.items():
        w = worst_case(rows)
        cells.append((name, str(w["runs"]), str(w["meet_targets"]), f"{100 * w['rms_last2']:.2f}",
                      f"{100 * w['rms_from_cycle3']:.2f}", f"{w['first_cycle_peak_m'] * 1e3:.2f}",
                      f"{100 * w['amplitude_error']:.2f}", f"{w['phase_error_deg']:.2f}",
                      f"{100 * w['saturated_share']:.2f}", f"{w['peak_flow_l_per_min']:.0f}", str(w["limit_cycles"]),
                      str(w["diverged"])))
    if markdown:
        lines = ["| " + " | ".join(cells[0]) + " |", "|" + "---|" * len(cells[0])]
        return "\n".join(lines + ["| " + " | ".join(c) + " |" for c in cells[1:]])
    widths = [max(len(c[i]) for c in cells) for i in range(len(cells[0]))]
    return "\n".join("  ".join(c[i].rjust(widths[i]) for i in range(len(c))) for c in cells)


def worst_case_line(w: dict) -> str:
    return (f"worst case over {w['runs']} runs: RMS last two cycles {100 * w['rms_last2']:.2f} %, "
            f"max cycle RMS from cycle 3 {100 * w['rms_from_cycle3']:.2f} %, first-cycle peak "
            f"{w['first_cycle_peak_m'] * 1e3:.2f} mm, amplitude error {100 * w['amplitude_error']:.2f} %, "
            f"phase error {w['phase_error_deg']:.2f} deg, saturated {100 * w['saturated_share']:.2f} %, "
            f"peak flow {w['peak_flow_l_per_min']:.0f} l/min; limit cycles {w['limit_cycles']}, "
            f"diverged {w['diverged']}; {w['meet_targets']}/{w['runs']} meet every target")
