"""Synthetic ground accelerations: filtered white noise times an intensity envelope, nothing downloaded.

Method (all steps deterministic for a seed; numpy's PCG64 ``default_rng(seed)``):

1. Gaussian white noise at ``dt_s``, with a warm-up of 10 / (zeta_f omega_f) s discarded so the filtered
   process is stationary from t = 0.
2. Kanai-Tajimi site filter (Kanai 1957, Bull. Earthq. Res. Inst. 35, 309-325; Tajimi 1960, Proc. 2nd
   WCEE, 781-798) in series with the Clough-Penzien high-pass filter (Clough & Penzien, Dynamics of
   Structures, 1975), which removes the unbounded low-frequency displacement of the plain Kanai-Tajimi model:

       H(s) = (2 zeta_g omega_g s + omega_g^2) / (s^2 + 2 zeta_g omega_g s + omega_g^2)
              * s^2 / (s^2 + 2 zeta_f omega_f s + omega_f^2)

   discretised by the bilinear transform (scipy.signal.bilinear_zpk, second-order sections).
3. Intensity envelope of Jennings, Housner & Tsai (1968, "Simulated earthquake motions", EERL, Caltech):
   (t / t_1)^2 for t < t_1, 1 up to t_2, exp(-c (t - t_2)) after, times a raised-cosine taper over the last
   ``end_taper_s`` so the record ends at zero acceleration.
4. Optional near-fault velocity pulse of Mavroeidis & Papageorgiou (2003, BSSA 93(3), 1099-1131):
   v_p(t) = (A/2) [1 + cos(2 pi f_p (t - t_0) / gamma)] cos(2 pi f_p (t - t_0) + nu) for
   |t - t_0| <= gamma / (2 f_p), added as its derivative after the noise part is scaled to the PGA.
5. Baseline correction: a correction e(t) sum_j c_j P_j(2t/T - 1) (the envelope times Legendre polynomials of
   degree 0-5, so the quiet start and end stay quiet) is subtracted, the c_j minimising the mean square
   ground displacement subject to velocity and displacement (trapezoidal integration) exactly zero at the end
   (a polynomial baseline correction, cf. Boore & Bommer 2005, Soil Dyn. Earthq. Eng. 25, 93-115).
6. Scaling to ``pga_g`` (a linear step: the end velocity and displacement stay zero).

``synthetic_ground_motion(name_or_params, seed=None) -> (time_s, acc_m_per_s2, info)``; ``GROUND_MOTIONS`` holds
the named presets (each with its seed). ``info`` records every parameter and the measured peaks (PGA, PGV,
PGD), end velocity and displacement, Arias intensity and the 5-95 % significant duration.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from .errors import FieldError
from .structure import G_M_PER_S2

METHOD = ("Kanai-Tajimi x Clough-Penzien filtered white noise (bilinear, sosfilt), Jennings et al. 1968 envelope "
          "with a raised-cosine end taper, optional Mavroeidis-Papageorgiou 2003 pulse, envelope-weighted Legendre "
          "baseline correction (end velocity and displacement zero), scaled to pga_g")


BASELINE_TERMS = 6


class GroundMotionError(FieldError):
    """A ground motion parameter outside its allowed range; ``field`` names it."""


@dataclass(frozen=True)
class GroundMotionParams:
    """Parameters of ``synthetic_ground_motion`` (SI units; frequencies in Hz)."""

    name: str = "custom"
    description: str = ""
    seed: int = 0
    duration_s: float = 20.0
    dt_s: float = 0.005
    pga_g: float = 0.3
    site_frequency_hz: float = 2.5  # Kanai-Tajimi omega_g / 2 pi
    site_damping: float = 0.6  # zeta_g
    highpass_frequency_hz: float = 0.25  # Clough-Penzien omega_f / 2 pi
    highpass_damping: float = 0.6  # zeta_f
    rise_s: float = 2.0  # Jennings t_1
    strong_end_s: float = 8.0  # Jennings t_2
    decay_per_s: float = 0.3  # Jennings c
    end_taper_s: float = 2.0
    pulse_velocity_m_per_s: float = 0.0  # A (0: no pulse)
    pulse_period_s: float = 1.0  # 1 / f_p
    pulse_time_s: float = 3.0  # t_0, the pulse's centre
    pulse_cycles: float = 2.0  # gamma
    pulse_phase_deg: float = 0.0  # nu

    def to_dict(self) -> dict:
        return asdict(self)


LIMITS = {
    "seed": (0, 2**63 - 1, "-"),
    "duration_s": (1.0, 600.0, "s"),
    "dt_s": (0.001, 0.02, "s"),
    "pga_g": (0.001, 2.0, "g"),
    "site_frequency_hz": (0.1, 25.0, "Hz"),
    "site_damping": (0.05, 2.0, "-"),
    "highpass_frequency_hz": (0.01, 2.0, "Hz"),
    "highpass_damping": (0.1, 2.0, "-"),
    "rise_s": (0.0, 600.0, "s"),
    "strong_end_s": (0.0, 600.0, "s"),
    "decay_per_s": (0.0, 10.0, "1/s"),
    "end_taper_s": (0.0, 600.0, "s"),
    "pulse_velocity_m_per_s": (0.0, 3.0, "m/s"),
    "pulse_period_s": (0.2, 20.0, "s"),
    "pulse_time_s": (0.0, 600.0, "s"),
    "pulse_cycles": (1.0, 10.0, "-"),
    "pulse_phase_deg": (-360.0, 360.0, "deg"),
}


GROUND_MOTIONS: dict[str, GroundMotionParams] = {
    # short, strong, broad-band on a stiff site, with a forward-directivity velocity pulse
    "near_field_short": GroundMotionParams(
        name="near_field_short", description="short strong near-field-like motion with a 1.2 s velocity pulse",
        seed=1994, duration_s=15.0, pga_g=0.45, site_frequency_hz=3.0, site_damping=0.6,
        highpass_frequency_hz=0.25, highpass_damping=0.6, rise_s=0.5, strong_end_s=4.0, decay_per_s=0.6,
        end_taper_s=1.5, pulse_velocity_m_per_s=0.5, pulse_period_s=1.2, pulse_time_s=3.0, pulse_cycles=2.0,
        pulse_phase_deg=90.0),
    # long, moderate, far from the source: long strong phase, slow decay
    "far_field_long": GroundMotionParams(
        name="far_field_long", description="long moderate far-field-like motion (25 s of strong shaking)",
        seed=1985, duration_s=45.0, pga_g=0.15, site_frequency_hz=2.0, site_damping=0.5,
        highpass_frequency_hz=0.2, highpass_damping=0.6, rise_s=4.0, strong_end_s=25.0, decay_per_s=0.2,
        end_taper_s=3.0),
    # soft soil: narrow-band around 0.8 Hz, the band of isolated periods
    "soft_site": GroundMotionParams(
        name="soft_site", description="soft-soil motion, narrow band around 0.8 Hz (Kanai-Tajimi zeta_g = 0.25)",
        seed=1989, duration_s=30.0, pga_g=0.2, site_frequency_hz=0.8, site_damping=0.25,
        highpass_frequency_hz=0.15, highpass_damping=0.7, rise_s=3.0, strong_end_s=15.0, decay_per_s=0.25,
        end_taper_s=3.0),
}


def ground_motion_params(data: dict | GroundMotionParams) -> GroundMotionParams:
    """Validate parameters given as a dict (unknown keys refused) or a GroundMotionParams."""
    if isinstance(data, GroundMotionParams):
        data = asdict(data)
    if not isinstance(data, dict):
        raise GroundMotionError("ground_motion", data, "a name or a dict of parameters",
                                f"ground motion must be a preset name ({', '.join(GROUND_MOTIONS)}) or parameters")
    names = {f.name for f in fields(GroundMotionParams)}
    unknown = [k for k in data if k not in names]
    if unknown:
        raise GroundMotionError(unknown[0], data[unknown[0]], "a parameter of GroundMotionParams",
                                f"unknown ground motion parameter(s) {', '.join(unknown)}; allowed: "
                                f"{', '.join(sorted(names))}")
    params = GroundMotionParams(**data)
    for key, (lo, hi, unit) in LIMITS.items():
        value = getattr(params, key)
        integer = key == "seed"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or (integer and int(value) != value) or not (lo <= value <= hi):
            raise GroundMotionError(key, value, f"[{lo:g}, {hi:g}] {unit}",
                                    f"{key} = {value!r} is outside the allowed range [{lo:g}, {hi:g}] {unit}")
    if not params.rise_s <= params.strong_end_s <= params.duration_s:
        raise GroundMotionError("strong_end_s", params.strong_end_s, "rise_s <= strong_end_s <= duration_s",
                                f"the envelope needs rise_s ({params.rise_s:g}) <= strong_end_s "
                                f"({params.strong_end_s:g}) <= duration_s ({params.duration_s:g})")
    if params.end_taper_s > params.duration_s - params.strong_end_s:
        raise GroundMotionError("end_taper_s", params.end_taper_s, "<= duration_s - strong_end_s",
                                "the end taper must fit after the strong phase (end_taper_s <= duration_s - "
                                "strong_end_s)")
    if params.highpass_frequency_hz >= params.site_frequency_hz:
        raise GroundMotionError("highpass_frequency_hz", params.highpass_frequency_hz, "< site_frequency_hz",
                                "the Clough-Penzien high-pass frequency must be below the site frequency")
    if 1.0 / params.dt_s < 8.0 * params.site_frequency_hz:
        raise GroundMotionError("dt_s", params.dt_s, f"<= 1 / (8 site_frequency_hz) = "
                                f"{1 / (8 * params.site_frequency_hz):g} s",
                                "dt_s is too coarse for the site frequency (8 samples per period at least)")
    return replace(params, seed=int(params.seed))


def jennings_envelope(t: np.ndarray, p: GroundMotionParams) -> np.ndarray:
    """Jennings et al. (1968) envelope with the raised-cosine end taper (dimensionless, 0 at t = 0 and T)."""
    e = np.where(t < p.rise_s, (t / p.rise_s) ** 2 if p.rise_s > 0 else 1.0, 1.0)
    e = np.where(t > p.strong_end_s, np.exp(-p.decay_per_s * (t - p.strong_end_s)), e)
    if p.end_taper_s > 0:
        tau = np.clip((p.duration_s - t) / p.end_taper_s, 0.0, 1.0)
        e = e * 0.5 * (1.0 - np.cos(np.pi * tau))
    return e


def _filter_sos(p: GroundMotionParams):
    from scipy.signal import bilinear_zpk, zpk2sos

    wg, zg = 2 * np.pi * p.site_frequency_hz, p.site_damping
    wf, zf = 2 * np.pi * p.highpass_frequency_hz, p.highpass_damping
    zeros = np.array([-wg / (2 * zg), 0.0, 0.0])
    poles = np.concatenate([np.roots([1.0, 2 * zg * wg, wg * wg]), np.roots([1.0, 2 * zf * wf, wf * wf])])
    gain = 2 * zg * wg
    z, pz, k = bilinear_zpk(zeros, poles, gain, fs=1.0 / p.dt_s)
    return zpk2sos(z, pz, k)


def mp_pulse_acceleration(t: np.ndarray, p: GroundMotionParams) -> np.ndarray:
    """d/dt of the Mavroeidis-Papageorgiou velocity pulse (m/s2); zero if pulse_velocity_m_per_s = 0."""
    if p.pulse_velocity_m_per_s == 0.0:
        return np.zeros_like(t)
    a_amp, fp, gamma = p.pulse_velocity_m_per_s, 1.0 / p.pulse_period_s, p.pulse_cycles
    nu = math.radians(p.pulse_phase_deg)
    x = t - p.pulse_time_s
    inside = np.abs(x) <= gamma / (2 * fp)
    w1, w2 = 2 * np.pi * fp / gamma, 2 * np.pi * fp
    env, denv = 0.5 * a_amp * (1 + np.cos(w1 * x)), -0.5 * a_amp * w1 * np.sin(w1 * x)
    acc = denv * np.cos(w2 * x + nu) - env * w2 * np.sin(w2 * x + nu)
    return np.where(inside, acc, 0.0)


def _integrate(a: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement by the trapezoidal rule from rest."""
    v = np.concatenate(([0.0], np.cumsum(0.5 * dt * (a[1:] + a[:-1]))))
    d = np.concatenate(([0.0], np.cumsum(0.5 * dt * (v[1:] + v[:-1]))))
    return v, d


def baseline_correct(a: np.ndarray, dt: float, weight: np.ndarray, terms: int = BASELINE_TERMS) -> np.ndarray:
    """a - weight(t) sum_j c_j P_j(2 t / T - 1) (P_j Legendre polynomials, j < ``terms``), with the c_j minimising
    the mean square displacement subject to end velocity and displacement (trapezoidal) exactly zero."""
    from numpy.polynomial import legendre

    n = a.size
    t = np.arange(n) * dt
    x = 2.0 * t / t[-1] - 1.0
    basis = [weight * legendre.legval(x, np.eye(terms)[j]) for j in range(terms)]
    disp = np.empty((n, terms))
    ends = np.empty((2, terms))
    for j, b in enumerate(basis):
        vb, db = _integrate(b, dt)
        disp[:, j] = db
        ends[:, j] = (vb[-1], db[-1])
    va, da = _integrate(a, dt)
    kkt = np.zeros((terms + 2, terms + 2))  # least squares with two equality constraints (Lagrange)
    kkt[:terms, :terms] = np.einsum("ij,ik->jk", disp, disp)  # einsum: no BLAS threads
    kkt[:terms, terms:] = ends.T
    kkt[terms:, :terms] = ends
    rhs = np.concatenate([np.einsum("ij,i->j", disp, da), [va[-1], da[-1]]])
    c = np.linalg.lstsq(kkt, rhs, rcond=None)[0][:terms]
    return a - sum(c[j] * basis[j] for j in range(terms))


def synthetic_ground_motion(name_or_params: str | dict | GroundMotionParams = "far_field_long",
                            seed: int | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """(time_s, acc_m_per_s2, info) by the method of the module docstring; deterministic for a seed.

    ``name_or_params``: a preset of ``GROUND_MOTIONS``, a dict or a GroundMotionParams; ``seed`` overrides
    the preset's. ``info``: the parameters, ``method``, and the measured ``pga_m_per_s2``, ``pga_g``,
    ``pgv_m_per_s``, ``pgd_m``, ``end_velocity_m_per_s``, ``end_displacement_m``, ``arias_intensity_m_per_s``
    and ``significant_duration_s`` (5-95 % of the Arias intensity).
    """
    from scipy.signal import sosfilt

    if isinstance(name_or_params, str):
        if name_or_params not in GROUND_MOTIONS:
            raise GroundMotionError("ground_motion", name_or_params, ", ".join(GROUND_MOTIONS),
                                    f"unknown ground motion {name_or_params!r}: use one of "
                                    f"{', '.join(GROUND_MOTIONS)} or give parameters")
        params = GROUND_MOTIONS[name_or_params]
    else:
        params = ground_motion_params(name_or_params)
    if seed is not None:
        params = replace(params, seed=seed)
    p = ground_motion_params(params)
    dt = p.dt_s
    n = int(round(p.duration_s / dt)) + 1
    t = np.arange(n) * dt
    warm = int(math.ceil(min(10.0 / (p.highpass_damping * 2 * np.pi * p.highpass_frequency_hz), 60.0) / dt))
    noise = np.random.default_rng(p.seed).standard_normal(n + warm)
    stationary = sosfilt(_filter_sos(p), noise)[warm:]
    env = jennings_envelope(t, p)
    a = env * stationary
    a *= p.pga_g * G_M_PER_S2 / np.max(np.abs(a))
    a = a + mp_pulse_acceleration(t, p)
    a = baseline_correct(a, dt, env)
    a *= p.pga_g * G_M_PER_S2 / np.max(np.abs(a))
    v, d = _integrate(a, dt)
    arias = np.concatenate(([0.0], np.cumsum(0.5 * dt * (a[1:] ** 2 + a[:-1] ** 2)))) * np.pi / (2 * G_M_PER_S2)
    t5, t95 = np.interp([0.05 * arias[-1], 0.95 * arias[-1]], arias, t)
    info = {**p.to_dict(), "method": METHOD, "samples": n,
            "pga_m_per_s2": float(np.max(np.abs(a))), "pga_g": float(np.max(np.abs(a)) / G_M_PER_S2),
            "pgv_m_per_s": float(np.max(np.abs(v))), "pgd_m": float(np.max(np.abs(d))),
            "end_velocity_m_per_s": float(v[-1]), "end_displacement_m": float(d[-1]),
            "arias_intensity_m_per_s": float(arias[-1]), "significant_duration_s": float(t95 - t5)}
    return t, a, info


def _main() -> None:  # python -m sim.ground_motion: the presets and the isolator demand they make on the rig
    from .history import history_envelope_problem, isolation_displacement, prepare_history
    from .isolator import PRESETS
    from .rig import BAR_PA, DEFAULT_RIG

    supply = 210 * BAR_PA
    for name in GROUND_MOTIONS:
        t, a, info = synthetic_ground_motion(name)
        print(f"{name}: seed {info['seed']}, {info['duration_s']:g} s, PGA {info['pga_g']:.3f} g, PGV "
              f"{info['pgv_m_per_s']:.3f} m/s, PGD {info['pgd_m']:.3f} m, end v {info['end_velocity_m_per_s']:.1e} "
              f"m/s, end d {info['end_displacement_m']:.1e} m, Arias {info['arias_intensity_m_per_s']:.3f} m/s, "
              f"D5-95 {info['significant_duration_s']:.1f} s")
        for iso_name in ("IUT_a", "IUT_b"):
            iso = PRESETS[iso_name]
            mass = DEFAULT_RIG.vertical_load_n / G_M_PER_S2
            d = isolation_displacement(t, a, iso, mass)
            target = prepare_history(t, d, 1e-3, 1.0, 0.5, 0.5, source=name)
            meta = target.to_dict()
            lo, hi = 0.0, 1.0
            if history_envelope_problem(target, DEFAULT_RIG, iso, supply) is not None:
                for _ in range(20):  # largest ground-motion scale whose demand fits (bisection)
                    mid = 0.5 * (lo + hi)
                    tm = prepare_history(t, isolation_displacement(t, mid * a, iso, mass), 1e-3, 1.0, 0.5, 0.5)
                    lo, hi = (mid, hi) if history_envelope_problem(tm, DEFAULT_RIG, iso, supply) is None else (lo, mid)
                fits = f"refused at scale 1 ({history_envelope_problem(target, DEFAULT_RIG, iso, supply).limit}); " \
                       f"fits up to a ground-motion scale of {lo:.2f}"
            else:
                fits = "fits the default rig at 210 bar"
            print(f"  {iso_name} under {mass / 1e3:.2f} t: peak d {meta['peak_displacement_m'] * 1e3:.1f} mm, "
                  f"v {meta['peak_velocity_m_per_s']:.3f} m/s, a {meta['peak_acceleration_m_per_s2']:.2f} m/s2; "
                  f"{fits}")


if __name__ == "__main__":
    _main()
