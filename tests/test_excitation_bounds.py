"""The commissioning excitation keeps its own stroke and velocity bounds on a heavy table on a soft oil column with
an underlapped valve (issue 32 item 3): a foreign rig (written from the physics, not isorig's model) on which it
used to be stopped by the run's velocity limit."""

import numpy as np

from sim.commission import foreign_campaign as fc
from sim.commission.identify import Conditions, excitation_limits, excitation_scenario
from sim.engine import Simulation
from sim.isolator import load_isolator
from sim.safety import make_limits

#: double-rod, underlapped 72 Hz valve, 3405 kg table, oil column near 24 Hz; the velocity limit stopped its
#: excitation at 1.28 s (20.4 mm/s): the last sweep had left the table at the guard, moving at 12 mm/s, and the
#: dither's position hold threw it back (its demand from the guard unlimited, a step of 24 mm/s on a ringing column)
HEAVY_SOFT_UNDERLAPPED = 66


def test_a_heavy_soft_underlapped_rig_is_excited_within_its_bounds():
    from foreign_rigs import draw_rig

    spec = draw_rig(HEAVY_SOFT_UNDERLAPPED)
    assert spec.drawn["valve.lap"] == "under" and spec.drawn["table.mass_kg"] > 3000.0
    declared = fc.declared_rig(spec.lab_knows())
    stroke_m, velocity_m_per_s = fc.DEFAULT_MAX_STROKE_M, fc.DEFAULT_MAX_VELOCITY_M_PER_S
    c = Conditions("simulated", fc.SUPPLY_PA, float(spec.drawn["table.vertical_load_n"]), "foreign", 0.0, stroke_m,
                   velocity_m_per_s)
    scenario = excitation_scenario(load_isolator(fc.CONTROLLER_ISOLATOR), c, declared)
    scenario.foreign_rig = spec
    result = Simulation(scenario, validate=False).run(limits=make_limits(declared, excitation_limits(c)))
    assert result.trip is None, result.trip.message
    s = result.samples
    y = np.asarray(s["measured_displacement_m"])
    v5 = (y[5:] - y[:-5]) / 5e-3  # what the velocity detector reads
    assert np.max(np.abs(y)) < stroke_m
    assert np.max(np.abs(v5)) < velocity_m_per_s
    phase = np.asarray(s["as_hat"])
    assert np.count_nonzero(phase == 1.0) * 1e-3 > 10.0  # it found the valve both ways and dithered
    assert phase[-1] == 3.0
