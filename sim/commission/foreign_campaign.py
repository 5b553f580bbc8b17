"""Commissioning and small-motion control on foreign rigs: rigs written from their physics, not from sim's model.

A family of rigs that varies only sim's model's numbers proves that the fit inverts the model. The foreign rigs
(``foreign_rigs``: valve lands and spool, unequal chambers, hoses, pump and accumulator, LuGre friction, specimens
beyond Bouc-Wen, a load cell, late and noisy sensors) are the test instrument. For each drawn rig:

1. **commission it** from what its lab knows (``ForeignRigSpec.lab_knows``: piston area, oil volume, stroke, pump
   flow) at the default bounds; a refused fit is tried once more with the bounds the refusal suggests
   (``Identification.second_attempt``), as an operator would;
2. **judge the values it trusted** against the rig's physics (``ForeignRigSpec.equivalents``): a value the
   controller relies on outside 3 sigma of its truth makes the rig ``wrong_trusted``;
3. **test it** with the commissioned rig file: 20 mm at 0.5 Hz, 2 mm at 1 Hz, 0.5 mm at 1 Hz (12 cycles, taper
   1), with the service's follow monitor; the figure is the tracking verdict's (``summary.tracking_verdict``).

Every run is deterministic in the rig's seed. ``summary(rows)`` is the object ``isorig compare --foreign-rigs N
--json`` prints.
"""

from __future__ import annotations

import math
import textwrap
import time
from dataclasses import dataclass

import numpy as np

from ..controllers.servo import LoopMarginError
from ..engine import Scenario, Simulation
from ..isolator import load_isolator
from ..rig import DEFAULT_RIG, RigParameters
from ..safety import make_limits
from .identify import (
    DEFAULT_MAX_STROKE_M,
    DEFAULT_MAX_VELOCITY_M_PER_S,
    Conditions,
    excitation_limits,
    excitation_scenario,
    identify,
)

SUPPLY_PA = 1.0e7
TEST_CYCLES = 12
#: the cases and the labs' targets on them (RMS |y - r| of the verdict over the amplitude)
CASES = (("20mm_0.5Hz", 0.02, 0.5, 0.001), ("2mm_1Hz", 0.002, 1.0, 0.005), ("0.5mm_1Hz", 0.0005, 1.0, 0.01))
CONTROLLER_ISOLATOR = "IUT_a"  # what the scenario names as mounted; the foreign rig's own specimen is what moves
SIGMAS_WRONG = 3.0


@dataclass(frozen=True)
class ForeignRun:
    """One foreign rig of the family and how to commission it."""

    seed: int
    max_stroke_m: float = DEFAULT_MAX_STROKE_M
    max_velocity_m_per_s: float = DEFAULT_MAX_VELOCITY_M_PER_S
    cases: tuple = CASES


#: what a lab writes in its start rig file (RigParameters names; ForeignRigSpec.lab_knows gives each)
START_FIELDS = ("piston_area_m2", "half_volume_m3", "stroke_m", "pump_max_flow_m3_per_s", "max_supply_pa",
                "command_limit_v")


def start_rig_file_data(lab: dict) -> dict:
    """The start rig file a lab writes from what it knows (catalogue and drawing values), as rig-file data: a
    single-rod actuator's other side as piston_area_b_m2 (a double-rod's sides are equal: not written)."""
    data = {name: float(lab[name]) for name in START_FIELDS}
    other = float(lab.get("rod_side_area_m2", 0.0))
    if other > 0.0 and abs(other - data["piston_area_m2"]) > 1e-9 * data["piston_area_m2"]:
        data["piston_area_b_m2"] = other
    return data


def declared_rig(lab: dict) -> RigParameters:
    """The rig of that start file: everything the controller relies on beyond it is isorig's default until
    commissioning measures it."""
    return DEFAULT_RIG.with_changes(**start_rig_file_data(lab))


def judged_values(ident, spec, declared: RigParameters) -> dict:
    """Each value the controller relies on, fitted and true (the rig's physics), with its one-sigma uncertainty;
    the oil column judged as its stiffness 2 beta A_p^2 / V_0 with the declared A_p and V_0, the valve's dead
    zone as the commands at its edges (``valve_edges``)."""
    truth = spec.equivalents(SUPPLY_PA)
    est = ident.fit.estimates
    out = {}
    for name in ("mass_kg", "position_latency_s", "valve_natural_frequency_rad_s"):
        if name in truth and name in est:
            out[name] = (est[name].value, est[name].std, truth[name])
    for name, edge in valve_edges(est).items():
        if name in truth:
            out[name] = (*edge, truth[name])
    if "bulk_modulus_pa" in est:
        scale = 2.0 * declared.piston_area_m2 ** 2 / declared.half_volume_m3
        e = est["bulk_modulus_pa"]
        out["oil_column_stiffness_n_per_m"] = (e.value * scale, e.std * scale, truth["oil_column_stiffness_n_per_m"])
    return out


def valve_edges(est: dict) -> dict:
    """The commands at which the fitted valve opens each way, (value, one sigma) in V: eq. (2) and the dead zone
    give u = dz - v_e0 towards +y and u = -(dz + v_e0) / k_en towards -y (the dead-zone inverse's edges; the
    sigmas from those of dz, v_e0 and k_en, taken as independent)."""
    if not all(n in est for n in ("dead_zone_v", "driver_offset_v", "driver_gain_negative")):
        return {}
    dz, v0, k = (est[n] for n in ("dead_zone_v", "driver_offset_v", "driver_gain_negative"))
    negative = -(dz.value + v0.value) / k.value
    return {"valve_edge_positive_v": (dz.value - v0.value, math.hypot(dz.std, v0.std)),
            "valve_edge_negative_v": (negative, math.hypot(dz.std / k.value, v0.std / k.value,
                                                           negative * k.std / k.value))}


def wrong_values(values: dict) -> list[str]:
    """The names of the values outside SIGMAS_WRONG of their truth."""
    wrong = []
    for name, (value, std, true_value) in values.items():
        if not (math.isfinite(value) and math.isfinite(std)) or abs(value - true_value) > SIGMAS_WRONG * std:
            wrong.append(name)
    return wrong


def commission(spec, declared: RigParameters, max_stroke_m: float, max_velocity_m_per_s: float):
    """One commissioning run of the foreign rig and its fit (sim.commission.identify)."""
    load = float(spec.drawn["table.vertical_load_n"])
    conditions = Conditions("simulated", SUPPLY_PA, load, "foreign", 0.0, max_stroke_m, max_velocity_m_per_s)
    scenario = excitation_scenario(load_isolator(CONTROLLER_ISOLATOR), conditions, declared)
    scenario.foreign_rig = spec
    limits = make_limits(declared, excitation_limits(conditions))  # the run's bounds close the valve, as on a rig
    samples = Simulation(scenario, validate=False).run(limits=limits).samples
    return identify(samples, declared, conditions)


def commissioning_section(ident, max_velocity_m_per_s: float) -> dict:
    """What a rig file's ``commissioning`` section tells the follow monitor and the verdict (sim.follow
    commissioning_facts): trusted, the velocity bound, the latency's estimate with its uncertainty."""
    latency = ident.fit.estimates["position_latency_s"]
    return {"trusted": ident.trusted, "max_velocity_m_per_s": max_velocity_m_per_s,
            "estimates": {"position_latency_s": {"value": latency.value, "std": latency.std}}}


def tested(spec, rig: RigParameters, amplitude_m: float, frequency_hz: float,
           commissioning: dict | None = None, controller_options: dict | None = None) -> dict:
    """One sine on the foreign rig with the controller told ``rig`` (and its ``commissioning`` section: the verdict
    judges the latency within its uncertainty); with the service's follow monitor. A rig on which the servo's loop
    cannot be made stable enough as told (LoopMarginError, before anything moves) gives ``stop_kind`` "refused"
    and the refusal's words (``why``), not an error that ends the campaign."""
    scenario = Scenario.sine(load_isolator(CONTROLLER_ISOLATOR), SUPPLY_PA / 1e5, amplitude_m, frequency_hz,
                             TEST_CYCLES, rig=rig, vertical_load_n=float(spec.drawn["table.vertical_load_n"]),
                             foreign_rig=spec, rig_commissioning=commissioning,
                             controller_options=dict(controller_options or {}))
    try:
        result = Simulation(scenario, validate=False).run(follow=True)
    except LoopMarginError as refused:  # the servo refuses the rig as told before anything moves: a case's outcome
        return {"share": None, "verdict": "refused", "stopped_s": 0.0, "stop_kind": "refused", "why": str(refused),
                "table_share": None}
    summary = result.summary()
    verdict = summary["tracking_verdict"]
    trip = result.trip
    # a stop at the actuator's force limit (sim.force_limit) is counted as that, not as the detector that stopped it
    kind = None if trip is None else trip.values.get("cause") or trip.values.get("kind", trip.detector)
    # the table's own figure: the simulation knows where the table was (sim.tracking's last two cycles, the true
    # position against the target), which the verdict, judging the reading with the latency's uncertainty, may not
    table = summary.get("last_two_cycles", {}).get("rms_y_minus_r_over_amplitude")
    return {"share": verdict.get("rms_share"), "verdict": verdict["verdict"],
            "stopped_s": None if trip is None else trip.time_s, "stop_kind": kind, "table_share": table}


def first_attempt(seed: int, max_stroke_m: float = DEFAULT_MAX_STROKE_M,
                  max_velocity_m_per_s: float = DEFAULT_MAX_VELOCITY_M_PER_S, noise_seed: int | None = None):
    """Rig SEED drawn and commissioned once from what its lab knows: (spec, declared rig, identification).
    ``noise_seed``: another realisation of its sensors' noise (default: the rig's own, SEED), as when a lab
    commissions the same rig again (scripts/foreign_repeat.py)."""
    from foreign_rigs import draw_rig
    from foreign_rigs import physics as ph

    spec = draw_rig(seed)
    if noise_seed is not None:
        spec.params[ph.P_SEED] = float(noise_seed)
    declared = declared_rig(spec.lab_knows())
    return spec, declared, commission(spec, declared, max_stroke_m, max_velocity_m_per_s)


@dataclass
class LabCommissioning:
    """A foreign rig commissioned as its lab would (``commission_as_a_lab``): the first attempt, and the last one
    with the velocity bound it ran at."""

    spec: object
    declared: RigParameters
    first: object  # sim.commission.identify.Identification
    last: object
    attempts: int
    max_velocity_m_per_s: float


def commission_as_a_lab(run: ForeignRun) -> LabCommissioning:
    """Rig ``run.seed`` commissioned once at the run's bounds and, where the refusal suggests other bounds
    (``Identification.second_attempt``), once more with them, as an operator would."""
    spec, declared, first = first_attempt(run.seed, run.max_stroke_m, run.max_velocity_m_per_s)
    out = LabCommissioning(spec, declared, first, first, 1, run.max_velocity_m_per_s)
    retry = None if first.trusted else first.second_attempt()
    if retry is not None:
        out.last = commission(spec, declared, retry["max_stroke_m"], retry["max_velocity_m_per_s"])
        out.attempts, out.max_velocity_m_per_s = 2, retry["max_velocity_m_per_s"]
    return out


def commission_and_test(run: ForeignRun) -> dict:
    """A row: the rig, its commissioning (first attempt, and a second where the first suggests one), the judged
    values and the cases."""
    t0 = time.perf_counter()
    lab = commission_as_a_lab(run)
    spec, declared, ident = lab.spec, lab.declared, lab.last
    row = {"seed": run.seed, "name": spec.name, "first_trusted": lab.first.trusted, "attempts": lab.attempts,
           "first_problems": list(lab.first.problems)}
    if lab.attempts == 2:
        row["retry_max_velocity_m_per_s"] = lab.max_velocity_m_per_s
    row["trusted"] = ident.trusted
    row["problems"] = list(ident.problems)
    row["commission_wall_s"] = time.perf_counter() - t0
    row["wrong"] = []
    if ident.fit is not None:
        values = judged_values(ident, spec, declared)
        for name, (value, std, true_value) in values.items():
            row[f"fit.{name}"] = value
            row[f"std.{name}"] = std
            row[f"true.{name}"] = true_value
        if ident.trusted:
            row["wrong"] = wrong_values(values)
    if ident.trusted:
        section = commissioning_section(ident, lab.max_velocity_m_per_s)
        for label, amplitude_m, frequency_hz, _target in run.cases:
            row.update({f"{label}.{k}": v for k, v in
                        tested(spec, ident.rig, amplitude_m, frequency_hz, section).items()})
    for key in ("actuator.rod", "valve.lap", "valve.spool_frequency_hz", "table.mass_kg", "specimen.kind",
                "sensors.position_latency_s"):
        row[f"drawn.{key}"] = spec.drawn[key]
    return row


def run_chunk(runs: list[ForeignRun]) -> list[dict]:
    """A worker's task (sim.campaign.Engine.map)."""
    return [commission_and_test(r) for r in runs]


def case_figures(outcomes: list[dict], target: float) -> dict:
    """One case's figures over ``tested``'s outcomes (each with ``share``, ``stopped_s``, ``stop_kind``): the runs,
    the worst and median share in %, the stops by the campaign's kinds, and how many ran to their end within
    ``target``."""
    shares = [100.0 * o["share"] for o in outcomes if o["share"] is not None]
    kinds = [o["stop_kind"] for o in outcomes if o["stopped_s"] is not None]
    return {
        "runs": len(outcomes),
        "worst_pct": max(shares) if shares else None,
        "median_pct": float(np.median(shares)) if shares else None,
        "oscillation_stops": kinds.count("oscillation"),
        "force_limit_stops": kinds.count("force_limit"),
        "refused_before_start": kinds.count("refused"),
        "other_stops": sum(1 for k in kinds if k not in ("oscillation", "force_limit", "refused")),
        "within_target": sum(1 for o in outcomes if o["stopped_s"] is None and o["share"] is not None
                             and o["share"] <= target),
        "target_pct": 100.0 * target,
    }


def summary(rows: list[dict], cases: tuple = CASES) -> dict:
    """The figures of ``isorig compare --foreign-rigs N --json`` (docs/commissioning.md, "Foreign rigs")."""
    out = {"rigs": len(rows), "commissioned_first_attempt": sum(1 for r in rows if r["first_trusted"]),
           "commissioned": sum(1 for r in rows if r["trusted"]),
           "wrong_trusted": sum(1 for r in rows if r["trusted"] and r["wrong"]), "cases": {}}
    for label, _a, _f, target in cases:
        ran = [r for r in rows if r["trusted"] and f"{label}.verdict" in r]
        out["cases"][label] = case_figures([{k: r[f"{label}.{k}"] for k in ("share", "stopped_s", "stop_kind")}
                                            for r in ran], target)
    return out


#: a refusal's reason by its words (sim.commission.identify.trust_problems), for the tables
PROBLEM_CATEGORIES = (("force balance", "the force balance explains too little of the measured forces"),
                      ("flow balance", "the flow balance explains too little of the motion"),
                      ("given the same commands", "the fitted rig's replay misses the measured velocity"),
                      ("reproduces", "the fitted rig's replay misses the measured velocity"),
                      ("is uncertain by", "a value the controller relies on is too uncertain"),
                      ("not a positive value", "a fitted value is not positive"),
                      ("not a rig", "the fitted values are not a rig"),
                      ("bound", "a fitted value ended on the fit's bound"),
                      ("did not run to its end", "the excitation did not run to its end"),
                      ("the dither never ran", "the sweeps did not find the valve's edges both ways (no dither)"))


def problem_categories(problem: str) -> set[str]:
    """The categories of a refusal's text (PROBLEM_CATEGORIES; a text may hold several reasons), or its first
    words."""
    found = {category for words, category in PROBLEM_CATEGORIES if words in problem}
    return found or {problem[:80]}


def markdown(rows: list[dict], cases: tuple = CASES) -> str:
    """The summary as the tables of docs/commissioning.md."""
    s = summary(rows, cases)
    n = s["rigs"]
    lines = ["| commissioning | rigs |", "|---|---|", f"| drawn | {n} |",
             f"| trusted at the first attempt | {s['commissioned_first_attempt']} |",
             f"| trusted (with a second attempt where suggested) | {s['commissioned']} |",
             f"| trusted with a value outside 3 sigma of its truth | {s['wrong_trusted']} |", "",
             "| case | runs | within target | median % | worst % | oscillation stops | force-limit stops "
             "| refused before start | other stops |",
             "|---|---|---|---|---|---|---|---|---|"]
    for label, c in s["cases"].items():
        med = "-" if c["median_pct"] is None else f"{c['median_pct']:.3g}"
        worst = "-" if c["worst_pct"] is None else f"{c['worst_pct']:.3g}"
        lines.append(f"| {label} (<= {c['target_pct']:g} %) | {c['runs']} | {c['within_target']} | {med} | {worst} | "
                     f"{c['oscillation_stops']} | {c['force_limit_stops']} | {c['refused_before_start']} | "
                     f"{c['other_stops']} |")
    reasons: dict[str, int] = {}
    for r in rows:
        if not r["trusted"]:
            problems = r["problems"] if isinstance(r["problems"], list) else [r["problems"]]
            for key in sorted({c for p in problems for c in problem_categories(p)}):
                reasons[key] = reasons.get(key, 0) + 1
    if reasons:
        lines += ["", "| refusal reason (of the refused rigs' last attempt) | rigs |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1])[:10]]
    return "\n".join(lines)


def figure(rows: list[dict], title: str, cases: tuple = CASES):
    """The tracking figures of the commissioned rigs per case (ECDF), and what became of every rig."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (NullFormatter below)

    fig, axes = plt.subplots(1, len(cases) + 2, figsize=(4.2 * (len(cases) + 2), 4.5), squeeze=False,
                             gridspec_kw={"width_ratios": [1.0, 1.6] + [1.0] * len(cases)})
    ax0 = axes[0][0]
    n = len(rows)
    first = sum(1 for r in rows if r["first_trusted"])
    trusted = sum(1 for r in rows if r["trusted"])
    wrong = sum(1 for r in rows if r["trusted"] and r["wrong"])
    ax0.bar(["trusted,\nfirst attempt", "trusted", "trusted with\na wrong value", "refused"],
            [first, trusted, wrong, n - trusted], color=["tab:green", "tab:olive", "tab:red", "tab:gray"])
    ax0.set_ylabel("rigs")
    ax0.set_title(f"commissioning, {n} foreign rigs")
    ax0.tick_params(axis="x", labelsize=7)
    reasons: dict[str, int] = {}
    for r in rows:
        if not r["trusted"]:
            problems = r["problems"] if isinstance(r["problems"], list) else [r["problems"]]
            for key in {c for p in problems for c in problem_categories(p)}:
                reasons[key] = reasons.get(key, 0) + 1
    ranked = sorted(reasons.items(), key=lambda kv: kv[1])[-7:]
    ax1 = axes[0][1]
    ax1.barh([textwrap.fill(k.replace("the ", "").replace(" of the measured forces", ""), 34) for k, _ in ranked],
             [v for _, v in ranked], color="tab:gray")
    ax1.tick_params(axis="y", labelsize=7)
    ax1.set_xlabel("refused rigs giving this reason")
    ax1.set_title("why the fit was refused")
    for ax, (label, _a, _f, target) in zip(axes[0][2:], cases, strict=True):
        v = np.sort([100 * r[f"{label}.share"] for r in rows if r.get(f"{label}.share") is not None
                     and r.get(f"{label}.stopped_s") is None])
        refused = sum(1 for r in rows if r.get(f"{label}.stop_kind") == "refused")
        stopped = sum(1 for r in rows if r.get(f"{label}.stopped_s") is not None) - refused
        if v.size:
            said = f"ran to the end ({v.size}); stopped: {stopped}" + (f"; refused: {refused}" if refused else "")
            ax.step(v, np.arange(1, v.size + 1) / max(trusted, 1), where="post", marker="o", ms=2.5, label=said)
        ax.set_ylim(0.0, 1.15)  # room above the curve for the legend
        ax.axvline(100 * target, color="k", lw=0.8, ls=":", label=f"target {100 * target:g} %")
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("RMS |y - r| of the verdict, % of the amplitude")
        ax.set_ylabel("share of the commissioned rigs")
        ax.set_title(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="upper left", framealpha=0.9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
