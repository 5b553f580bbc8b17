import numpy as np
import pytest

from sim.controllers import make_controller
from sim.controllers.base import N_MEAS
from sim.models import atanh_over_x, first_order_rate, reference_model_step


def meas(y, r, pl=0.0, t=0.0):
    m = np.zeros(N_MEAS)
    m[:6] = (t, r, 0.0, y, pl, 1e7)  # the loop undisturbed: M_HOLD_LEARNING 0
    return m


def test_atanh_over_x_removable_singularity():
    assert atanh_over_x(0.0) == 1.0
    assert atanh_over_x(1e-5) == pytest.approx(1.0, abs=1e-9)
    assert atanh_over_x(0.5) == pytest.approx(np.arctanh(0.5) / 0.5)


def test_first_order_model_eq7_steady_state():
    # steady state of eq. (7): u = k atanh(y/a_s)  ->  y = a_s tanh(u)
    a_p, a_s = 0.5, 0.03
    y = 0.03 * np.tanh(2.0)
    assert first_order_rate(y, 2.0, a_p, a_s) == pytest.approx(0.0, abs=1e-12)
    assert first_order_rate(0.0, 1.0, a_p, a_s) == pytest.approx(a_p * a_s)


def test_reference_model_eq8_exact_discretisation():
    y = 0.0
    for _ in range(1000):
        y = reference_model_step(y, 0.01, 50.0, 50.0, 1e-3)
    assert y == pytest.approx(0.01, rel=1e-9)
    # one step from zero equals (b/a)(1 - e^{-a dt}) r
    assert reference_model_step(0.0, 1.0, 50.0, 50.0, 1e-3) == pytest.approx(1 - np.exp(-0.05))


def test_mrac_is_finite_at_zero_and_near_as_hat():
    c = make_controller("mrac", ar0=1.0, ay0=-0.5)
    for y in (0.0, 1e-12, 0.039, 0.04, 0.05, -0.2):
        s = c.new_state()
        u, rep = c.step(s, meas(y, 0.02), 1e-3)
        assert np.isfinite(u), y
        assert np.all(np.isfinite(s))
    # at y = 0 eq. (9) tends to a_r r k / a_s
    s = c.new_state()
    u, _ = c.step(s, meas(0.0, 0.02), 1e-3)
    assert u == pytest.approx(1.0 * 0.02 / 0.04)


def test_mrac_adaptation_signs_eq19_eq20():
    c = make_controller("mrac")
    s = c.new_state()
    s[0] = 0.01  # y_m above y = 0 -> e < 0 -> a_r grows for r > 0 (eq. 20)
    c.step(s, meas(0.0, 0.02), 1e-3)
    assert s[1] == pytest.approx(1e5 * 0.01 * 0.02 * 1e-3)
    assert s[2] == 0.0  # eq. (19): y = 0, no change


def test_mrac_literal_vs_dimensionless_as():
    lit = make_controller("mrac")
    dim = make_controller("mrac", dimensionless_as=True)
    s1, s2 = lit.new_state(), dim.new_state()
    s1[0] = s2[0] = 0.0
    lit.step(s1, meas(0.02, 0.02), 1e-3)
    dim.step(s2, meas(0.02, 0.02), 1e-3)
    # e = 0.02; literal regressor atanh(0.02) ~ 0.02, dimensionless atanh(0.5) ~ 0.55
    assert 0.04 - s1[3] == pytest.approx(2 * 0.02 * np.arctanh(0.02) * 1e-3)
    assert 0.04 - s2[3] == pytest.approx(2 * 0.02 * np.arctanh(0.5) * 1e-3)


def test_pid_anti_windup_freezes_integral_in_saturation():
    c = make_controller("pid")
    s = c.new_state()
    for _ in range(100):
        u, rep = c.step(s, meas(0.0, 0.1), 1e-3)  # huge error: saturated
    assert u > 10
    assert s[0] == pytest.approx(0.0)  # integral did not wind up
    assert np.isnan(rep).all()


def test_unknown_controller_and_option():
    with pytest.raises(ValueError, match="allowed"):
        make_controller("lqr")
    with pytest.raises(ValueError, match="unknown mrac option"):
        make_controller("mrac", gama=1)


@pytest.mark.parametrize(("name", "options", "words"), [
    ("mrac", {"gamma": float("nan")}, "gamma = nan must be a finite number"),
    ("mrac", {"a_m_per_s": -5.0}, "outside the allowed range"),
    ("mrac", {"dimensionless_as": 2.5}, "true or false"),
    ("pid", {"kp_v_per_m": float("inf")}, "finite number"),
    ("servo", {"harmonics": 2.5}, "whole number"),
    ("servo", {"learning_gain": "0.5"}, "finite number"),
])
def test_controller_options_are_checked_like_every_input(name, options, words):
    from sim.controllers import ControllerOptionError

    with pytest.raises(ControllerOptionError, match=words) as exc:
        make_controller(name, **options)
    key = next(iter(options))
    assert exc.value.field == f"controller_options.{key}" and exc.value.limit


def test_each_controller_declares_its_options_and_what_it_adapts():
    from sim.controllers import ADAPTED_LABELS, CONTROLLER_NAMES, describe_controllers

    described = {c["name"]: c for c in describe_controllers()}
    assert set(described) == set(CONTROLLER_NAMES)
    for c in described.values():
        assert all(o["unit"] and o["meaning"] for o in c["options"])
        assert all(a["column"] in ("model_m", "ar_hat", "ay_hat", "as_hat") and a["unit"] for a in c["adapted"])
    assert [a["name"] for a in described["mrac"]["adapted"]][1:] == ["a_r_hat", "a_y_hat", "a_s_hat"]
    assert described["pid"]["adapted"] == [] and ADAPTED_LABELS["pid"] == {}
    assert ADAPTED_LABELS["servo"]["as_hat"] == "learned frequency (Hz)"
    defaults = {o["name"]: o["default"] for o in described["mrac"]["options"]}
    assert defaults["gamma"] == 1e5 and defaults["gamma_as"] == 2.0 and defaults["as0_m"] == 0.04  # section V
