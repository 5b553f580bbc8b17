"""Criteria of real-time hybrid simulation (RTHS) and an online energy-based stability monitor.

Criteria, after the RTHS benchmark (Silva, C. E., Gomez, D., Maghareh, A., Dyke, S. J. & Spencer, B. F.,
2020, "Benchmark control problem for real-time hybrid simulation", Mech. Syst. Signal Process. 135, 106381),
for a command x_c (what the controller was asked) and a measurement x_m (what the rig did), over the N samples
of the test, in the normalisation computed here:

    J1 = the time delay of x_m behind x_c (ms): the shift tau maximising the normalised cross-correlation
         of x_m(t) and x_c(t - tau) on the samples common to every shift; integer lag first, then refined by a
         bounded scalar search with x_c between samples by a cubic spline (resolution better than 1 us at 1 kHz).
         Positive when the measurement lags.
    J2 = 100 sqrt( sum (x_m - x_c)^2 / sum x_c^2 )            (%, normalised RMS tracking error)
    J3 = 100 max |x_m - x_c| / max |x_c|                      (%, normalised peak tracking error)

over the periods whose measurement arrived: a period whose packet was lost holds the previous reading (its row
is flagged FLAG_LOST), which is not where the table was, so J2 and J3 leave it out, and J1 bridges it by a
straight line between the measurements around it (a delay fit needs evenly spaced samples).

and, for the RTHS's base displacement x (the numerical substructure's) against the full-numerical reference
x_ref (sim.structure.reference_response) on the same time grid:

    J4 = 100 sqrt( sum (x - x_ref)^2 / sum x_ref^2 )          (%)
    J5 = 100 max |x - x_ref| / max |x_ref|                    (%)

Stability monitor (``EnergyMonitor``): the energy the tracking error adds to the loop,

    E_err(t) = integral F_m (x_m' - x_c') dt = sum 1/2 (F_m,k + F_m,k+1) [(x_m,k+1 - x_m,k) - (x_c,k+1 - x_c,k)]

the work of the measured force on the commanded path counted by the numerical model (integral F_m dx_c) taken
from the work actually done on the specimen (integral F_m dx_m), after the energy-based error monitors of
Mosqueda, Stojadinovic & Mahin (2007, "Real-time error monitoring for hybrid simulation. Part I", J. Struct.
Eng. 133(8), 1100-1108) and Galmez & Fermandois (2020, "Online stability analysis for real-time hybrid
simulation testing", Front. Built Environ. 6, 134). A lagging actuator on a spring of stiffness k at
x_c = X sin(omega t) adds E_err = pi k X^2 sin(omega tau) per cycle (> 0: energy injected, the source of
RTHS instability); an actuator that leads removes energy. The monitor trips when E_err exceeds
max(``limit_j``, ``relative_limit`` x the reference energy), the reference energy being the largest input
energy so far (the numerical model's relative input energy, sim.structure.CRIntegrator.input_energy_j) or,
when none is given, the largest work done on the specimen so far.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_MAX_DELAY_S = 0.1
DEFAULT_ENERGY_LIMIT_J = 100.0
DEFAULT_RELATIVE_ENERGY_LIMIT = 0.5


def _pair(a, b, names: tuple[str, str]) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape or x.size < 4:
        raise ValueError(f"{names[0]} and {names[1]} must be 1-D arrays of the same length (>= 4 samples)")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError(f"{names[0]} and {names[1]} must be finite")
    return x, y


def nrms_percent(value, reference) -> float:
    """100 sqrt(sum (value - reference)^2 / sum reference^2) (%); NaN if the reference is all zero."""
    x, r = _pair(value, reference, ("value", "reference"))
    den = float(np.sum(r * r))
    return 100.0 * math.sqrt(float(np.sum((x - r) ** 2)) / den) if den > 0 else float("nan")


def npeak_percent(value, reference) -> float:
    """100 max |value - reference| / max |reference| (%); NaN if the reference is all zero."""
    x, r = _pair(value, reference, ("value", "reference"))
    den = float(np.max(np.abs(r)))
    return 100.0 * float(np.max(np.abs(x - r))) / den if den > 0 else float("nan")


def time_delay_s(command, measured, dt_s: float, max_delay_s: float = DEFAULT_MAX_DELAY_S) -> float:
    """J1 in seconds: how late ``measured`` follows ``command`` (negative if it leads), |delay| <= max_delay_s.

    rho(tau) = <x_m, x_c(. - tau)>^2 / (|x_m|^2 |x_c(. - tau)|^2) (means removed), the squared normalised
    cross-correlation on the samples common to every shift, is maximised first over whole samples (positive
    correlation only), then over [lag - 1, lag + 1] samples by a bounded Brent search with x_c between samples
    from a cubic spline. NaN if either signal is constant. Cost: one FFT correlation and ~20 spline evaluations.
    """
    from scipy.interpolate import CubicSpline
    from scipy.optimize import minimize_scalar
    from scipy.signal import correlate

    c, m = _pair(command, measured, ("command", "measured"))
    if not (isinstance(dt_s, (int, float)) and dt_s > 0 and math.isfinite(dt_s)):
        raise ValueError(f"dt_s = {dt_s!r} must be a positive number of seconds")
    if np.ptp(c) == 0.0 or np.ptp(m) == 0.0:
        return float("nan")
    n = c.size
    max_lag = int(min(max(1, round(max_delay_s / dt_s)), (n - 8) // 4))
    lo, hi = max_lag + 2, n - max_lag - 2  # the samples of x_m common to every shift
    length = hi - lo
    mw = m[lo:hi] - m[lo:hi].mean()
    mm = float(np.sum(mw * mw))  # element-wise sums: no BLAS threads next to the real-time loop
    if mm == 0.0:
        return float("nan")
    # integer lags k: x_c[lo - k : hi - k] against mw; cross terms by one FFT correlation, norms by cumsums
    lags = np.arange(-max_lag, max_lag + 1)
    starts = lo - lags
    cross = correlate(c, mw, mode="valid", method="fft")[starts]
    s1 = np.concatenate(([0.0], np.cumsum(c)))
    s2 = np.concatenate(([0.0], np.cumsum(c * c)))
    seg_sum = s1[starts + length] - s1[starts]
    cc = s2[starts + length] - s2[starts] - seg_sum * seg_sum / length
    scores = np.where((cross > 0) & (cc > 0), cross * cross / (mm * np.maximum(cc, 1e-300)), 0.0)
    best = int(lags[int(np.argmax(scores))])
    spline = CubicSpline(np.arange(n, dtype=np.float64), c)
    idx = np.arange(lo, hi, dtype=np.float64)

    def cost(tau: float) -> float:
        cs = spline(idx - tau)
        cs -= cs.mean()
        den = float(np.sum(cs * cs))
        return -float(np.sum(mw * cs)) ** 2 / (mm * den) if den > 0 else 0.0

    res = minimize_scalar(cost, bounds=(best - 1.0, best + 1.0), method="bounded", options={"xatol": 1e-5})
    return float(res.x) * dt_s


def tracking_criteria(command_m, measured_m, dt_s: float, max_delay_s: float = DEFAULT_MAX_DELAY_S,
                      measured=None) -> dict:
    """{"j1_delay_ms", "j2_rms_percent", "j3_peak_percent"} of a command/measurement pair (module docstring).

    ``measured``: True where the period's measurement arrived (sim.measurement.measured_rows of the record's
    flags; None: every period). J2 and J3 are taken over those periods; J1 over every period, a lost one bridged
    by a straight line between the measurements around it."""
    c, m = _pair(command_m, measured_m, ("command", "measured"))
    fresh = np.ones(c.size, dtype=bool) if measured is None else np.asarray(measured, dtype=bool)
    if fresh.shape != c.shape:
        raise ValueError("measured must be one flag per sample of the command")
    if fresh.sum() < 4:
        nan = float("nan")
        return {"j1_delay_ms": nan, "j2_rms_percent": nan, "j3_peak_percent": nan}
    index = np.arange(c.size)
    bridged = m if fresh.all() else np.interp(index, index[fresh], m[fresh])  # for J1 only
    return {"j1_delay_ms": 1e3 * time_delay_s(c, bridged, dt_s, max_delay_s),
            "j2_rms_percent": nrms_percent(m[fresh], c[fresh]),
            "j3_peak_percent": npeak_percent(m[fresh], c[fresh])}


def reference_criteria(response_m, reference_m) -> dict:
    """{"j4_rms_percent", "j5_peak_percent"} of the RTHS's base displacement against the reference's."""
    return {"j4_rms_percent": nrms_percent(response_m, reference_m),
            "j5_peak_percent": npeak_percent(response_m, reference_m)}


#: the issue's targets (upper bounds): J1-J3 on the rig's tracking, J4-J5 of an RTHS against its reference
CRITERIA = (
    ("j1_delay_ms", "J1", 1.0, "ms", "time delay of the measured displacement behind the command"),
    ("j2_rms_percent", "J2", 1.0, "%", "normalised RMS tracking error"),
    ("j3_peak_percent", "J3", 3.0, "%", "normalised peak tracking error"),
    ("j4_rms_percent", "J4", 2.0, "%", "normalised RMS error of the base displacement against the reference"),
    ("j5_peak_percent", "J5", 3.0, "%", "normalised peak error of the base displacement against the reference"),
)


def criteria_verdicts(criteria: dict) -> list[dict]:
    """One line per criterion present in ``criteria`` (the keys of ``tracking_criteria`` and
    ``reference_criteria``): name, value, target (an upper bound; J1 on the delay's size), unit, what it
    measures and ``met`` (None when the value is not a number)."""
    out = []
    for key, name, target, unit, meaning in CRITERIA:
        if key not in criteria:
            continue
        value = criteria[key]
        finite = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        size = abs(value) if finite and key == "j1_delay_ms" else value
        out.append({"key": key, "name": name, "value": value if finite else None, "target": target, "unit": unit,
                    "bound": f"{'|J1|' if key == 'j1_delay_ms' else name} <= {target:g} {unit}",
                    "meaning": meaning, "met": (size <= target) if finite else None})
    return out


def tracking_error_energy(force_n, command_m, measured_m) -> np.ndarray:
    """E_err(t_k) (J) for whole records: the cumulative sum of 1/2 (F_k + F_k+1) (dx_m - dx_c), E_err(0) = 0."""
    f = np.asarray(force_n, dtype=np.float64)
    c = np.asarray(command_m, dtype=np.float64)
    m = np.asarray(measured_m, dtype=np.float64)
    if not (f.shape == c.shape == m.shape) or f.ndim != 1:
        raise ValueError("force_n, command_m and measured_m must be 1-D arrays of the same length")
    inc = 0.5 * (f[1:] + f[:-1]) * (np.diff(m) - np.diff(c))
    return np.concatenate(([0.0], np.cumsum(inc)))


class EnergyMonitor:
    """Online E_err (module docstring), updated once per control period with a few float operations.

    ``update(force_n, command_m, measured_m, input_energy_j=None, time_s=None) -> bool`` returns True once
    the limit is passed (and stays tripped until ``reset``); ``reason`` then says what, when and by how much.
    Attributes (J): ``added_energy_j`` (E_err), ``specimen_energy_j`` (integral F dx_m),
    ``command_energy_j`` (integral F dx_c), ``reference_energy_j`` (the scale of the relative limit),
    ``limit_j`` (the current threshold); ``ratio`` = E_err / reference energy (the live indicator).
    """

    def __init__(self, limit_j: float = DEFAULT_ENERGY_LIMIT_J,
                 relative_limit: float = DEFAULT_RELATIVE_ENERGY_LIMIT):
        for name, value in (("limit_j", limit_j), ("relative_limit", relative_limit)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0:
                raise ValueError(f"{name} = {value!r} must be a non-negative number")
        self.absolute_limit_j = float(limit_j)
        self.relative_limit = float(relative_limit)
        self.reset()

    def reset(self) -> None:
        self.added_energy_j = 0.0
        self.specimen_energy_j = 0.0
        self.command_energy_j = 0.0
        self.reference_energy_j = 0.0
        self.limit_j = self.absolute_limit_j
        self.tripped = False
        self.reason = ""
        self.trip_time_s = None
        self.at_trip: dict | None = None  # the energies and the limit when it tripped (they go on after)
        self._first = True
        self._f = 0.0
        self._c = 0.0
        self._m = 0.0

    @property
    def ratio(self) -> float:
        return self.added_energy_j / self.reference_energy_j if self.reference_energy_j > 0 else 0.0

    @property
    def indicator(self) -> float:
        """E_err / the current limit: the monitor trips when this passes 1 (the live indicator to plot)."""
        return self.added_energy_j / self.limit_j if self.limit_j > 0 else (math.inf if self.added_energy_j > 0
                                                                              else 0.0)

    def live(self, time_s: float | None = None) -> dict:
        """The few figures a live display needs: E_err, the limit, the reference energy, ``ratio``,
        ``indicator`` (E_err / limit: trips at 1) and ``tripped``."""
        return {"time_s": time_s, "added_energy_j": self.added_energy_j, "limit_j": self.limit_j,
                "reference_energy_j": self.reference_energy_j, "ratio": self.ratio, "indicator": self.indicator,
                "tripped": self.tripped}

    def update(self, force_n: float, command_m: float, measured_m: float, input_energy_j: float | None = None,
               time_s: float | None = None) -> bool:
        """One period: the measured force (N), the command and the measured displacement (m) of this period,
        optionally the numerical model's input energy so far (J) and the time (s, for the reason)."""
        if self._first:
            self._first = False
        else:
            f = 0.5 * (self._f + force_n)
            dm = measured_m - self._m
            dc = command_m - self._c
            self.specimen_energy_j += f * dm
            self.command_energy_j += f * dc
            self.added_energy_j += f * (dm - dc)
        self._f, self._c, self._m = force_n, command_m, measured_m
        scale = abs(input_energy_j) if input_energy_j is not None else self.specimen_energy_j
        if scale > self.reference_energy_j:
            self.reference_energy_j = scale
        limit = self.relative_limit * self.reference_energy_j
        self.limit_j = limit if limit > self.absolute_limit_j else self.absolute_limit_j
        if not self.tripped and not math.isfinite(self.added_energy_j):
            self.tripped = True
            self.trip_time_s = time_s
            self.reason = ("RTHS stability monitor: a non-finite force or displacement"
                           + (f" at t = {time_s:.3f} s" if time_s is not None else ""))
        elif not self.tripped and self.added_energy_j > self.limit_j:
            self.tripped = True
            self.trip_time_s = time_s
            self.at_trip = {"time_s": time_s, "added_energy_j": self.added_energy_j, "limit_j": self.limit_j,
                            "reference_energy_j": self.reference_energy_j,
                            "specimen_energy_j": self.specimen_energy_j, "command_energy_j": self.command_energy_j}
            when = f" at t = {time_s:.3f} s" if time_s is not None else ""
            self.reason = (f"RTHS stability monitor: the tracking error added {self.added_energy_j:.4g} J to the "
                           f"loop{when}, above the limit {self.limit_j:.4g} J = max({self.absolute_limit_j:g} J, "
                           f"{100 * self.relative_limit:g} % of the reference energy "
                           f"{self.reference_energy_j:.4g} J)")
        return self.tripped

    def to_dict(self) -> dict:
        return {"added_energy_j": self.added_energy_j, "specimen_energy_j": self.specimen_energy_j,
                "command_energy_j": self.command_energy_j, "reference_energy_j": self.reference_energy_j,
                "limit_j": self.limit_j, "absolute_limit_j": self.absolute_limit_j,
                "relative_limit": self.relative_limit, "ratio": self.ratio, "indicator": self.indicator,
                "tripped": self.tripped,
                "reason": self.reason, "trip_time_s": self.trip_time_s,
                "at_trip": dict(self.at_trip) if self.at_trip is not None else None}


def _main() -> None:  # python -m sim.hybrid_metrics: virtual RTHS with an ideal delayed actuator
    import time

    from .ground_motion import synthetic_ground_motion
    from .isolator import PRESETS
    from .structure import ShearBuilding, reference_response, virtual_rths

    building = ShearBuilding.from_dict(DEMO_BUILDING)
    print(f"demo building: {DEMO_BUILDING}; fixed-base periods "
          + ", ".join(f"{p:.3f}" for p in building.fixed_base_periods_s()) + " s; modal damping "
          + ", ".join(f"{z:.4f}" for z in building.modal_damping_ratios()))
    for gm in ("far_field_long", "near_field_short"):
        t0, a0, _ = synthetic_ground_motion(gm)
        t = np.arange(0.0, t0[-1] + 1e-9, 1e-3)
        ag = np.interp(t, t0, a0)
        for iso_name in ("IUT_a", "IUT_b"):
            iso = PRESETS[iso_name]
            clock = time.perf_counter()
            ref = reference_response(building, iso, t, ag)
            ref_s = time.perf_counter() - clock
            print(f"{gm}, {iso_name}: reference {ref_s:.2f} s ({ref['substeps']} RK4 substeps per ms), peak base "
                  f"displacement {np.max(np.abs(ref['base_displacement_m'])) * 1e3:.1f} mm")
            for delay in (0, 1, 2, 5, 10, 20):
                mon = EnergyMonitor()
                clock = time.perf_counter()
                out = virtual_rths(building, iso, t, ag, delay, mon)
                run_s = time.perf_counter() - clock
                n = out["time_s"].size
                j = reference_criteria(out["base_displacement_m"], ref["base_displacement_m"][:n])
                tr = tracking_criteria(out["command_m"], out["measured_m"], 1e-3)
                j1 = round(tr["j1_delay_ms"], 3) + 0.0
                print(f"  delay {delay:2d} ms: J1 {j1:.3f} ms, J2 {tr['j2_rms_percent']:.2f} %, "
                      f"J4 {j['j4_rms_percent']:.2f} %, J5 {j['j5_peak_percent']:.2f} %, E_err "
                      f"{mon.added_energy_j:.1f} J ({100 * mon.ratio:.1f} % of {mon.reference_energy_j:.0f} J)"
                      + (f", TRIPPED at {mon.trip_time_s:.2f} s" if mon.tripped else "")
                      + f"; {1e6 * run_s / n:.1f} us per period")


DEMO_BUILDING = {"name": "demo_3_storey", "base_mass_kg": 4000.0, "masses_kg": [3000.0, 3000.0, 2750.0],
                 "stiffness_n_per_m": [8.0e6, 6.0e6, 4.0e6], "damping_ratio": 0.05}


if __name__ == "__main__":
    _main()
