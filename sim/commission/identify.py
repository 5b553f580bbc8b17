"""Commissioning: from a run of the excitation to a rig file the lab can trust, or a refusal that says why.

``excitation_scenario`` is the run (sim.controllers.excitation around the table's resting position, within
the operator's stroke and velocity bounds); any driver runs it through the same loop and detectors as a test.
``identify(samples, declared, conditions)`` fits the record (sim.commission.fit), builds the commissioned rig
(the declared rig with every fitted value), replays the commands on it (sim.commission.response) and judges
the result (``trust_problems``): a rig file is written only from a fit that explains the record, whose
uncertainties are small enough for the controller, and whose values are a rig.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..controllers.excitation import dither_lines, excitation_duration_s
from ..errors import FieldError
from ..history import HistoryTarget
from ..isolator import Isolator
from ..loop import CONTROL_PERIOD_S
from ..rig import RigError, RigParameters
from ..samples import Samples
from .bounds import DEFAULT_MAX_STROKE_M, DEFAULT_MAX_VELOCITY_M_PER_S
from .fit import ONE_BLAS_THREAD, RigFit, fit_rig
from .flow import LOWER, UPPER
from .response import FrequencyResponse, dither_response
from .signals import FitError, signals_from_samples

STROKE_RANGE_M = (2e-4, 0.01)
VELOCITY_RANGE_M_PER_S = (0.01, 0.1)  # below 10 mm/s a sticking table breaks away faster than the bound
GUARD_SHARE = 0.75  # the excitation's own guard: this share of the stroke bound (the detector sits at the bound)
MAX_RIG_TIME_S = 60.0
#: a refused fit's second attempt (second_attempt): this many times the velocity bound, at most this, m/s
RETRY_VELOCITY_SHARE = 2.0
RETRY_MAX_VELOCITY_M_PER_S = 0.04
#: a run that stopped with the table at this share of the velocity bound stopped at the bound (the velocity
#: detector reads the same 5-period difference as record_figures)
VELOCITY_STOP_SHARE = 0.95

#: what a fit must reach before its rig file is written (docs/commissioning.md, "When a fit is refused")
MIN_FLOW_R2 = 0.98
MIN_FORCE_R2 = 0.9
MAX_VELOCITY_NRMSE = 0.2
MIN_OPENING_SHARE = 0.3  # the dither must open the valve past its dead zone in this share of its periods
#: largest one-sigma uncertainty of each value the controller relies on: relative, or absolute (V, s)
#: (k_en, ``driver_gain_negative``, is not among them: no controller uses it; the flow gain, which the servo adapts,
#: may be 30 % off for 1 % at 0.5 mm: scripts/parameter_sensitivity.py, docs/commissioning.md)
MAX_RELATIVE_STD = {"flow_gain_m3_per_s_v_sqrt_pa": 0.1, "mass_kg": 0.2, "bulk_modulus_pa": 0.2,
                    "valve_natural_frequency_rad_s": 0.2}
MAX_ABSOLUTE_STD = {"dead_zone_v": 0.03, "driver_offset_v": 0.03, "position_latency_s": 3e-4}
#: systematic allowance added to the jackknife's spread (what the fit's model leaves out; measured on 200
#: simulated plants by scripts/commissioning_targets.py, and for the valve on the foreign rigs 0-39 of
#: scripts/foreign_fits.py: a second-order valve is a model of a spool with flow forces, lands and play, whose
#: fitted frequency came 5-25 % below the spool's, and a dead zone's edges are soft where lands leak, 10-25 mV):
#: relative share of the value, or absolute
SYSTEMATIC_RELATIVE = {"flow_gain_m3_per_s_v_sqrt_pa": 0.005, "driver_gain_negative": 0.005, "mass_kg": 0.02,
                       "bulk_modulus_pa": 0.02, "valve_natural_frequency_rad_s": 0.1, "valve_damping_ratio": 0.02,
                       "friction_force_n": 0.02, "viscous_n_s_per_m": 0.3, "presliding_m": 0.2,
                       "bristle_damping_n_s_per_m": 0.3}
SYSTEMATIC_ABSOLUTE = {"dead_zone_v": 0.01, "driver_offset_v": 0.01, "position_latency_s": 5e-5}


#: the jackknife's spread is widened this much: from 5 groups it has 4 degrees of freedom (Student's t at the
#: 3-sigma level is 2.2 times the normal's), and on foreign rigs 0-299 the values that passed every other rule
#: came up to 3.6-7.3 of its sigmas (plus allowance) off their truth; widened 2x, none beyond 3
#: (docs/commissioning.md, "Uncertainties")
JACKKNIFE_WIDENING = 2.0
#: what the flow balance leaves unexplained as an uncertainty of the values it gives the oil column and the valve:
#: this many times sqrt(1 - R^2) of the value (a soft column's air and hoses, a valve's lands and play: on foreign
#: rigs 0-299 the oil column came 13-17 % off with 3-4 % stated at flow R^2 0.994-0.997, a valve 30-65 % off at
#: 0.982-0.993; with this term none beyond 3 sigma)
MODEL_ERROR_PER_UNEXPLAINED = {"bulk_modulus_pa": 2.0, "valve_natural_frequency_rad_s": 2.0}
#: and what the force balance leaves unexplained, of the mass it gives (a load cell's resonance, a lead core's
#: heating, friction laws beyond Dahl's: foreign rig 512, force R^2 0.980, its mass 11 % off with 3.2 % stated;
#: this term, 0.5 sqrt(1 - R^2), is twice what brings it within 3 sigma, and refused none of the 132 rigs trusted
#: on rigs 0-599 with the valve's play and lap fitted)
MODEL_ERROR_PER_UNEXPLAINED_FORCE = {"mass_kg": 0.5}
#: and of the latency it gives, as a share of the fitted valve's lag 2 xi_v / w_v: the flow balance tells the sum
#: of the two delays well and their split only as well as its model fits the valve (a delay and a second-order lag
#: differ in a cubic term below the valve's corner). Foreign rig 231 (an underlapped 51 Hz spool damped 0.87,
#: commissioned at 40 mm/s): latency 2.62 +- 0.18 ms against 1.99, the valve's lag 4.5 ms against 5.4, flow R^2
#: 0.998, and the force balance's Stribeck-shifted latency agreeing by chance. On rigs 0-299 with their second
#: attempts, 0.6 brings it within 3 sigma, 1.0 keeps 139 of the 142 trusted, 2.0 (the valve's own) keeps 130
LATENCY_PER_VALVE_LAG_UNEXPLAINED = 1.0
#: how far a value moves when its fit starts elsewhere in the cost's valley (sim.commission.fit.start_shifts), as an
#: uncertainty: this share of the move. On the 188 foreign rigs of 0-599 trusted or refused for the latency alone,
#: 0.5 brings rig 121 (its latency 5.4 sigma off) within 3 sigma and keeps 134 of the 140 trusted (the six it
#: refuses were at 0.26-0.30 ms of the 0.3 ms allowed); 1.0 keeps 110
START_SHIFT_SHARE = 0.5


class CommissioningError(FieldError):
    """Bounds or conditions a commissioning run cannot take; names the field, the value and what is allowed."""


@dataclass(frozen=True)
class Conditions:
    """Where and how the rig was commissioned (the rig file's provenance)."""

    rig: str  # "simulated" or udp://HOST:PORT
    supply_pa: float
    vertical_load_n: float
    specimen: str  # the isolator mounted, or "none"
    start_m: float
    max_stroke_m: float = DEFAULT_MAX_STROKE_M
    max_velocity_m_per_s: float = DEFAULT_MAX_VELOCITY_M_PER_S

    def to_dict(self) -> dict:
        return asdict(self)


def check_bounds(max_stroke_m: float, max_velocity_m_per_s: float, rig: RigParameters, start_m: float) -> None:
    """A clear CommissioningError for bounds outside what commissioning takes or the rig allows."""
    lo, hi = STROKE_RANGE_M
    if not (isinstance(max_stroke_m, (int, float)) and math.isfinite(max_stroke_m) and lo <= max_stroke_m <= hi):
        raise CommissioningError("max_stroke_m", max_stroke_m, f"[{lo:g}, {hi:g}] m",
                                 f"max_stroke_m = {max_stroke_m!r} m is outside [{lo * 1e3:g}, {hi * 1e3:g}] mm")
    lo, hi = VELOCITY_RANGE_M_PER_S
    if not (isinstance(max_velocity_m_per_s, (int, float)) and math.isfinite(max_velocity_m_per_s)
            and lo <= max_velocity_m_per_s <= hi):
        raise CommissioningError("max_velocity_m_per_s", max_velocity_m_per_s, f"[{lo:g}, {hi:g}] m/s",
                                 f"max_velocity_m_per_s = {max_velocity_m_per_s!r} m/s is outside "
                                 f"[{lo * 1e3:g}, {hi * 1e3:g}] mm/s")
    if abs(start_m) + max_stroke_m > rig.stroke_m:
        raise CommissioningError("max_stroke_m", max_stroke_m, f"<= {rig.stroke_m - abs(start_m):g} m",
                                 f"the table rests at {start_m * 1e3:.2f} mm: +-{max_stroke_m * 1e3:g} mm around it "
                                 f"passes the rig's stroke of +-{rig.stroke_m * 1e3:g} mm; move it towards zero first")


def excitation_options(max_stroke_m: float, max_velocity_m_per_s: float) -> dict:
    """The excitation controller's options for these bounds."""
    return {"guard_m": GUARD_SHARE * max_stroke_m, "max_velocity_m_per_s": max_velocity_m_per_s}


def excitation_target(start_m: float, options: dict) -> HistoryTarget:
    """The run's target: the table's resting position, held for the excitation's whole length."""
    n = int(math.ceil(excitation_duration_s(options) / CONTROL_PERIOD_S))
    return HistoryTarget(np.full(n, float(start_m)), np.zeros(n), np.zeros(n), CONTROL_PERIOD_S,
                         source=f"commissioning excitation about {start_m * 1e3:.3f} mm", scale=1.0, taper_in_s=0.0,
                         taper_out_s=0.0, duration_s=n * CONTROL_PERIOD_S, source_dt_s=CONTROL_PERIOD_S,
                         source_samples=n)


def excitation_scenario(isolator: Isolator, conditions: Conditions, declared: RigParameters,
                        plant_changes: dict | None = None):
    """The commissioning run as a sim.engine.Scenario (``plant_changes``: a simulated rig unlike the declared)."""
    from ..engine import Scenario

    check_bounds(conditions.max_stroke_m, conditions.max_velocity_m_per_s, declared, conditions.start_m)
    options = excitation_options(conditions.max_stroke_m, conditions.max_velocity_m_per_s)
    return Scenario(isolator, conditions.supply_pa, [], "excitation", controller_options=options, rig=declared,
                    vertical_load_n=conditions.vertical_load_n, plant_changes=dict(plant_changes or {}),
                    history=excitation_target(conditions.start_m, options))


def excitation_limits(conditions: Conditions) -> dict:
    """Operator limits of the run (backend.safety): the stroke and velocity bounds, each closing the valve."""
    return {"displacement_m": abs(conditions.start_m) + conditions.max_stroke_m,
            "velocity_m_per_s": conditions.max_velocity_m_per_s,
            "tracking_error_m": 2.0 * conditions.max_stroke_m,
            "actions": {"displacement_m": "valve_close", "velocity_m_per_s": "valve_close",
                        "tracking_error_m": "valve_close"}}


def commissioned_rig(fit: RigFit, declared: RigParameters, vertical_load_n: float) -> RigParameters:
    """The declared rig with every fitted value. The friction fitted at one vertical load is F_f = mu N + F_c:
    the declared mu is kept and F_c takes the rest (mu is lowered when F_f is below mu N)."""
    friction = fit.value("friction_force_n")
    mu = declared.friction_coefficient
    if friction < mu * vertical_load_n:
        mu = max(friction, 0.0) / vertical_load_n if vertical_load_n > 0 else 0.0
    coulomb = max(0.0, friction - mu * vertical_load_n)
    return declared.with_changes(
        mass_kg=fit.value("mass_kg"), friction_coefficient=mu, coulomb_force_n=coulomb,
        viscous_n_s_per_m=max(0.0, fit.value("viscous_n_s_per_m")),
        flow_gain_m3_per_s_v_sqrt_pa=fit.value("flow_gain_m3_per_s_v_sqrt_pa"),
        driver_gain_positive=1.0, driver_gain_negative=fit.value("driver_gain_negative"),
        dead_zone_v=max(0.0, fit.value("dead_zone_v")), underlap_v=max(0.0, -fit.value("dead_zone_v")),
        driver_offset_v=fit.value("driver_offset_v"), valve_play_v=max(0.0, fit.value("valve_play_v")),
        valve_natural_frequency_rad_s=fit.value("valve_natural_frequency_rad_s"),
        valve_damping_ratio=fit.value("valve_damping_ratio"), bulk_modulus_pa=fit.value("bulk_modulus_pa"),
        position_latency_s=max(0.0, fit.value("position_latency_s")))


def friction_law(fit: RigFit) -> tuple[float, float, float] | None:
    """(F_c, delta, sigma_1) of the Dahl law when the fit chose it over Coulomb's (sim.commission.force), else None."""
    delta = fit.value("presliding_m")
    if not delta > 0.0:
        return None
    return fit.value("friction_force_n"), delta, fit.value("bristle_damping_n_s_per_m")


def with_systematic(fit: RigFit) -> None:
    """Widen each estimate's jackknife spread (JACKKNIFE_WIDENING) and add the fit model's systematic allowance,
    what each balance leaves unexplained (MODEL_ERROR_PER_UNEXPLAINED, _FORCE; the latency's as a share of the
    valve's lag, LATENCY_PER_VALVE_LAG_UNEXPLAINED), the valve law's disagreement between
    the record's parts (sim.commission.flow.part_disagreement), the latency's between the two balances, how
    far each value moves with the readings' noise doubled (sim.commission.fit.noise_shifts) and START_SHIFT_SHARE
    of how far it moves when its fit starts elsewhere (sim.commission.fit.start_shifts) (in place)."""
    unexplained = math.sqrt(max(0.0, 1.0 - fit.flow_r2)) if math.isfinite(fit.flow_r2) else 1.0
    unexplained_force = math.sqrt(max(0.0, 1.0 - fit.force_r2)) if math.isfinite(fit.force_r2) else 1.0
    for name, e in fit.estimates.items():
        floor = SYSTEMATIC_RELATIVE.get(name, 0.0) * abs(e.value) + SYSTEMATIC_ABSOLUTE.get(name, 0.0)
        model = math.hypot(MODEL_ERROR_PER_UNEXPLAINED.get(name, 0.0) * unexplained,
                           MODEL_ERROR_PER_UNEXPLAINED_FORCE.get(name, 0.0) * unexplained_force) * abs(e.value)
        if name == "position_latency_s":
            model = math.hypot(model, LATENCY_PER_VALVE_LAG_UNEXPLAINED * unexplained * valve_lag_s(fit))
        e.std = math.hypot(JACKKNIFE_WIDENING * e.std, floor, model, fit.disagreement.get(name, 0.0),
                           fit.noise_shift.get(name, 0.0), START_SHIFT_SHARE * fit.start_shift.get(name, 0.0))


def valve_lag_s(fit: RigFit) -> float:
    """The fitted valve's low-frequency delay 2 xi_v / w_v (eq. 3, third line), in s (0 for a value that is not
    a valve's, or a fit without one)."""
    if not {"valve_natural_frequency_rad_s", "valve_damping_ratio"} <= fit.estimates.keys():
        return 0.0
    w, xi = fit.value("valve_natural_frequency_rad_s"), fit.value("valve_damping_ratio")
    return 2.0 * xi / w if math.isfinite(w) and math.isfinite(xi) and w > 0.0 and xi > 0.0 else 0.0


def response_problems(response: FrequencyResponse | None) -> list[str]:
    """Why the dither or the fitted rig's replay of it says the fit is not the rig (empty: it may be)."""
    if response is None:
        return []
    problems = []
    if response.opening_share < MIN_OPENING_SHARE:
        problems.append(f"the dither opened the valve past its dead zone in {100 * response.opening_share:.0f} % of "
                        f"its periods (at least {100 * MIN_OPENING_SHARE:g} % are needed): it did not show the valve's "
                        "dynamics; run it again (a sweep may have taken a spring-back for the valve's edge)")
    nrmse = response.velocity_nrmse
    if not math.isfinite(nrmse):
        problems.append("the fitted rig, given the same commands, did not stay finite: it is not this rig")
    elif nrmse > MAX_VELOCITY_NRMSE:
        problems.append(f"the fitted rig, given the same commands, reproduces the table's velocity to "
                        f"{100 * nrmse:.0f} % RMS; at most {100 * MAX_VELOCITY_NRMSE:g} % is needed")
    return problems


def trust_problems(fit: RigFit) -> list[str]:
    """Why the fit may not become a rig file (empty: it may), from the fit alone."""
    problems = []
    if fit.flow_r2 < MIN_FLOW_R2:
        problems.append(f"the flow balance (eq. 3, second line) explains {100 * fit.flow_r2:.1f} % of the table's "
                        f"motion; at least {100 * MIN_FLOW_R2:g} % is needed")
    if fit.force_r2 < MIN_FORCE_R2:
        problems.append(f"the force balance (eq. 3, first line) explains {100 * fit.force_r2:.1f} % of the measured "
                        f"forces; at least {100 * MIN_FORCE_R2:g} % is needed")
    for name, limit in MAX_RELATIVE_STD.items():
        e = fit.estimates[name]
        if not (math.isfinite(e.value) and e.value > 0):
            problems.append(f"{name} = {e.value:.4g} {e.unit} is not a positive value")
        elif e.relative > limit:
            problems.append(f"{name} is uncertain by +-{100 * e.relative:.0f} % (one sigma); at most "
                            f"+-{100 * limit:g} % is needed")
    for name, limit in MAX_ABSOLUTE_STD.items():
        e = fit.estimates[name]
        if e.std > limit:
            problems.append(f"{name} is uncertain by +-{e.std:.3g} {e.unit} (one sigma); at most +-{limit:g} "
                            f"{e.unit} is needed")
    bounds = {"valve_natural_frequency_rad_s": (2 * math.pi * LOWER[2], 2 * math.pi * UPPER[2]),
              "valve_damping_ratio": (LOWER[3], UPPER[3]), "position_latency_s": (LOWER[4] * 1e-3, UPPER[4] * 1e-3),
              "driver_gain_negative": (LOWER[5], UPPER[5])}
    for name, (lo, hi) in bounds.items():
        value = fit.value(name)
        if value <= lo * 1.001 or value >= hi * 0.999:
            problems.append(f"{name} = {value:.4g} ended on the fit's bound ([{lo:.4g}, {hi:.4g}]): the record does "
                            "not show it")
    return problems


@dataclass
class Identification:
    """The outcome of a commissioning: the fit, the commissioned rig (None when refused), the frequency
    response, why it was refused (``problems``), the conditions and the record's figures."""

    conditions: Conditions
    declared: RigParameters
    fit: RigFit | None = None
    rig: RigParameters | None = None
    response: FrequencyResponse | None = None
    problems: list[str] = field(default_factory=list)
    record: dict = field(default_factory=dict)  # rig time, peaks of the motion, phases reached

    @property
    def trusted(self) -> bool:
        return self.rig is not None and not self.problems

    def second_attempt(self) -> dict | None:
        """What to change for a second run after a refusal (``second_attempt``), or None."""
        return None if self.trusted else second_attempt(self.problems, self.conditions)

    def changed(self) -> dict:
        """The commissioned values that differ from the declared rig, by name."""
        if self.rig is None:
            return {}
        return {name: getattr(self.rig, name) for name in RigParameters.__dataclass_fields__
                if getattr(self.rig, name) != getattr(self.declared, name)}

    def to_dict(self) -> dict:
        return {"trusted": self.trusted, "problems": list(self.problems), "second_attempt": self.second_attempt(),
                "conditions": self.conditions.to_dict(),
                "record": dict(self.record), "fit": self.fit.to_dict() if self.fit else None,
                "response": self.response.to_dict() if self.response else None, "changed": self.changed()}


def second_attempt(problems: list[str], conditions: Conditions) -> dict | None:
    """The bounds of a second commissioning run after a refusal, with why, or None when a second run at other
    bounds cannot help: a fit or replay that did not explain the record, or values too uncertain for the
    controller, get RETRY_VELOCITY_SHARE times the velocity bound (more motion over the rig's friction and its
    readings' noise), up to RETRY_MAX_VELOCITY_M_PER_S, and so does an excitation stopped at the velocity bound
    (a valve faster than its sweeps allowed for); the stroke bound stays (docs/commissioning.md, "When a fit is
    refused")."""
    words = " ".join(problems)
    at_bound = "against the velocity bound" in words
    if not at_bound and not any(key in words for key in ("explains", "reproduces", "uncertain")):
        return None
    faster = min(RETRY_VELOCITY_SHARE * conditions.max_velocity_m_per_s, RETRY_MAX_VELOCITY_M_PER_S)
    if faster <= conditions.max_velocity_m_per_s * 1.001:
        return None
    if at_bound:
        why = (f"the excitation stopped at the velocity bound of {1e3 * conditions.max_velocity_m_per_s:g} mm/s: "
               f"this rig's valve is faster than its sweeps allowed for; at {1e3 * faster:g} mm/s they have room "
               "for it (keep the stroke bound; clear the table's path)")
    else:
        why = (f"the record at {1e3 * conditions.max_velocity_m_per_s:g} mm/s did not show the rig well enough "
               f"for a fit the controller can rely on; at {1e3 * faster:g} mm/s the motion stands further above "
               "the rig's friction and its readings' noise (keep the stroke bound; clear the table's path)")
    return {"max_stroke_m": conditions.max_stroke_m, "max_velocity_m_per_s": faster, "why": why}


def record_figures(samples: Samples, conditions: Conditions) -> dict:
    """What the excitation did: its length, how far and how fast the table went (the velocity as the velocity
    detector reads it: the reading's difference over 5 periods, not across a lost period's held reading), the
    phases it reached."""
    from ..measurement import measured_rows

    y = np.asarray(samples["measured_displacement_m"], dtype=float)
    readings = np.where(measured_rows(samples["flags"]), y, np.nan)
    v5 = np.zeros_like(y)
    v5[5:] = (readings[5:] - readings[:-5]) / (5 * CONTROL_PERIOD_S)
    phase = np.nan_to_num(np.asarray(samples["as_hat"], dtype=float), nan=-1)
    return {"rig_time_s": len(samples) * CONTROL_PERIOD_S,
            "peak_excursion_m": float(np.nanmax(np.abs(readings - conditions.start_m))) if y.size else 0.0,
            "peak_velocity_m_per_s": float(np.nanmax(np.abs(v5))) if y.size else 0.0,
            "peak_command_v": float(np.max(np.abs(samples["voltage_v"]))) if y.size else 0.0,
            "dither_s": float(np.count_nonzero(phase == 1.0) * CONTROL_PERIOD_S),
            "completed": bool(np.any(phase == 3.0))}


def dither_slice(samples: Samples) -> slice | None:
    phase = np.nan_to_num(np.asarray(samples["as_hat"], dtype=float), nan=-1)
    idx = np.flatnonzero(phase == 1.0)
    return slice(int(idx[0]), int(idx[-1]) + 1) if idx.size else None


@ONE_BLAS_THREAD
def identify(samples: Samples, declared: RigParameters, conditions: Conditions,
             options: dict | None = None) -> Identification:
    """Fit the commissioning record ``samples`` (see the module docstring), on one BLAS thread like the fit
    (the replay's too: sim.commission.fit)."""
    from ..controllers.excitation import OPTIONS as EXCITATION_OPTIONS

    out = Identification(conditions, declared, record=record_figures(samples, conditions))
    if not out.record["completed"]:
        text = ("the excitation did not run to its end (stopped, tripped, or the valve did not open both ways "
                "within the command it may use): nothing is fitted from part of it")
        peak, bound = out.record["peak_velocity_m_per_s"], conditions.max_velocity_m_per_s
        if peak >= VELOCITY_STOP_SHARE * bound:
            text += (f"; the table reached {1e3 * peak:.1f} mm/s against the velocity bound of {1e3 * bound:g} mm/s: "
                     "this rig's valve moves it faster than the excitation's sweeps allowed for")
        out.problems.append(text)
        return out
    if out.record["dither_s"] <= 0.0:
        out.problems.append("the valve sweeps did not find the valve's edges both ways, so the dither never ran: "
                            "nothing showed the valve's dynamics, the oil column or the latency (raise the command "
                            "the sweeps may use, or check that the valve opens both ways)")
        return out
    try:
        sig = signals_from_samples(samples, CONTROL_PERIOD_S)
        phase = np.nan_to_num(np.asarray(samples["as_hat"], dtype=float), nan=-1)
        out.fit = fit_rig(sig, declared, parts=[phase == 0.0, phase == 1.0])  # the valve sweeps, the dither
    except FitError as exc:
        out.problems.append(str(exc))
        return out
    with_systematic(out.fit)
    out.problems += trust_problems(out.fit)
    try:
        rig = commissioned_rig(out.fit, declared, conditions.vertical_load_n)
        rig.check()
    except RigError as exc:
        out.problems.append(f"the fitted values are not a rig: {exc}")
        return out
    o = {**{k: s.default for k, s in EXCITATION_OPTIONS.items()}, **(options or {})}
    window = dither_slice(samples)
    if window is not None:
        lines, _ = dither_lines(o["dither_min_hz"], o["dither_max_hz"], o["dither_lines"], o["dither_corner_hz"])
        try:
            loaded = rig.with_changes(vertical_load_n=conditions.vertical_load_n)  # the friction of the run
            out.response = dither_response(sig, window, loaded, lines, 1.0 / o["dither_min_hz"],
                                           friction_law(out.fit))
        except ValueError as exc:
            out.problems.append(str(exc))
    out.problems += response_problems(out.response)
    out.rig = rig
    return out


def declared_values(ident: Identification) -> dict:
    """The declared rig's value of each fitted quantity, by the fit's names (the friction at the run's vertical
    load, F_f = mu N + F_c): what a page puts beside each fitted value."""
    d = ident.declared
    out = {name: float(getattr(d, name)) for name in (ident.fit.estimates if ident.fit else {})
           if isinstance(getattr(d, name, None), (int, float))}
    if ident.fit is not None and "friction_force_n" in ident.fit.estimates:
        out["friction_force_n"] = d.friction_coefficient * ident.conditions.vertical_load_n + d.coulomb_force_n
    return out


def provenance(ident: Identification, started_from: str, started) -> dict:
    """A rig file's ``commissioning`` section: when (``started``, a datetime), where, how, and how well;
    ``started_from``: the rig file (or defaults) the run was told of. Written by ``isorig identify rig`` and
    by the service's commissioning (backend.commissioning)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        isorig_version = version("isorig")
    except PackageNotFoundError:
        isorig_version = "unknown"
    r = ident.response
    return {"date": started.isoformat(timespec="seconds"), "isorig_version": isorig_version,
            **ident.conditions.to_dict(), "started_from": started_from, "trusted": ident.trusted,
            "rig_time_s": ident.record.get("rig_time_s"), "record": ident.record,
            "fit": {"flow_r2": ident.fit.flow_r2 if ident.fit else None,
                    "force_r2": ident.fit.force_r2 if ident.fit else None,
                    "velocity_nrmse": r.velocity_nrmse if r else None,
                    "pressure_nrmse": r.pressure_nrmse if r else None},
            "estimates": {k: e.to_dict() for k, e in (ident.fit.estimates.items() if ident.fit else ())}}
