"""Drawing a foreign rig from the declared distributions (distributions.toml), and what its lab knows of it.

``draw_rig(seed)`` is deterministic in the seed. A ``ForeignRigSpec`` holds the drawn quantities by name, the
packed parameters of ``physics`` and two views of the rig that the instrument, not isorig, states:

- ``lab_knows()``: what a lab would write in a start rig file (catalogue and drawing values: piston areas, oil
  volumes, stroke, pump flow, ranges), nothing measured;
- ``equivalents(supply_pa)``: the rig's physics expressed as the quantities a lumped single-valve model relies on
  (moving mass, position latency, spool frequency, the oil column's stiffness at mid-stroke, and, where the
  valve has a dead band, the commands at its edges each way, V): the truth a commissioning's values are judged
  against.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import physics as ph

DISTRIBUTIONS_FILE = Path(__file__).with_name("distributions.toml")
CONTROL_PERIOD_S = 1e-3
NOMINAL_SUPPLY_PA = 1.0e7  # the valve's lands are sized for their table speed at this supply
LAP_WORDS = {"under": "underlapped", "critical": "critically lapped", "over": "overlapped"}


def load_distributions(path: Path = DISTRIBUTIONS_FILE) -> dict:
    """The declared distributions, by section and name."""
    with open(path, "rb") as f:
        return tomllib.load(f)


def _draw(rng: np.random.Generator, spec: dict):
    if "uniform" in spec:
        lo, hi = spec["uniform"]
        return float(rng.uniform(lo, hi))
    if "log_uniform" in spec:
        lo, hi = spec["log_uniform"]
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    if "choice" in spec:
        options = spec["choice"]
        weights = np.asarray(spec.get("weights", [1.0] * len(options)), dtype=float)
        return options[int(rng.choice(len(options), p=weights / weights.sum()))]
    raise ValueError(f"unknown distribution {spec!r}: use uniform, log_uniform or choice")


@dataclass
class ForeignRigSpec:
    """One drawn rig: its quantities by name (``drawn``), its packed physics parameters and its seed."""

    seed: int
    drawn: dict
    params: np.ndarray = field(repr=False)

    @property
    def name(self) -> str:
        d = self.drawn
        return (f"foreign rig {self.seed} ({d['actuator.rod']}-rod, {LAP_WORDS[d['valve.lap']]} "
                f"{d['valve.spool_frequency_hz']:.0f} Hz valve, {d['table.mass_kg']:.0f} kg, "
                f"{d['specimen.kind'].replace('_', ' ')})")

    def lab_knows(self) -> dict:
        """What the lab writes in its start rig file (SI): areas, oil volume per side (cylinder at mid-stroke and
        hose, averaged over the sides), stroke, pump flow, ranges. Nothing here is measured."""
        p = self.params
        return {
            "piston_area_m2": float(p[ph.P_AREA_A]),
            "rod_side_area_m2": float(p[ph.P_AREA_B]),
            "half_volume_m3": float(0.5 * (p[ph.P_DEAD_A] + p[ph.P_HOSE_A] + p[ph.P_DEAD_B] + p[ph.P_HOSE_B])),
            "stroke_m": float(0.9 * p[ph.P_STROKE]),
            "pump_max_flow_m3_per_s": float(p[ph.P_PUMP_FLOW]),
            "max_supply_pa": float(min(p[ph.P_RELIEF], 2.1e7)),
            "command_limit_v": 10.0,
        }

    def equivalents(self, supply_pa: float) -> dict:
        """The physics as the quantities a lumped model relies on (module docstring), where they are defined."""
        p = self.params
        pa = supply_pa * p[ph.P_AREA_B] / (p[ph.P_AREA_A] + p[ph.P_AREA_B])  # the chambers balanced at rest
        pb = supply_pa - pa
        c_a = ph._compliance(p[ph.P_DEAD_A], p[ph.P_HOSE_A], pa, p)
        c_b = ph._compliance(p[ph.P_DEAD_B], p[ph.P_HOSE_B], pb, p)
        out = {
            "mass_kg": float(p[ph.P_MASS]),
            "position_latency_s": float(p[ph.P_POS_LATENCY] * CONTROL_PERIOD_S),
            "valve_natural_frequency_rad_s": float(p[ph.P_SPOOL_W]),
            "oil_column_stiffness_n_per_m": float(p[ph.P_AREA_A] ** 2 / c_a + p[ph.P_AREA_B] ** 2 / c_b),
        }
        laps = [p[ph.P_LAP_PA], p[ph.P_LAP_AT], p[ph.P_LAP_PB], p[ph.P_LAP_BT]]
        if min(laps) > 0.0 and p[ph.P_PLAY] == 0.0:
            # the valve opens towards +y when (u + bias) / 10 > lap_pa, towards -y when < -lap_pb: the commands
            # at its edges, what a dead-zone inverse must know (however a model splits them into a width, a null
            # and each way's gain)
            full = ph.COMMAND_FULL_SCALE_V
            out["valve_edge_positive_v"] = float(full * p[ph.P_LAP_PA] - p[ph.P_NULL])
            out["valve_edge_negative_v"] = float(-full * p[ph.P_LAP_PB] - p[ph.P_NULL])
        return out


#: the drawn quantities that are physics parameters as they are (the others are derived below)
AS_DRAWN = {
    ph.P_MASS: "table.mass_kg", ph.P_LOAD: "table.vertical_load_n", ph.P_HOSE_A: "actuator.hose_volume_m3",
    ph.P_BETA_OIL: "actuator.oil_bulk_modulus_pa", ph.P_BETA_HOSE: "actuator.hose_bulk_modulus_pa",
    ph.P_AIR: "actuator.air_fraction", ph.P_PISTON_LEAK: "actuator.piston_leak_m3_per_s_pa",
    ph.P_SPOOL_ZETA: "valve.spool_damping_ratio", ph.P_PLAY: "valve.spool_play_v", ph.P_NULL: "valve.null_bias_v",
    ph.P_LAND_LEAK: "valve.land_leak_m3_per_s_pa", ph.P_TRANSITION: "valve.transition_pa", ph.P_TANK: "valve.tank_pa",
    ph.P_PUMP_FLOW: "supply.pump_flow_m3_per_s", ph.P_REG_BAND: "supply.regulator_band_pa",
    ph.P_ACC_GAS: "supply.accumulator_gas_m3", ph.P_PRECHARGE: "supply.precharge_pa",
    ph.P_LINE_VOLUME: "supply.supply_line_volume_m3", ph.P_RELIEF: "supply.relief_pa",
    ph.P_MU: "friction.coulomb_per_load", ph.P_COULOMB: "friction.coulomb_n", ph.P_SEAL: "friction.seal_m2",
    ph.P_STRIBECK: "friction.stribeck_ratio", ph.P_STRIBECK_V: "friction.stribeck_velocity_m_per_s",
    ph.P_VISCOUS: "friction.viscous_n_s_per_m", ph.P_ASYM: "friction.asymmetry",
    ph.P_COOLING: "specimen.cooling_time_s", ph.P_SOFTENING: "specimen.softening_length_m",
    ph.P_LC_ZETA: "sensors.load_cell_damping_ratio", ph.P_POS_NOISE: "sensors.position_noise_m",
    ph.P_POS_STEP: "sensors.position_step_m", ph.P_PRESSURE_NOISE: "sensors.pressure_noise_pa",
    ph.P_SUPPLY_NOISE: "sensors.supply_noise_pa", ph.P_FORCE_NOISE: "sensors.force_noise_n",
}


def draw_rig(seed: int, distributions: dict | None = None) -> ForeignRigSpec:
    """Rig ``seed`` of the family: every quantity drawn from the declared distributions."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not (0 <= seed < 2 ** 32):
        raise ValueError(f"a foreign rig's seed must be a whole number in [0, 2**32); got {seed!r}")
    dist = distributions or load_distributions()
    rng = np.random.default_rng([20261129, seed])
    d = {f"{section}.{name}": _draw(rng, spec) for section, entries in dist.items() for name, spec in entries.items()}
    p = np.zeros(ph.N_PARAMS)
    for index, key in AS_DRAWN.items():
        p[index] = d[key]
    area_a = d["actuator.area_a_m2"]
    area_b = area_a if d["actuator.rod"] == "double" else area_a / d["actuator.cap_to_rod_area_ratio"]
    stroke = d["actuator.half_stroke_m"]
    p[ph.P_AREA_A], p[ph.P_AREA_B], p[ph.P_STROKE] = area_a, area_b, stroke
    p[ph.P_DEAD_A] = area_a * stroke + d["actuator.dead_volume_extra_m3"]
    p[ph.P_DEAD_B] = area_b * stroke + _draw(rng, dist["actuator"]["dead_volume_extra_m3"])
    p[ph.P_HOSE_B] = _draw(rng, dist["actuator"]["hose_volume_m3"])
    p[ph.P_SPOOL_W] = 2 * math.pi * d["valve.spool_frequency_hz"]
    # two lands in series at full opening share the supply: each drops half of it with no load
    p[ph.P_LAND_FLOW] = d["valve.table_speed_at_full_opening_m_per_s"] * area_a / math.sqrt(0.5 * NOMINAL_SUPPLY_PA)
    lap = {"under": -d["valve.underlap_share"], "critical": 0.0, "over": d["valve.overlap_share"]}[d["valve.lap"]]
    spread = d["valve.land_lap_spread_share"]
    for index in (ph.P_LAP_PA, ph.P_LAP_AT, ph.P_LAP_PB, ph.P_LAP_BT):
        p[index] = lap * (1.0 + spread * rng.uniform(-1.0, 1.0)) if lap != 0.0 else 0.0
    p[ph.P_LINE_RESISTANCE] = d["supply.supply_line_drop_pa_at_5e-3_m3_per_s"] / 5e-3
    p[ph.P_PUMP_SET] = NOMINAL_SUPPLY_PA
    coulomb_nominal = p[ph.P_MU] * p[ph.P_LOAD] + p[ph.P_COULOMB]
    p[ph.P_BRISTLE_K] = coulomb_nominal / d["friction.presliding_m"]
    p[ph.P_BRISTLE_C] = 2.0 * d["friction.bristle_damping_ratio"] * math.sqrt(p[ph.P_BRISTLE_K] * p[ph.P_MASS])
    kind = d["specimen.kind"]
    p[ph.P_SPECIMEN] = ph.SPECIMEN_KINDS.index(kind)
    if kind == "spring_sliders":
        p[ph.P_SPRING] = d["specimen.spring_n_per_m"]
        for i in range(int(d["specimen.sliders"])):
            p[ph.P_SK0 + i] = _draw(rng, dist["specimen"]["slider_stiffness_n_per_m"])
            p[ph.P_SF0 + i] = _draw(rng, dist["specimen"]["slider_strength_n"])
    elif kind == "lead_rubber":
        p[ph.P_SPRING] = d["specimen.spring_n_per_m"]
        p[ph.P_SK0] = (d["specimen.lead_elastic_to_post_yield"] - 1.0) * p[ph.P_SPRING]
        p[ph.P_SF0] = d["specimen.lead_yield_n"]
        p[ph.P_HEAT_CAP] = d["specimen.lead_heat_capacity_j_per_k"]
        p[ph.P_STRENGTH_LOSS] = d["specimen.lead_strength_loss_per_k"]
    elif kind == "soft_rubber":
        p[ph.P_SPRING] = d["specimen.spring_n_per_m"]
        p[ph.P_SK0] = p[ph.P_SPRING]  # the rubber's own hysteresis: a slider as stiff as the spring
        p[ph.P_SF0] = d["specimen.rubber_hysteresis_strength_n"]
        p[ph.P_RUBBER_DAMPING] = d["specimen.rubber_damping_n_s_per_m"]
    p[ph.P_LC_W] = 2 * math.pi * d["sensors.load_cell_frequency_hz"]
    p[ph.P_POS_LATENCY] = d["sensors.position_latency_s"] / CONTROL_PERIOD_S
    p[ph.P_SEED] = float(seed)
    p[ph.P_COOLING] = max(p[ph.P_COOLING], 1.0)
    p[ph.P_SOFTENING] = max(p[ph.P_SOFTENING], 1e-3)
    return ForeignRigSpec(seed, d, p)
