import json

import numpy as np
import pytest
from scipy.signal import lsim

from sim.isolator import PRESETS, Isolator
from sim.structure import (
    CRIntegrator,
    ShearBuilding,
    StructureError,
    channel_names,
    isolator_tangent_stiffness_n_per_m,
    load_structure,
    reference_response,
    virtual_rths,
)

THREE = {"base_mass_kg": 4000.0, "masses_kg": [3000.0, 3000.0, 2750.0],
         "stiffness_n_per_m": [8.0e6, 6.0e6, 4.0e6], "damping_ratio": 0.05}
LINEAR = Isolator("linear", 100.0, 0.5, 1.0, 4.0e5, 0.0)  # k_w = 0: a linear spring of 400 kN/m


def building(**changes):
    return ShearBuilding.from_dict({**THREE, **changes})


# ---- the structure file ---------------------------------------------------------------------------------
@pytest.mark.parametrize("changes, field", [
    ({"base_mass_kg": 0.0}, "base_mass_kg"),
    ({"base_mass_kg": -5.0}, "base_mass_kg"),
    ({"masses_kg": [3000.0, -1.0, 2750.0]}, "masses_kg[1]"),
    ({"masses_kg": [3000.0, float("nan"), 2750.0]}, "masses_kg[1]"),
    ({"stiffness_n_per_m": [8e6, 0.0, 4e6]}, "stiffness_n_per_m[1]"),
    ({"stiffness_n_per_m": [8e6, 6e6]}, "stiffness_n_per_m"),
    ({"masses_kg": []}, "masses_kg"),
    ({"masses_kg": "3000"}, "masses_kg"),
    ({"damping_ratio": 0.0}, "damping_ratio"),
    ({"damping_ratio": 1.0}, "damping_ratio"),
    ({"damping_ratio": True}, "damping_ratio"),
    ({"dampingratio": 0.05}, "dampingratio"),
])
def test_bad_structures_name_the_field(changes, field):
    with pytest.raises(StructureError) as err:
        ShearBuilding.from_dict({**THREE, **changes})
    assert err.value.field == field
    assert field.split("[")[0] in str(err.value)
    assert isinstance(err.value, ValueError)


def test_missing_field_is_named():
    data = dict(THREE)
    del data["stiffness_n_per_m"]
    with pytest.raises(StructureError, match="stiffness_n_per_m") as err:
        ShearBuilding.from_dict(data)
    assert err.value.field == "stiffness_n_per_m"


def test_load_structure_file(tmp_path):
    path = tmp_path / "b.json"
    path.write_text(json.dumps({**THREE, "name": "demo"}))
    b = load_structure(path)
    assert b.masses_kg == (3000.0, 3000.0, 2750.0) and b.name == "demo"
    assert ShearBuilding.from_dict(b.to_dict()) == b
    path.write_text('{"base_mass_kg": 1,')
    with pytest.raises(StructureError, match="not valid JSON"):
        load_structure(path)
    path.write_text(json.dumps({**THREE, "masses_kg": [1.0, 0.0, 1.0]}))
    with pytest.raises(StructureError, match=r"b\.json.*masses_kg\[1\]"):
        load_structure(path)


# ---- matrices and damping -------------------------------------------------------------------------------
def test_stiffness_matrix_of_the_storey_springs():
    k = building().stiffness_matrix()
    expected = np.array([[8e6, -8e6, 0, 0], [-8e6, 14e6, -6e6, 0], [0, -6e6, 10e6, -4e6], [0, 0, -4e6, 4e6]])
    np.testing.assert_array_equal(k, expected)


def test_rayleigh_damping_gives_the_ratio_at_the_first_two_fixed_base_modes():
    for zeta in (0.02, 0.05, 0.2):
        b = building(damping_ratio=zeta)
        ratios = b.modal_damping_ratios()
        assert ratios[:2] == pytest.approx([zeta, zeta], rel=1e-10)
        assert ratios[2] > zeta  # above the second mode, Rayleigh damping grows
        # no damping at the base: the base row of C holds only the first storey's spring term
        c = b.damping_matrix()
        _, beta = b.rayleigh_coefficients()
        assert c[0, 0] == pytest.approx(beta * 8e6)


def test_single_storey_is_stiffness_proportional():
    b = ShearBuilding.from_dict({"base_mass_kg": 1000, "masses_kg": [2000], "stiffness_n_per_m": [2e6],
                                 "damping_ratio": 0.05})
    alpha, beta = b.rayleigh_coefficients()
    w = np.sqrt(2e6 / 2000)
    assert alpha == 0.0 and beta == pytest.approx(2 * 0.05 / w)
    assert b.modal_damping_ratios() == pytest.approx([0.05])


def test_tangent_stiffness_bound():
    iso = PRESETS["IUT_a"]
    assert isolator_tangent_stiffness_n_per_m(iso) == pytest.approx(1.25e6 + 1.7e4 * 141)
    stiff_unloading = Isolator("x", 100.0, 0.8, 1.0, 1e5, 1e4)
    assert isolator_tangent_stiffness_n_per_m(stiff_unloading) == pytest.approx(1e5 + 1e4 * 100 * 1.6)


# ---- the CR integrator -----------------------------------------------------------------------------------
def linear_state_space(b: ShearBuilding, k_iso: float):
    """x = [u, u'], input a_g, output u_b: the exact linear reference (matrix exponential in lsim)."""
    m = b.mass_vector_kg()
    k = b.stiffness_matrix()
    k[0, 0] += k_iso
    c = b.damping_matrix()
    n = m.size
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-k / m[:, None], -c / m[:, None]]])
    bb = np.concatenate([np.zeros(n), -np.ones(n)])[:, None]
    cc = np.zeros((1, 2 * n))
    cc[0, 0] = 1.0
    return a, bb, cc, np.zeros((1, 1)), k, c, m


def run_cr_linear(b, k_iso, t, ag, dt):
    step = CRIntegrator(b, dt, k_iso, ag[0])
    out = np.zeros(t.size)
    for i in range(t.size - 1):
        out[i + 1] = step.next_base_displacement()
        step.advance(k_iso * out[i + 1], ag[i + 1])  # the "specimen": a linear spring
    return out, step


def test_cr_follows_the_analytic_steady_state_of_a_linear_system():
    # closed form: u(t) = Im(U exp(i w t)) with (K - w^2 M + i w C) U = -M 1 A; start on it, stay on it
    b = building()
    k_iso = 1.5e6
    _, _, _, _, k, c, m = linear_state_space(b, k_iso)
    w, amp, dt = 2 * np.pi * 1.3, 2.0, 1e-3
    u_hat = np.linalg.solve(k - w * w * np.diag(m) + 1j * w * c, -m * amp)
    step = CRIntegrator(b, dt, k_iso)
    step.set_state(u_hat.imag, (1j * w * u_hat).imag, 0.0, k_iso * u_hat.imag[0])
    t = np.arange(1, 10_001) * dt  # 10 s, 13 cycles
    got = np.empty(t.size)
    for i, ti in enumerate(t):
        got[i] = step.next_base_displacement()
        step.advance(k_iso * got[i], amp * np.sin(w * ti))
    exact = np.imag(u_hat[0] * np.exp(1j * w * t))
    assert np.max(np.abs(got - exact)) < 1e-3 * np.max(np.abs(exact))
    row = np.zeros(len(channel_names(b)))
    step.write_channels(row)
    assert row[0] == got[-1] and row[-1] == pytest.approx(k_iso * got[-1])


def test_cr_from_rest_matches_the_exact_linear_solution():
    b = building()
    k_iso = 1.0e6
    dt = 1e-3
    t = np.arange(0, 8, dt)
    ag = 3.0 * np.sin(2 * np.pi * 0.9 * t) * np.sin(np.pi * t / 8) ** 2 + 1.0 * np.sin(2 * np.pi * 4.1 * t)
    a, bb, cc, dd, *_ = linear_state_space(b, k_iso)
    _, exact, _ = lsim((a, bb, cc, dd), ag, t, interp=True)
    got, _ = run_cr_linear(b, k_iso, t, ag, dt)
    assert np.sqrt(np.mean((got - exact) ** 2)) < 2e-4 * np.sqrt(np.mean(exact ** 2))


@pytest.mark.parametrize("zeta", [1e-4, 0.02])
def test_cr_is_stable_far_beyond_the_explicit_limit(zeta):
    # very stiff storeys: omega_max dt ~ 38, where central differences (limit omega dt <= 2) explode.
    # Started away from equilibrium, CR overshoots transiently at such omega dt (x_1 ~ -3 x_0 per mode),
    # but never grows: nearly undamped, the last 1000 steps stay below the first 1000; damped, it decays.
    b = ShearBuilding.from_dict({"base_mass_kg": 1000.0, "masses_kg": [1000.0, 1000.0, 1000.0],
                                 "stiffness_n_per_m": [1e9, 1e9, 1e9], "damping_ratio": zeta})
    k_iso = 1e9
    dt = 0.02
    k = b.stiffness_matrix()
    k[0, 0] += k_iso
    omega_max = np.sqrt(np.max(np.linalg.eigvals(k / b.mass_vector_kg()[:, None]).real))
    assert omega_max * dt > 30
    step = CRIntegrator(b, dt, k_iso)
    u0 = np.array([1e-3, -2e-3, 3e-3, -1e-3])
    step.set_state(u0, np.zeros(4), 0.0, k_iso * u0[0])
    peaks = np.empty(20_000)
    for i in range(peaks.size):
        x = step.next_base_displacement()
        step.advance(k_iso * x, 0.0)
        peaks[i] = np.max(np.abs(step.x))
    assert np.all(np.isfinite(peaks))
    assert peaks[-1000:].max() <= peaks[:1000].max()
    if zeta > 0.01:
        assert peaks[-1] < 1e-9 * peaks.max()


def test_next_base_displacement_is_explicit_and_repeatable():
    step = CRIntegrator(building(), 1e-3, PRESETS["IUT_a"], 1.0)
    first = step.next_base_displacement()
    assert step.next_base_displacement() == first
    step.advance(0.0, 1.0)
    assert step.time_s == pytest.approx(1e-3)
    assert step.base_displacement_m == first
    with pytest.raises(StructureError):
        CRIntegrator(building(), 0.0, 1e6)


# ---- the offline reference and virtual RTHS ----------------------------------------------------------------
def test_reference_with_a_linear_isolator_matches_the_exact_solution():
    b = building()
    dt = 2e-3
    t = np.arange(0, 6, dt)
    ag = 2.0 * np.sin(2 * np.pi * 1.1 * t) * np.minimum(t, 1.0)
    ref = reference_response(b, LINEAR, t, ag)
    a, bb, cc, dd, *_ = linear_state_space(b, LINEAR.kd_n_per_m)
    _, exact, x = lsim((a, bb, cc, dd), ag, t, interp=True)
    assert np.max(np.abs(ref["base_displacement_m"] - exact)) < 1e-6 * np.max(np.abs(exact))
    assert np.allclose(ref["drift_1_m"], x[:, 1] - x[:, 0], atol=1e-9)
    assert set(channel_names(b)) <= set(ref)
    assert ref["isolator_force_n"] == pytest.approx(LINEAR.kd_n_per_m * ref["base_displacement_m"])


def test_reference_converges_with_the_substep():
    b = building()
    t = np.arange(0, 5, 1e-3)
    ag = 4.0 * np.sin(2 * np.pi * 1.0 * t) * np.minimum(t / 2, 1)
    ref = reference_response(b, PRESETS["IUT_a"], t, ag)
    fine = reference_response(b, PRESETS["IUT_a"], t, ag, substeps=2 * ref["substeps"])
    x = ref["base_displacement_m"]
    assert np.max(np.abs(x - fine["base_displacement_m"])) < 1e-6 * np.max(np.abs(x))
    assert np.max(np.abs(ref["bouc_wen_w"])) <= 1.0 + 1e-9


def test_virtual_rths_with_an_ideal_actuator_reproduces_the_reference():
    b = building()
    t = np.arange(0, 8, 1e-3)
    ag = 3.0 * np.sin(2 * np.pi * 1.2 * t) * np.sin(np.pi * t / 8) ** 2
    ref = reference_response(b, PRESETS["IUT_b"], t, ag)
    out = virtual_rths(b, PRESETS["IUT_b"], t, ag, delay_steps=0)
    x, xr = out["base_displacement_m"], ref["base_displacement_m"]
    assert np.sqrt(np.sum((x - xr) ** 2) / np.sum(xr ** 2)) < 1e-3  # J4 < 0.1 %
    assert np.max(np.abs(out["abs_acc_3_m_per_s2"] - ref["abs_acc_3_m_per_s2"])) \
        < 0.01 * np.max(np.abs(ref["abs_acc_3_m_per_s2"]))
    # the input energy is positive and of the order of the isolator's hysteretic work
    assert out["input_energy_j"][-1] > 0
