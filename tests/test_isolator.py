import json

import numpy as np
import pytest

from sim.isolator import PRESETS, IsolatorError, bouc_wen_rate, isolator_from_dict, load_isolator, simulate_loop


def test_presets_are_the_papers_tables():
    a, b = PRESETS["IUT_a"], PRESETS["IUT_b"]
    assert (a.rho_bw_per_m, a.sigma_bw, a.n, a.kd_n_per_m, a.kw_n) == (141, 0.5, 1, 1.25e6, 1.7e4)
    assert (b.rho_bw_per_m, b.sigma_bw, b.n, b.kd_n_per_m, b.kw_n) == (90, 0.5, 1, 6.8e5, 6.2e3)


def test_bouc_wen_rate_matches_eq4_branches():
    # loading (d' w > 0): rho d' (1 - |w|^n); unloading: rho d' (1 + |w|^n (2 sigma - 1))
    assert bouc_wen_rate(0.5, 0.1, 141.0, 0.5, 1.0) == pytest.approx(141 * 0.1 * 0.5)
    assert bouc_wen_rate(0.5, -0.1, 141.0, 0.7, 1.0) == pytest.approx(141 * -0.1 * (1 + 0.5 * 0.4))
    assert bouc_wen_rate(0.0, 0.2, 90.0, 0.5, 1.0) == pytest.approx(90 * 0.2)


def test_bouc_wen_variable_saturates_at_one():
    d = np.linspace(0, 0.1, 2001)  # monotonic loading far beyond 1/rho
    f = simulate_loop(PRESETS["IUT_a"], d, 1e-3)
    w_end = (f[-1] - 1.25e6 * d[-1]) / 1.7e4
    assert w_end == pytest.approx(1.0, abs=1e-6)
    assert w_end <= 1.0 + 1e-12


def test_hysteresis_loop_dissipates_energy():
    t = np.arange(0, 3, 1e-3)
    d = 0.02 * np.sin(2 * np.pi * t)
    f = simulate_loop(PRESETS["IUT_b"], d, 1e-3)
    last = t >= 2
    area = -np.trapezoid(d[last], f[last])  # loop area, clockwise positive
    assert abs(area) > 100.0  # ~4 kw a for saturated loops: order 4*6.2e3*0.02 = 500 J


def test_user_isolator_from_json(tmp_path):
    data = {"name": "my_lrb", "rho_bw_per_m": 200, "sigma_bw": 0.5, "n": 1, "kd_n_per_m": 9e5, "kw_n": 3e4}
    p = tmp_path / "iso.json"
    p.write_text(json.dumps(data))
    iso = load_isolator(p)
    assert iso.name == "my_lrb" and iso.kw_n == 3e4


@pytest.mark.parametrize("change, field", [
    ({"kd_n_per_m": None}, "kd_n_per_m"),
    ({"kw_n": -1}, "kw_n"),
    ({"n": "one"}, "n"),
    ({"sigma_bw": float("nan")}, "sigma_bw"),
    ({"name": ""}, "name"),
])
def test_invalid_isolator_names_the_field(change, field):
    data = {"name": "x", "rho_bw_per_m": 200, "sigma_bw": 0.5, "n": 1, "kd_n_per_m": 9e5, "kw_n": 3e4}
    data.update(change)
    with pytest.raises(IsolatorError, match=field):
        isolator_from_dict(data)


def test_missing_field_is_named():
    with pytest.raises(IsolatorError, match="rho_bw_per_m"):
        isolator_from_dict({"name": "x", "sigma_bw": 0.5, "n": 1, "kd_n_per_m": 9e5, "kw_n": 3e4})


def test_bad_json_file(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(IsolatorError, match="not valid JSON"):
        load_isolator(p)
    with pytest.raises(IsolatorError, match="unknown isolator"):
        load_isolator("IUT_z")
