import numpy as np
import pytest

from sim.ground_motion import GROUND_MOTIONS, GroundMotionError, synthetic_ground_motion
from sim.history import (
    HistoryError,
    history_envelope_problem,
    isolation_displacement,
    prepare_history,
    read_acceleration_csv,
    read_at2,
    read_displacement_csv,
    read_ground_motion,
)
from sim.isolator import PRESETS, Isolator
from sim.profiles import ProfileError
from sim.rig import BAR_PA, DEFAULT_RIG

G = 9.80665


def write_csv(path, header, t, y, fmt="{:.6f},{:.9g}"):
    lines = ([header] if header else []) + [fmt.format(a, b) for a, b in zip(t, y, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


# ---- CSV readers -----------------------------------------------------------------------------------------
def test_reads_a_displacement_csv_with_comments_and_header(tmp_path):
    t = np.arange(0, 2, 0.01)
    y = 0.01 * np.sin(2 * np.pi * t)
    p = tmp_path / "d.csv"
    body = "\n".join(f"{a:.2f},{b:.9g}" for a, b in zip(t, y, strict=True))
    p.write_text("# from an analysis\n\ntime_s,displacement_m\n" + body + "\n")
    tt, yy = read_displacement_csv(p)
    np.testing.assert_allclose(tt, t, atol=1e-12)
    np.testing.assert_allclose(yy, y, atol=1e-9)


def test_reads_semicolons_with_decimal_commas(tmp_path):
    t = np.arange(0, 1, 0.05)
    p = tmp_path / "d.csv"
    p.write_text("time_s;displacement_m\n" + "\n".join(f"{a:.2f};{0.001 * i:.3f}".replace(".", ",")
                                                       for i, a in enumerate(t)) + "\n")
    tt, yy = read_displacement_csv(p)
    np.testing.assert_allclose(yy, 0.001 * np.arange(t.size))


@pytest.mark.parametrize("edit, line, words", [
    (lambda rows: rows.__setitem__(7, "0.070,nan"), 9, "not a finite number"),  # header is line 1
    (lambda rows: rows.__setitem__(7, "0.070,abc"), 9, "is not a number"),
    (lambda rows: rows.__setitem__(7, "0.070"), 9, "missing value"),
    (lambda rows: rows.__setitem__(7, "0.060,0.0"), 9, "not after the previous row"),
    (lambda rows: rows.__delitem__(slice(7, 10)), 9, "a gap"),
    (lambda rows: rows.__setitem__(7, "0.0705,0.0"), 9, "non-uniform step"),
])
def test_bad_rows_are_named(tmp_path, edit, line, words):
    rows = [f"{0.01 * i:.3f},{0.001 * i:.4f}" for i in range(30)]
    edit(rows)
    p = tmp_path / "bad.csv"
    p.write_text("time_s,displacement_m\n" + "\n".join(rows) + "\n")
    with pytest.raises(HistoryError, match=words) as err:
        read_displacement_csv(p)
    assert err.value.line == line
    assert f"line {line}" in str(err.value) and "bad.csv" in str(err.value)
    assert isinstance(err.value, ValueError)


def test_too_few_rows_and_missing_file(tmp_path):
    p = write_csv(tmp_path / "short.csv", "time_s,displacement_m", np.arange(5) * 0.01, np.zeros(5))
    with pytest.raises(HistoryError, match="only 5 data row"):
        read_displacement_csv(p)
    with pytest.raises(HistoryError, match="cannot read"):
        read_displacement_csv(tmp_path / "none.csv")


def test_acceleration_units_and_plausibility(tmp_path):
    t = np.arange(0, 1, 0.005)
    shape = np.sin(2 * np.pi * 2 * t)
    # a record in m/s2 with a 9.8 peak: fine as m/s2 (1 g) ...
    p = write_csv(tmp_path / "a.csv", "time_s,acceleration_m_per_s2", t, 9.8 * shape)
    _, a = read_acceleration_csv(p)
    assert np.max(np.abs(a)) == pytest.approx(9.8, rel=1e-6)
    # ... but read as g it would be 9.8 g: refused, saying what was assumed and what to choose
    p2 = write_csv(tmp_path / "b.csv", "time_s,accel", t, 9.8 * shape)
    with pytest.raises(HistoryError, match=r"read as g \(given\).*units='m/s2'") as err:
        read_acceleration_csv(p2, units="g")
    assert err.value.field == "units"
    # a record in g (peak 0.35) read with the default unit: m/s2 is assumed and the message says so
    p3 = write_csv(tmp_path / "c.csv", "time_s,accel", t, 0.035 * shape)
    with pytest.raises(HistoryError, match=r"assumed: no unit in the header.*units='g'"):
        read_acceleration_csv(p3)
    _, a3 = read_acceleration_csv(p3, units="g")
    assert np.max(np.abs(a3)) == pytest.approx(0.035 * G, rel=1e-6)
    _, a3b = read_acceleration_csv(p3, check_units=False)
    assert np.max(np.abs(a3b)) == pytest.approx(0.035, rel=1e-6)
    # the header's unit is used, and a contradicting argument refused
    p4 = write_csv(tmp_path / "d.csv", "time_s,acceleration_g", t, 0.3 * shape)
    assert np.max(np.abs(read_acceleration_csv(p4)[1])) == pytest.approx(0.3 * G, rel=1e-6)
    with pytest.raises(HistoryError, match="header names"):
        read_acceleration_csv(p4, units="m/s2")
    with pytest.raises(HistoryError, match="units"):
        read_acceleration_csv(p4, units="ft/s2")


AT2 = """PEER NGA STRONG MOTION DATABASE RECORD
SYNTHETIC TEST, 1/1/2000, ISORIG, 000
ACCELERATION TIME HISTORY IN UNITS OF G
NPTS=   {n}, DT=   .0050 SEC
{body}
"""


def at2_body(values, per_line=5):
    rows = [values[i:i + per_line] for i in range(0, len(values), per_line)]
    return "\n".join("".join(f"{v:15.7E}" for v in row) for row in rows)


def test_reads_at2_in_g(tmp_path):
    values = 0.2 * np.sin(np.arange(47) * 0.3)
    p = tmp_path / "rec.AT2"
    p.write_text(AT2.format(n=47, body=at2_body(values)))
    t, a = read_at2(p)
    assert t.size == 47 and t[1] == pytest.approx(0.005)
    np.testing.assert_allclose(a, values * G, rtol=1e-6, atol=1e-12)
    t2, a2 = read_ground_motion(p)
    np.testing.assert_array_equal(a, a2)


def fortran_e(v: float) -> str:
    """Fortran E10.4 with a 0.dddd mantissa and the leading zero dropped: ' .1000E+00', '-.2000E+00'."""
    if v == 0:
        return " .0000E+00"
    exp = int(np.floor(np.log10(abs(v)))) + 1
    mant = abs(v) / 10.0 ** exp
    return f"{'-' if v < 0 else ' '}.{round(mant * 1e4):04d}E{exp:+03d}"


def test_reads_old_at2_header_and_touching_fortran_fields(tmp_path):
    p = tmp_path / "old.at2"
    vals = [0.1, -0.2, 0.05, -0.15] * 5
    body = "\n".join("".join(fortran_e(v) for v in vals[i:i + 4]) for i in range(0, 20, 4))
    assert "E+00-.2000E+00" in body  # negative fields touch the previous one
    p.write_text("TITLE\nEVENT\nACCELERATION IN G\n   20    .01000   NPTS, DT\n" + body + "\n")
    t, a = read_at2(p)
    assert t[-1] == pytest.approx(0.19)
    np.testing.assert_allclose(a / G, vals, rtol=1e-6)


@pytest.mark.parametrize("body, npts, line, words", [
    (at2_body([0.1] * 12), 15, 7, "ends after 12 values"),
    (at2_body([0.1] * 5) + "\n   1.0E-01  abc   2.0E-01", 15, 6, "'abc' is not a number"),
    (at2_body([0.1] * 15) + "\n  5.0E-02", 15, 8, "more than NPTS"),
])
def test_bad_at2_files_name_the_line(tmp_path, body, npts, line, words):
    p = tmp_path / "bad.AT2"
    p.write_text(AT2.format(n=npts, body=body))
    with pytest.raises(HistoryError, match=words) as err:
        read_at2(p)
    assert err.value.line == line and f"line {line}" in str(err.value)


def test_at2_without_npts_or_in_the_wrong_unit(tmp_path):
    p = tmp_path / "x.AT2"
    p.write_text("a\nb\nc\nd\n 0.1 0.2\n")
    with pytest.raises(HistoryError, match="NPTS and DT"):
        read_at2(p)
    p.write_text(AT2.format(n=20, body=at2_body([9.8] * 20)))  # m/s2 values in a g file: 9.8 g
    with pytest.raises(HistoryError, match="units='m/s2'"):
        read_at2(p)
    assert read_at2(p, check_units=False)[1][0] == pytest.approx(9.8 * G)


# ---- prepare_history -------------------------------------------------------------------------------------
def test_prepared_history_is_resampled_tapered_and_consistent():
    f, amp = 0.7, 0.02
    t = np.arange(0, 10.0 + 1e-9, 0.005)  # 200 Hz record
    x = amp * np.sin(2 * np.pi * f * t)
    h = prepare_history(t, x, 1e-3, scale=1.5, taper_in_s=1.0, taper_out_s=2.0, source="sine")
    tk = h.time_s
    assert h.n_samples == 10_001 and h.duration_s == pytest.approx(10.0)
    for arr in (h.r_m, h.r_dot_m_per_s, h.r_ddot_m_per_s2):
        assert arr.dtype == np.float64 and arr.flags.c_contiguous
    # closed form: r = 1.5 e(t) A sin(w t) with the raised-cosine tapers, and its two derivatives
    w = 2 * np.pi * f
    e, de, dde = np.ones_like(tk), np.zeros_like(tk), np.zeros_like(tk)
    for mask, tau, width, sign in ((tk < 1, tk, 1.0, 1.0), (tk > 8, 10 - tk, 2.0, -1.0)):
        q = np.pi * tau[mask] / width
        e[mask] = 0.5 * (1 - np.cos(q))
        de[mask] = sign * 0.5 * np.pi / width * np.sin(q)
        dde[mask] = 0.5 * (np.pi / width) ** 2 * np.cos(q)
    s, c = amp * np.sin(w * tk), amp * w * np.cos(w * tk)
    np.testing.assert_allclose(h.r_m, 1.5 * e * s, atol=1e-9)
    np.testing.assert_allclose(h.r_dot_m_per_s, 1.5 * (de * s + e * c), atol=1e-7)
    np.testing.assert_allclose(h.r_ddot_m_per_s2, 1.5 * (dde * s + 2 * de * c - e * w * w * s), atol=2e-4)
    # and r' is the derivative of r sample to sample (central differences, away from the tapers' kinks)
    fd1 = np.gradient(h.r_m, 1e-3)
    assert np.max(np.abs(fd1 - h.r_dot_m_per_s)[1100:7900]) < 1e-5 * np.max(np.abs(h.r_dot_m_per_s))
    # at rest at both ends
    for k in (0, -1):
        assert abs(h.r_m[k]) < 1e-15 and abs(h.r_dot_m_per_s[k]) < 1e-12
    meta = h.to_dict()
    assert meta["scale"] == 1.5 and meta["source"] == "sine" and meta["source_dt_s"] == pytest.approx(0.005)
    assert not any(isinstance(v, np.ndarray) for v in meta.values())
    assert meta["peak_displacement_m"] == pytest.approx(0.03, rel=1e-3)


def test_prepare_history_refusals():
    t = np.arange(0, 5, 0.01)
    x = 0.01 * np.cos(2 * np.pi * t)  # starts at 10 mm
    with pytest.raises(HistoryError, match="starts away from rest") as err:
        prepare_history(t, x, taper_in_s=0.0)
    assert err.value.field == "taper_in_s"
    prepare_history(t, x, taper_in_s=0.0, require_rest=False)
    with pytest.raises(HistoryError, match="taper_in_s \\+ taper_out_s"):
        prepare_history(t, x, taper_in_s=3.0, taper_out_s=3.0)
    with pytest.raises(HistoryError, match="scale"):
        prepare_history(t, x, scale=0.0)
    bad = x.copy()
    bad[17] = np.nan
    with pytest.raises(HistoryError, match="sample 17"):
        prepare_history(t, bad)


def test_lowpass_removes_noise_before_derivatives():
    t = np.arange(0, 6, 1e-3)
    rng = np.random.default_rng(3)
    x = 0.01 * np.sin(2 * np.pi * 0.5 * t) + 1e-5 * rng.standard_normal(t.size)
    raw = prepare_history(t, x, 1e-3)
    smooth = prepare_history(t, x, 1e-3, lowpass_hz=5.0)
    peak = 0.01 * (2 * np.pi * 0.5) ** 2
    assert np.max(np.abs(raw.r_ddot_m_per_s2)) > 10 * peak  # noise blows up the second derivative
    assert np.max(np.abs(smooth.r_ddot_m_per_s2)) < 1.5 * peak


# ---- the isolation model -----------------------------------------------------------------------------------
def test_isolation_displacement_of_a_linear_isolator_matches_the_closed_form():
    # m x'' + k x = -m A sin(w t) from rest: x = X (sin w t - (w / wn) sin wn t), X = -A / (wn^2 - w^2)
    iso = Isolator("lin", 100.0, 0.5, 1.0, 5.0e5, 0.0)
    m, amp, w = 12_000.0, 2.0, 2 * np.pi * 0.8
    wn = np.sqrt(5.0e5 / m)
    t = np.arange(0, 10, 0.001)  # a_g is linear between samples: (w dt)^2 / 8 ~ 3e-6 from the sine
    x = isolation_displacement(t, amp * np.sin(w * t), iso, m)
    big_x = -amp / (wn ** 2 - w ** 2)
    exact = big_x * (np.sin(w * t) - w / wn * np.sin(wn * t))
    assert np.max(np.abs(x - exact)) < 1e-5 * np.max(np.abs(exact))


def test_isolation_displacement_of_bouc_wen_converges_and_dissipates():
    t = np.arange(0, 14, 0.005)
    ag = np.where(t < 6, 3.0 * np.sin(2 * np.pi * 1.0 * t) * np.sin(np.pi * t / 6) ** 2, 0.0)
    iso = PRESETS["IUT_b"]
    x = isolation_displacement(t, ag, iso, 12_742.0)
    fine = isolation_displacement(t, ag, iso, 12_742.0, substeps=200)
    assert np.max(np.abs(x - fine)) < 1e-6 * np.max(np.abs(x))
    # hysteresis damps the free vibration after the shaking; the k_d spring alone keeps ringing
    lin = isolation_displacement(t, ag, Isolator("kd", 90.0, 0.5, 1.0, iso.kd_n_per_m, 0.0), 12_742.0)
    late = t > 12
    assert np.ptp(x[late]) < 0.2 * np.ptp(x)
    assert np.ptp(lin[late]) > 0.5 * np.ptp(lin[t > 6])
    with pytest.raises(HistoryError, match="mass_kg"):
        isolation_displacement(t, ag, iso, 0.0)


# ---- the envelope ----------------------------------------------------------------------------------------
def sine_history(amplitude_m, frequency_hz, duration_s=6.0, **kw):
    t = np.arange(0, duration_s + 1e-9, 0.002)
    return prepare_history(t, amplitude_m * np.sin(2 * np.pi * frequency_hz * t), 1e-3, **kw)


def test_envelope_accepts_a_modest_history():
    h = sine_history(0.03, 0.5)
    assert history_envelope_problem(h, DEFAULT_RIG, PRESETS["IUT_a"], 210 * BAR_PA) is None


def test_envelope_refuses_stroke_at_the_first_sample_beyond():
    h = sine_history(0.1, 0.5, scale=1.6)
    err = history_envelope_problem(h, DEFAULT_RIG, PRESETS["IUT_b"], 210 * BAR_PA)
    assert isinstance(err, ProfileError) and err.field == "history" and "stroke" in err.limit
    k = int(np.flatnonzero(np.abs(h.r_m) > DEFAULT_RIG.stroke_m)[0])
    assert err.sample == k and err.time_s == pytest.approx(k * 1e-3)
    assert f"t = {k * 1e-3:.3f} s" in str(err) and "scale of at most" in str(err)


def test_envelope_refuses_velocity_beyond_the_pump():
    # 10 mm at 8 Hz: 0.5 m/s peak, beyond Q_pump / A_p = 0.42 m/s
    h = sine_history(0.01, 8.0, duration_s=3.0)
    err = history_envelope_problem(h, DEFAULT_RIG, PRESETS["IUT_a"], 210 * BAR_PA)
    assert err is not None and "pump" in err.limit
    v_max = DEFAULT_RIG.pump_max_flow_m3_per_s / DEFAULT_RIG.piston_area_m2
    assert abs(err.value) > v_max
    assert np.all(np.abs(h.r_dot_m_per_s[:err.sample]) <= v_max)


def test_envelope_refuses_force_at_low_supply_and_names_the_inertia():
    h = sine_history(0.06, 0.5)
    err = history_envelope_problem(h, DEFAULT_RIG, PRESETS["IUT_a"], 50 * BAR_PA)
    assert err is not None and "A_p P_s" in err.limit and "inertial" in str(err)
    assert history_envelope_problem(h, DEFAULT_RIG, PRESETS["IUT_a"], 210 * BAR_PA) is None


# ---- synthetic ground motions ----------------------------------------------------------------------------
def test_ground_motions_are_deterministic_scaled_and_end_at_rest():
    for name, preset in GROUND_MOTIONS.items():
        t, a, info = synthetic_ground_motion(name)
        assert info["seed"] == preset.seed and info["name"] == name
        assert np.max(np.abs(a)) == pytest.approx(preset.pga_g * G, rel=1e-9)
        assert a[0] == 0.0 and abs(a[-1]) < 1e-12
        assert abs(info["end_velocity_m_per_s"]) < 1e-9 and abs(info["end_displacement_m"]) < 1e-9
        assert t[-1] == pytest.approx(preset.duration_s)
    t1, a1, _ = synthetic_ground_motion("soft_site", seed=5)
    t2, a2, _ = synthetic_ground_motion("soft_site", seed=5)
    _, a3, _ = synthetic_ground_motion("soft_site", seed=6)
    np.testing.assert_array_equal(a1, a2)
    assert np.max(np.abs(a1 - a3)) > 0.1


def test_ground_motion_spectrum_peaks_near_the_site_frequency():
    t, a, info = synthetic_ground_motion("soft_site")
    spec = np.abs(np.fft.rfft(a)) ** 2
    f = np.fft.rfftfreq(a.size, t[1])
    smooth = np.convolve(spec, np.ones(41) / 41, mode="same")
    assert abs(f[np.argmax(smooth)] - info["site_frequency_hz"]) < 0.3


def test_ground_motion_parameters_are_checked():
    with pytest.raises(GroundMotionError) as err:
        synthetic_ground_motion({"pga_g": 5.0})
    assert err.value.field == "pga_g"
    with pytest.raises(GroundMotionError, match="unknown"):
        synthetic_ground_motion("nope")
    with pytest.raises(GroundMotionError) as err:
        synthetic_ground_motion({"site_frequencyhz": 2.0})
    assert err.value.field == "site_frequencyhz"
