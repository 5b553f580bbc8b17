"""The robustness suite of issue 15 (item 2): the default controller on the rigs and tests where labs operate
and the paper's rig is not, with one set of defaults and the targets it must meet.

Four groups of cases, each a closed-loop sine test in the engine (``sim.engine``; ``isorig compare --robustness``
runs them on the campaign engine, ``sim.campaign.Engine``):

- **small amplitude**: 0.5, 1, 2 and 5 mm at 0.1, 0.5 and 1 Hz on IUT_a (100 bar) and IUT_b (70 bar), the
  paper's rig; target: the last two full cycles' RMS |y - r| / amplitude <= 1 %, no limit cycle;
- **soft oil column**: rigs whose oil column (``oil_column_hz``: sqrt(2 beta A_p^2 / (V_0 m)) / 2 pi) is down to
  about 20 Hz, by a heavier table, a lower bulk modulus, longer hoses (a larger V_0) or all three, declared in
  the rig (what the controller assumes is the plant); the paper's tests at 0.5, 1 and 1.5 Hz; target <= 0.5 %,
  no sustained oscillation;
- **sensor latency**: a position reading late by 0.5, 1 and 2 ms, declared (``position_latency_s``); up to 1.5 Hz;
  target <= 0.5 % of the *true* table displacement against the target (the engine's ``displacement_m``);
- **stiffness change**: the isolator's stiffness (k_d, or k_d and k_w: its whole restoring force) halves or
  doubles at the start of a cycle in the middle of the test (``Scenario.timed_changes``); target: every cycle
  from the third after the change on <= 0.5 % (the figure is the worst of them).

Two sensitivity groups (not the issue's targets; run them by name with ``--groups``) repeat cases on a plant
that differs from the declared rig where a lab's declaration is roughest: the small-amplitude cases with the
valve's null offset (v_e0, eq. 2) 20 mV off the declared one, and the soft-oil-column cases with 50 % more oil
volume V_0 than declared (a column 18 % slower).

A limit cycle (or a sustained oscillation) is a self-excited motion: it does not repeat from cycle to cycle as a
converged periodic response does. Measured over the last two full cycles: the part of y - r, and of the valve
command, in the band ``BAND_HZ`` (5-30 Hz: well above the test frequencies, around the stick-slip and the oil
column's frequencies) that differs between the two cycles (their difference, band-passed, over sqrt 2).
Counted as a limit cycle when that error exceeds ``LIMIT_CYCLE_SHARE`` of the amplitude or that command
exceeds ``LIMIT_CYCLE_COMMAND_V``. The band RMS of y - r itself (periodic part included) is shown too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .compare import GridPoint, jsonable
from .engine import CONTROL_PERIOD_S, ISOLATOR_PARAMETERS, Scenario
from .isolator import load_isolator
from .rig import DEFAULT_RIG, RigParameters
from .tracking import cycle_windows, tracking_summary

BAND_HZ = (5.0, 30.0)
LIMIT_CYCLE_SHARE = 0.001  # of the amplitude: the grid's limit-cycle threshold (sim.compare)
LIMIT_CYCLE_COMMAND_V = 0.02  # V of valve command that does not repeat: 2 % of the dead zone, ~1 mm/s at 100 bar
TAPER_CYCLES = 1
CYCLES = 8
CHANGE_CYCLES = 12  # a stiffness-change test: 1 taper, 4 full cycles, the change, 6 full cycles, 1 taper
CHANGE_AT_CYCLE = 5  # the change takes effect at the start of this cycle (0-based: after the taper and 4 cycles)

GROUPS = ("small amplitude", "soft oil column", "sensor latency", "stiffness change")
TARGETS = {"small amplitude": 0.01, "soft oil column": 0.005, "sensor latency": 0.005, "stiffness change": 0.005}
#: sensitivity groups (``--groups`` only; not the issue's targets): the same cases on a plant that differs from the
#: declared rig where a lab's declaration is roughest
SENSITIVITY_GROUPS = ("valve null off", "more oil than declared")
TARGETS.update({SENSITIVITY_GROUPS[0]: 0.01, SENSITIVITY_GROUPS[1]: 0.005})
ALL_GROUPS = GROUPS + SENSITIVITY_GROUPS
NULL_ERROR_V = -0.02  # the plant's valve null offset less the declared one
VOLUME_ERROR_SHARE = 1.5  # the plant's V_0 over the declared one
PAPER_TESTS = (("IUT_a", 100.0, 0.02), ("IUT_b", 70.0, 0.03))  # isolator, supply bar, amplitude m (section V)
SMALL_AMPLITUDES_M = (0.0005, 0.001, 0.002, 0.005)
SMALL_FREQUENCIES_HZ = (0.1, 0.5, 1.0)
OIL_COLUMN_RIGS = (
    ("heavy table", {"mass_kg": 9000.0}),
    ("soft oil", {"bulk_modulus_pa": 1.33e8}),
    ("long hoses, heavier, softer", {"mass_kg": 3000.0, "bulk_modulus_pa": 5.0e8, "half_volume_m3": 4.0e-3}),
    ("heavier table", {"mass_kg": 4000.0}),
)
TEST_FREQUENCIES_HZ = (0.5, 1.0, 1.5)
LATENCIES_S = (0.0005, 0.001, 0.002)
STIFFNESS_TESTS = (  # isolator, supply bar, amplitude m, frequency Hz, parameters that change
    ("IUT_a", 100.0, 0.02, 1.0, ("kd_n_per_m",)),
    ("IUT_b", 70.0, 0.03, 0.5, ("kd_n_per_m",)),
    ("LRB_example", 100.0, 0.02, 1.0, ("kd_n_per_m",)),
    ("HDRB_soft", 100.0, 0.03, 0.5, ("kd_n_per_m",)),
    ("IUT_a", 100.0, 0.02, 1.0, ("kd_n_per_m", "kw_n")),
    ("IUT_a", 100.0, 0.005, 0.5, ("kd_n_per_m",)),
)
STIFFNESS_FACTORS = (0.5, 2.0)


def oil_column_hz(rig: RigParameters) -> float:
    """Natural frequency of the oil column on the table: sqrt(2 beta A_p^2 / (V_0 m)) / (2 pi), the hydraulic
    stiffness of the two chambers (2 beta A_p^2 / V_0 with V_0 per side, hoses included) on the moving mass.
    The isolator adds its stiffness (k_d + k_w rho on unloading, a few MN/m against 140 MN/m here): left out."""
    return math.sqrt(2.0 * rig.bulk_modulus_pa * rig.piston_area_m2 ** 2 / (rig.half_volume_m3 * rig.mass_kg)) \
        / (2.0 * math.pi)


@dataclass
class RobustnessPoint(GridPoint):
    """One case of the suite: a grid point (controller, isolator, supply, frequency, amplitude) with its own rig
    (declared: what the controller assumes, and the plant), plant-only changes, timed changes, cycles and target.
    ``rig`` is a label; ``corner`` holds the case's name."""

    group: str = ""
    rig_changes: dict = field(default_factory=dict)
    plant: dict = field(default_factory=dict)
    timed: list = field(default_factory=list)
    cycles: int = CYCLES
    change_cycle: int | None = None
    target: float = 0.0
    base_rig: RigParameters = DEFAULT_RIG

    @property
    def declared_rig(self) -> RigParameters:
        return self.base_rig.with_changes(**self.rig_changes) if self.rig_changes else self.base_rig

    def scenario(self, cycles: int = CYCLES) -> Scenario:
        """The case's test (its own cycle count: ``cycles`` is the grid's and is not used)."""
        s = Scenario.sine(self.isolator, self.supply_bar, self.amplitude_m, self.frequency_hz, self.cycles,
                          controller=self.controller, taper_cycles=TAPER_CYCLES,
                          controller_options=dict(self.options or {}), rig=self.declared_rig,
                          plant_changes=dict(self.plant), timed_changes=list(self.timed))
        s.label = self.label
        return s

    @property
    def label(self) -> str:
        return f"{self.controller} {self.group}: {self.corner}"

    def extra_figures(self, result) -> dict:
        """The case's figure, its target and the limit-cycle measures (sim.compare.point_figures adds them)."""
        return case_figures(self, result)


def _band_rms(x: np.ndarray) -> float:
    """RMS of x in BAND_HZ (FFT mask over the whole record x)."""
    if x.size < 4:
        return float("nan")
    spectrum = np.fft.rfft(x)
    freqs = np.fft.rfftfreq(x.size, CONTROL_PERIOD_S)
    spectrum[(freqs < BAND_HZ[0]) | (freqs > BAND_HZ[1])] = 0.0
    return float(np.sqrt(np.mean(np.fft.irfft(spectrum, x.size) ** 2)))


def last_two_full_cycles(scenario: Scenario, n_samples: int):
    """(first, end) sample of the last two full-amplitude cycles of the last block, or None."""
    block = scenario.profile[-1]
    windows = cycle_windows(scenario)
    full = windows[block.taper_cycles:block.cycles - block.taper_cycles]
    if len(full) < 2 or full[-1][2] > n_samples:
        return None
    return full[-2], full[-1]


def non_repeating_band_rms(x: np.ndarray, scenario: Scenario) -> float:
    """RMS of what does not repeat between the last two full cycles, in BAND_HZ: the band-passed difference of
    the two cycles over sqrt(2) (a converged periodic response gives 0, a self-excited oscillation does not)."""
    cycles = last_two_full_cycles(scenario, x.size)
    if cycles is None:
        return float("nan")
    (_, a0, a1, _), (_, b0, b1, _) = cycles
    n = min(a1 - a0, b1 - b0)
    return _band_rms(x[b0:b0 + n] - x[a0:a0 + n]) / math.sqrt(2.0)


def case_figures(point: RobustnessPoint, result) -> dict:
    """The figure the case's target applies to, and the limit-cycle measures."""
    scenario, s = result.scenario, result.samples
    amp = point.amplitude_m
    summary = tracking_summary(s, scenario)
    error = s["displacement_m"] - s["target_m"]
    diverged = bool(result.diverged or not summary["all_finite"])
    figure = float("nan")
    if point.change_cycle is None:
        figure = summary.get("last_two_cycles", {}).get("rms_y_minus_r_over_amplitude", float("nan"))
    else:
        last_full = point.cycles - TAPER_CYCLES  # 0-based end (exclusive) of the full cycles
        after = [c["rms_y_minus_r_m"] for c in summary["cycles"][point.change_cycle + 2:last_full]]
        if len(after) == last_full - point.change_cycle - 2:
            figure = max(after) / amp
    cycles = last_two_full_cycles(scenario, len(s))
    band = float("nan")
    if cycles is not None:
        band = _band_rms(error[cycles[0][1]:cycles[1][2]]) / amp
    lc_error = non_repeating_band_rms(error, scenario) / amp
    lc_command = non_repeating_band_rms(s["voltage_v"], scenario)
    limit = (not math.isfinite(lc_error) or not math.isfinite(lc_command) or lc_error > LIMIT_CYCLE_SHARE
             or lc_command > LIMIT_CYCLE_COMMAND_V)
    met = (not diverged) and math.isfinite(figure) and figure <= point.target and not limit
    return {"group": point.group, "case": point.corner, "figure": figure, "target": point.target,
            "band_error_share": band, "limit_cycle_error_share": lc_error, "limit_cycle_command_v": lc_command,
            "limit_cycle": limit, "met": met, "oil_column_hz": oil_column_hz(scenario.plant_rig),
            "declared_rig_changes": dict(point.rig_changes), "plant_changes": dict(point.plant),
            "timed_changes": [list(c) for c in point.timed]}


def _point(group: str, case: str, isolator: str, supply_bar: float, amplitude_m: float, frequency_hz: float,
           controller: str, base_rig: RigParameters, plant: dict, rig_label: str = "declared", **kwargs):
    return RobustnessPoint(controller, isolator, supply_bar, frequency_hz, amplitude_m, rig_label, case, None,
                           group=group, target=TARGETS[group], base_rig=base_rig, plant=dict(plant), **kwargs)


def robustness_points(controllers=("servo",), base_rig: RigParameters = DEFAULT_RIG, plant: dict | None = None,
                      groups=GROUPS) -> list[RobustnessPoint]:
    """Every case of the suite for each controller. ``base_rig`` is the rig every case starts from (a lab's rig
    file; the cases' own changes go on top, declared), ``plant`` plant-only changes added to every case."""
    plant = dict(plant or {})
    unknown = [g for g in groups if g not in ALL_GROUPS]
    if unknown:
        raise ValueError(f"unknown robustness group(s) {', '.join(unknown)}; allowed: {', '.join(ALL_GROUPS)}")
    points = []
    for c in controllers:
        if "small amplitude" in groups:
            for iso, bar, _a in PAPER_TESTS:
                for a in SMALL_AMPLITUDES_M:
                    for f in SMALL_FREQUENCIES_HZ:
                        points.append(_point("small amplitude", f"{iso} {bar:g} bar {a * 1e3:g} mm {f:g} Hz", iso,
                                             bar, a, f, c, base_rig, plant))
        if SENSITIVITY_GROUPS[0] in groups:
            null = {"driver_offset_v": base_rig.driver_offset_v + NULL_ERROR_V, **plant}
            for iso, bar, _a in PAPER_TESTS:
                for a in SMALL_AMPLITUDES_M:
                    for f in SMALL_FREQUENCIES_HZ:
                        points.append(_point(SENSITIVITY_GROUPS[0], f"{iso} {bar:g} bar {a * 1e3:g} mm {f:g} Hz", iso,
                                             bar, a, f, c, base_rig, null))
        for group in ("soft oil column", SENSITIVITY_GROUPS[1]):
            if group not in groups:
                continue
            for name, changes in OIL_COLUMN_RIGS:
                declared = base_rig.with_changes(**changes)
                hz = oil_column_hz(declared)
                case_plant = dict(plant)
                if group != "soft oil column":
                    case_plant["half_volume_m3"] = VOLUME_ERROR_SHARE * declared.half_volume_m3
                for iso, bar, a in PAPER_TESTS:
                    for f in TEST_FREQUENCIES_HZ:
                        points.append(_point(group, f"{name} ({hz:.1f} Hz) {iso} {bar:g} bar "
                                             f"{a * 1e3:g} mm {f:g} Hz", iso, bar, a, f, c, base_rig, case_plant,
                                             rig_label=name, rig_changes=dict(changes)))
        if "sensor latency" in groups:
            for latency in LATENCIES_S:
                for iso, bar, a in PAPER_TESTS:
                    for f in TEST_FREQUENCIES_HZ:
                        points.append(_point("sensor latency", f"{latency * 1e3:g} ms {iso} {bar:g} bar "
                                             f"{a * 1e3:g} mm {f:g} Hz", iso, bar, a, f, c, base_rig, plant,
                                             rig_label=f"latency {latency * 1e3:g} ms",
                                             rig_changes={"position_latency_s": latency}))
        if "stiffness change" in groups:
            for iso, bar, a, f, names in STIFFNESS_TESTS:
                isolator = load_isolator(iso)
                for factor in STIFFNESS_FACTORS:
                    t_s = CHANGE_AT_CYCLE / f
                    timed = [(t_s, n, factor * getattr(isolator, n)) for n in names]
                    what = "k_d" if names == ("kd_n_per_m",) else "k_d and k_w"
                    points.append(_point("stiffness change", f"{what} x{factor:g} {iso} {bar:g} bar {a * 1e3:g} mm "
                                         f"{f:g} Hz", iso, bar, a, f, c, base_rig, plant, cycles=CHANGE_CYCLES,
                                         change_cycle=CHANGE_AT_CYCLE, timed=timed))
    return points


def check_points(points: list[RobustnessPoint]) -> None:
    """Every case within its rig's envelope, before and after its timed changes (a ProfileError otherwise)."""
    import dataclasses

    from .profiles import validate_profile

    for p in points:
        s = p.scenario()
        s.validate()
        if p.timed:
            changed = {n: v for _t, n, v in p.timed}
            iso = dataclasses.replace(s.isolator, **{n: v for n, v in changed.items() if n in ISOLATOR_PARAMETERS})
            rig = s.rig.with_changes(vertical_load_n=s.effective_vertical_load_n)
            validate_profile(s.profile, rig, iso, s.supply_pa)


# ---------------------------------------------------------------------------------------------------------------
# tables


def _pct(x: float, digits: int = 3) -> str:
    return f"{100 * x:.{digits}f}" if math.isfinite(x) else "nan"


HEADER = ("group", "case", "RMS (y - r) / A %", "target %", "band 5-30 Hz %", "LC error %", "LC command mV",
          "met")


def format_row(r: dict) -> tuple:
    lc = f"{1e3 * r['limit_cycle_command_v']:.2f}" if math.isfinite(r["limit_cycle_command_v"]) else "nan"
    verdict = "met" if r["met"] else "NOT MET" + (" (limit cycle)" if r["limit_cycle"] else "") + \
        (" (diverged)" if r["diverged"] else "")
    return (r["group"], f"{r['controller']} {r['case']}" if r["controller"] != "servo" else r["case"],
            _pct(r["figure"]), f"{100 * r['target']:g}", _pct(r["band_error_share"]),
            _pct(r["limit_cycle_error_share"], 4), lc, verdict)


def robustness_table(rows: list[dict], markdown: bool = True) -> str:
    cells = [HEADER] + [format_row(r) for r in rows]
    if markdown:
        lines = ["| " + " | ".join(cells[0]) + " |", "|" + "---|" * len(HEADER)]
        return "\n".join(lines + ["| " + " | ".join(c) + " |" for c in cells[1:]])
    widths = [max(len(c[i]) for c in cells) for i in range(len(HEADER))]
    return "\n".join("  ".join(c[i].ljust(widths[i]) if i < 2 else c[i].rjust(widths[i]) for i in range(len(HEADER)))
                     for c in cells)


SUMMARY_HEADER = ("group", "controller", "cases", "met", "worst figure %", "target %", "worst case",
                  "limit cycles", "largest LC error %", "largest LC command mV")


def group_summary(rows: list[dict]) -> list[dict]:
    """Per group and controller: cases, how many met, the worst figure and its case, limit cycles."""
    out = []
    keys = []
    for r in rows:
        if (r["group"], r["controller"]) not in keys:
            keys.append((r["group"], r["controller"]))
    for group, controller in keys:
        g = [r for r in rows if r["group"] == group and r["controller"] == controller]
        figures = [r["figure"] if math.isfinite(r["figure"]) else math.inf for r in g]
        worst = g[int(np.argmax(figures))]
        lc_e = [r["limit_cycle_error_share"] for r in g]
        lc_u = [r["limit_cycle_command_v"] for r in g]
        out.append({"group": group, "controller": controller, "cases": len(g), "met": sum(r["met"] for r in g),
                    "worst_figure": max(figures), "target": g[0]["target"], "worst_case": worst["case"],
                    "limit_cycles": sum(r["limit_cycle"] for r in g),
                    "largest_limit_cycle_error_share": max(lc_e) if all(map(math.isfinite, lc_e)) else math.inf,
                    "largest_limit_cycle_command_v": max(lc_u) if all(map(math.isfinite, lc_u)) else math.inf})
    return out


def summary_table(rows: list[dict], markdown: bool = True) -> str:
    cells = [SUMMARY_HEADER]
    for s in group_summary(rows):
        cells.append((s["group"], s["controller"], str(s["cases"]), str(s["met"]), _pct(s["worst_figure"]),
                      f"{100 * s['target']:g}", s["worst_case"], str(s["limit_cycles"]),
                      _pct(s["largest_limit_cycle_error_share"], 4),
                      f"{1e3 * s['largest_limit_cycle_command_v']:.2f}"))
    if markdown:
        lines = ["| " + " | ".join(cells[0]) + " |", "|" + "---|" * len(cells[0])]
        return "\n".join(lines + ["| " + " | ".join(c) + " |" for c in cells[1:]])
    widths = [max(len(c[i]) for c in cells) for i in range(len(cells[0]))]
    return "\n".join("  ".join(c[i].ljust(widths[i]) for i in range(len(c))) for c in cells)


def description(base_rig: RigParameters = DEFAULT_RIG) -> dict:
    """What the suite runs and judges, for the JSON output."""
    return {
        "groups": list(GROUPS), "sensitivity_groups": list(SENSITIVITY_GROUPS),
        "sensitivity": {"valve_null_error_v": NULL_ERROR_V, "half_volume_share": VOLUME_ERROR_SHARE},
        "targets": TARGETS, "band_hz": list(BAND_HZ),
        "limit_cycle": {"error_share": LIMIT_CYCLE_SHARE, "command_v": LIMIT_CYCLE_COMMAND_V},
        "cycles": CYCLES, "taper_cycles": TAPER_CYCLES,
        "stiffness_change": {"cycles": CHANGE_CYCLES, "at_cycle": CHANGE_AT_CYCLE + 1,
                             "judged_from_cycle": CHANGE_AT_CYCLE + 3},
        "oil_column_rigs": [{"name": n, "changes": c, "oil_column_hz": oil_column_hz(base_rig.with_changes(**c))}
                            for n, c in OIL_COLUMN_RIGS],
        "base_rig_oil_column_hz": oil_column_hz(base_rig),
    }


__all__ = ["ALL_GROUPS", "GROUPS", "SENSITIVITY_GROUPS", "TARGETS", "RobustnessPoint", "check_points", "description",
           "group_summary", "jsonable", "oil_column_hz", "robustness_points", "robustness_table", "summary_table"]
