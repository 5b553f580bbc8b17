"""The rig's parameters from a commissioning record: the two physical lines of eq. (3) fitted
(sim.commission.flow, sim.commission.force, on sim.commission.signals), every value with its uncertainty.

The piston area A_p, the oil volume V_0 and the regularisation drop are the declared ones (a catalogue value,
and two that only enter as C or at the force limit); everything else is fitted: the flow balance first (with
the latency a first scan of the force balance suggests), then the force balance at the flow balance's latency.

Uncertainties are delete-a-group jackknife estimates: the record is cut into ``CHUNK_S`` stretches dealt
round to ``BLOCKS`` groups (each group has some of every phase of the excitation), the fit is made again
without each group, and the spread of those fits is the uncertainty; the valve law's disagreement between the
record's experiments, and the latency's between the two balances, are kept beside it (``RigFit.disagreement``).
Nothing here knows the rig it runs on.

The fit runs its linear algebra on one BLAS thread (``ONE_BLAS_THREAD``): a record gets the same values on a
machine of any core count (OpenBLAS splits a product by its threads, and the rounding follows the split:
foreign rig 84's valve 564.6 +- 57.9 rad/s on two threads, 575.1 +- 65.5 on one), and the fit's many small
products do not wait on threads that synchronise: foreign rig 84's fit 3.0 -> 1.5 s on a quiet 2-core machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from ..rig import RigParameters
from .flow import FlowFit, fit_flow, part_disagreement
from .force import ForceFit, fit_force, latency_from_force
from .signals import FitError, Signals

BLOCKS = 5
CHUNK_S = 0.2
NOISE_CHECK_SEED = 20261129  # the added noise of ``noise_shifts``: fixed, so that a record gets one verdict
#: ``start_shifts`` starts the flow balance's fit again this far (ms) either side of its latency
VALLEY_STEP_MS = 0.5
#: wraps a function so that it runs on one BLAS thread (module docstring); nested uses cost ~0.2 ms each
ONE_BLAS_THREAD = threadpool_limits.wrap(limits=1, user_api="blas")


@dataclass
class Estimate:
    """A fitted value with its one-sigma uncertainty (jackknife), unit and meaning."""

    value: float
    std: float
    unit: str
    meaning: str

    @property
    def relative(self) -> float:
        return self.std / abs(self.value) if self.value else math.inf

    def to_dict(self) -> dict:
        return {"value": self.value, "std": self.std, "unit": self.unit, "meaning": self.meaning}


@dataclass
class RigFit:
    """What the fits found: every estimate by name (RigParameters names where one exists), the fits' R^2."""

    estimates: dict[str, Estimate]
    flow_r2: float
    force_r2: float
    force_balance_s: float  # the record's length the force balance was fitted over
    declared: RigParameters
    #: the valve law's disagreement between the record's parts, one sigma by name (part_disagreement)
    disagreement: dict = field(default_factory=dict)
    #: how far each value moves when the record is fitted again with its readings' noise doubled in variance
    #: (``noise_shifts``), by name
    noise_shift: dict = field(default_factory=dict)
    #: how far the latency moves when the flow balance's fit starts again either side of it (``start_shifts``)
    start_shift: dict = field(default_factory=dict)

    def value(self, name: str) -> float:
        return self.estimates[name].value

    def to_dict(self) -> dict:
        return {"estimates": {k: e.to_dict() for k, e in self.estimates.items()}, "flow_r2": self.flow_r2,
                "force_r2": self.force_r2, "force_balance_s": self.force_balance_s,
                "disagreement": dict(self.disagreement), "noise_shift": dict(self.noise_shift),
                "start_shift": dict(self.start_shift)}


def _named(flow: FlowFit, force: ForceFit, declared: RigParameters) -> dict[str, float]:
    return {
        "flow_gain_m3_per_s_v_sqrt_pa": flow.flow_gain,
        "driver_gain_negative": flow.negative_gain,
        "dead_zone_v": flow.dead_zone_v,
        "driver_offset_v": flow.null_offset_v,
        "valve_play_v": flow.play_v,
        "valve_natural_frequency_rad_s": 2.0 * math.pi * flow.valve_hz,
        "valve_damping_ratio": flow.valve_damping,
        "bulk_modulus_pa": declared.half_volume_m3 / (2.0 * flow.compliance_m3_per_pa)
        if flow.compliance_m3_per_pa > 0 else math.nan,
        "position_latency_s": flow.latency_s,
        "mass_kg": force.mass_kg,
        "friction_force_n": force.friction_n,
        "viscous_n_s_per_m": force.viscous_n_s_per_m,
        "presliding_m": force.presliding_m,
        "bristle_damping_n_s_per_m": force.bristle_damping_n_s_per_m,
    }


UNITS = {"flow_gain_m3_per_s_v_sqrt_pa": ("m3/(s V sqrt(Pa))", "valve flow gain K_q, spool opening positive"),
         "driver_gain_negative": ("V/V", "k_en of eq. (2): a negative command's flow gain is k_en K_q"),
         "dead_zone_v": ("V", "half width of the valve's dead zone DZ (negative: the underlap, both lands open)"),
         "driver_offset_v": ("V", "valve null offset v_e0 (eq. 2)"),
         "valve_play_v": ("V", "the valve's play (backlash) between command and spool, full width"),
         "valve_natural_frequency_rad_s": ("rad/s", "valve natural frequency w_v"),
         "valve_damping_ratio": ("-", "valve damping ratio xi_v"),
         "bulk_modulus_pa": ("Pa", "effective bulk modulus beta (the oil column's stiffness, with the declared V_0)"),
         "position_latency_s": ("s", "delay of the position reading"),
         "mass_kg": ("kg", "moving mass m"),
         "friction_force_n": ("N", "Coulomb friction mu N + F_c at the run's vertical load (the Dahl law's level)"),
         "viscous_n_s_per_m": ("N s/m", "viscous friction sigma (the oil column's damping)"),
         "presliding_m": ("m", "the guides' pre-sliding distance delta (Dahl law): F_c / delta is their stiffness"),
         "bristle_damping_n_s_per_m": ("N s/m", "the pre-sliding's damping sigma_1 (Dahl law)")}


def _whole_fit(sig: Signals, declared: RigParameters) -> tuple[float, FlowFit, ForceFit]:
    """The force balance's latency (the flow balance's first guess), the flow balance, then the force balance at
    the flow balance's latency, on the whole record."""
    area = declared.piston_area_m2
    guess = latency_from_force(sig, area)
    flow = fit_flow(sig, area, declared.orifice_regularisation_pa, latency_guess_s=guess,
                    area_ratio_b=declared.area_ratio_b)
    return guess, flow, fit_force(sig, area, flow.latency_s)


@ONE_BLAS_THREAD
def fit_rig(sig: Signals, declared: RigParameters, blocks: int = BLOCKS,
            parts: list[np.ndarray] | None = None) -> RigFit:
    """Every parameter of ``UNITS`` with its jackknife uncertainty over ``blocks`` groups of the record, and the
    valve law's disagreement between ``parts`` of it (boolean masks: the excitation's phases)."""
    if np.ptp(sig.y[sig.valid]) < 1e-5:
        raise FitError("the table moved less than 0.01 mm in the record: nothing to fit")
    area, dp_reg, ratio = declared.piston_area_m2, declared.orifice_regularisation_pa, declared.area_ratio_b
    guess, flow, force = _whole_fit(sig, declared)
    full = _named(flow, force, declared)
    start = flow.theta
    group = (np.arange(len(sig)) // max(1, int(round(CHUNK_S / sig.dt_s)))) % blocks
    leave_one_out = []
    for b in range(blocks):
        keep = sig.valid & (group != b)
        f = fit_flow(sig, area, dp_reg, keep, start, area_ratio_b=ratio)
        try:
            g = fit_force(sig, area, f.latency_s, keep, presliding_m=force.presliding_m)
        except FitError:
            g = force
        leave_one_out.append(_named(f, g, declared))
    estimates = {}
    for name, value in full.items():
        others = np.array([d[name] for d in leave_one_out])
        std = float(math.sqrt((blocks - 1) / blocks * np.sum((others - others.mean()) ** 2)))
        unit, meaning = UNITS[name]
        estimates[name] = Estimate(float(value), std, unit, meaning)
    disagreement = part_disagreement(sig, area, dp_reg, flow, parts, ratio) if parts else {}
    # the latency from the flow balance (beside the valve's lag) and from the force balance (the mechanics
    # alone): what separates them is model error in one (foreign rigs 50 and 72: 0.16 and 0.27 ms apart,
    # the flow balance's 0.24 and 0.57 ms late)
    disagreement["position_latency_s"] = abs(flow.latency_s - guess) / math.sqrt(2.0)
    shifts = noise_shifts(sig, declared, full)
    return RigFit(estimates, flow.r2, force.r2, force.samples * sig.dt_s, declared, disagreement, shifts,
                  start_shifts(sig, declared, flow))


def start_shifts(sig: Signals, declared: RigParameters, flow: FlowFit) -> dict[str, float]:
    """How far the flow balance's latency moves when its fit starts again from its own solution with the latency
    VALLEY_STEP_MS earlier and later: the largest move, by name. The valve's lag and the latency trade along a
    flat valley of the flow balance's cost (below its 35 Hz corner a second-order valve and a delay differ in a
    cubic term only), and where the fit stops in that valley depends on where it began; the jackknife's groups
    all begin at the whole fit's solution and cannot see it. Foreign rig 121: 0.113 +- 0.083 ms trusted against
    a true 0.560 ms; begun 0.5 ms later the fit stopped at 0.551 ms."""
    moves = []
    for step_ms in (-VALLEY_STEP_MS, VALLEY_STEP_MS):
        begun = flow.theta
        begun[4] = max(0.0, begun[4] + step_ms)
        again = fit_flow(sig, declared.piston_area_m2, declared.orifice_regularisation_pa, start=begun,
                         area_ratio_b=declared.area_ratio_b)
        moves.append(abs(again.latency_s - flow.latency_s))
    return {"position_latency_s": float(max(moves))}


def noise_shifts(sig: Signals, declared: RigParameters, full: dict[str, float]) -> dict[str, float]:
    """How far each value moves when the whole fit is made again on the record with as much white noise again
    added to its position, load pressure and force readings (each at its measured sigma, from a fixed seed):
    about the error the readings' noise leaves in it. The jackknife deals the same noise to every group and
    cannot see it. On foreign rigs with noisy pressure transducers the flow balance's latency, which trades
    with the valve's lag, moved 0.2-0.6 ms with the noise (rigs 53, 139, 239, 279) and was stated to +-0.05-0.2 ms
    before this term. A record the fit cannot take once noisier gives no shifts (the other rules judge it)."""
    rng = np.random.default_rng(NOISE_CHECK_SEED)
    n, size = sig.noise, len(sig)
    noisier = Signals(sig.dt_s, sig.u, sig.y + rng.normal(0.0, n["position_m"], size),
                      sig.p_load + rng.normal(0.0, n["load_pressure_pa"], size),
                      sig.force + rng.normal(0.0, n["force_n"], size), sig.p_supply, sig.valid)
    try:
        again = _named(*_whole_fit(noisier, declared)[1:], declared)
    except FitError:
        return {}
    return {name: float(abs(again[name] - value)) for name, value in full.items()
            if math.isfinite(again[name]) and math.isfinite(value)}
