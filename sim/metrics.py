"""Per-cycle isolator characterisation from a force-displacement record (EN 15129 / ISO 22762 / ASCE 7 practice).

For one cycle (see docs/metrics.md for the why of every choice):

- ``d_max_m``, ``d_min_m``: the largest and smallest displacement of the cycle (d+, d-).
- ``f_max_n``, ``f_min_n``: the forces **at** d+ and d- (F+, F-), as in ASCE 7; the peak forces are reported
  too, as ``f_peak_max_n`` / ``f_peak_min_n``. The two coincide for rate-independent loops with a hardening
  post-yield branch (bilinear, Bouc-Wen with k_d > 0); for a rate-dependent device only the forces at peak
  displacement give the secant stiffness (a spring-plus-damper gives K_eff = k exactly).
- ``k_eff_n_per_m`` = (F+ - F-) / (d+ - d-)  (= (|F+| + |F-|) / (|d+| + |d-|) for a loop around the origin).
- ``edc_j``: the loop area, the work  sum 1/2 (F_i + F_i+1)(d_i+1 - d_i)  around the closed polygon (the
  shoelace formula in the d-F plane, closing segment included); positive for a dissipating loop.
- ``xi_eff`` = (2 / pi) EDC / (K_eff (d+ - d-)^2)  (= EDC / (2 pi K_eff D^2) for a symmetric loop).
- ``qd_n``: the force intercept at the loop centre d_c = (d+ + d-)/2 (d = 0 for a centred loop):
  (F_up - F_down) / 2, i.e. the mean of |F| on the two branches, each from a local straight-line fit.
- ``kd_n_per_m``: the post-yield slope, the least-squares slope of F over d on both loading legs where
  |d - d_c| >= half the half-amplitude (the mean of the two legs).

A quantity that is undefined for a cycle (zero amplitude, a branch that never crosses d_c) is ``None``.

Cycles are split by the command's phase when the cycle start times are known, else at upward crossings of the
record's centre line with hysteresis (a Schmitt trigger whose band is set from the noise level), so noise
cannot create spurious cycles. Partial cycles (a record that starts or stops mid-cycle) are dropped; taper
cycles are complete cycles and are kept, with ``closure`` telling how far the loop is from closed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

METRIC_KEYS = ("d_max_m", "d_min_m", "f_max_n", "f_min_n", "k_eff_n_per_m", "edc_j", "xi_eff", "qd_n",
               "kd_n_per_m")
CYCLE_KEYS = ("cycle",) + METRIC_KEYS
# Extra keys of cycle_metrics beyond the contract (added, never renamed).
EXTRA_KEYS = ("f_peak_max_n", "f_peak_min_n", "closure", "t_start_s", "t_end_s", "i_start", "i_end")

QD_BAND = 0.05  # local fit for Q_d over |d - d_c| <= 5 % of the half-amplitude
KD_FROM = 0.5  # K_d fitted where |d - d_c| >= 50 % of the half-amplitude, on the loading legs
HYSTERESIS_FRACTION = 0.02  # Schmitt band at least 2 % of the record's robust half-amplitude
NOISE_FACTOR = 6.0  # ... and at least 6 sigma of the displacement noise
MIN_CYCLE_SAMPLES = 8


def _float_or_none(x) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _as_array(name: str, values) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a one-dimensional sequence of numbers")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values (NaN or inf) at sample {int(np.argmin(np.isfinite(arr)))}")
    return arr


def loop_area_j(displacement_m, force_n) -> float:
    """Area of the closed d-F polygon = the work  sum 1/2 (F_i + F_i+1)(d_i+1 - d_i)  including the closing
    segment (the shoelace formula); positive when the loop dissipates energy (clockwise in the d-F plane)."""
    d = np.asarray(displacement_m, dtype=float)
    f = np.asarray(force_n, dtype=float)
    if d.size < 3:
        return 0.0
    d_next = np.roll(d, -1)
    f_next = np.roll(f, -1)
    return float(0.5 * np.sum((f + f_next) * (d_next - d)))


def _legs(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices of the upward leg (d- -> d+) and the downward leg (d+ -> d-), taken cyclically."""
    n = d.size
    i_min, i_max = int(np.argmin(d)), int(np.argmax(d))
    up = np.arange(i_min, i_max + 1 if i_max >= i_min else i_max + 1 + n) % n
    down = np.arange(i_max, i_min + 1 if i_min >= i_max else i_min + 1 + n) % n
    return up, down


def _intercept(d: np.ndarray, f: np.ndarray, centre: float, band: float) -> float | None:
    """Force at d = centre on one leg: straight-line fit over |d - centre| <= band, else interpolation."""
    sel = np.abs(d - centre) <= band
    if np.count_nonzero(sel) >= 3 and np.ptp(d[sel]) > 0:
        return _line(d[sel] - centre, f[sel])[1]
    # too few samples in the band (coarse sampling): interpolate at the first crossing of the centre
    s = np.sign(d - centre)
    cross = np.nonzero(s[:-1] * s[1:] <= 0)[0]
    for j in cross:
        if d[j + 1] != d[j]:
            return float(f[j] + (f[j + 1] - f[j]) * (centre - d[j]) / (d[j + 1] - d[j]))
        return float(f[j])
    return None


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope and intercept of y = a x + b."""
    xm, ym = x.mean(), y.mean()
    dx = x - xm
    a = float(np.dot(dx, y - ym) / np.dot(dx, dx))
    return a, float(ym - a * xm)


def _slope(d: np.ndarray, f: np.ndarray) -> float | None:
    if d.size < 3 or np.ptp(d) <= 0:
        return None
    return _line(d, f)[0]


def loop_metrics(displacement_m, force_n) -> dict:
    """Characterisation quantities of one cycle (keys ``METRIC_KEYS`` plus peak forces and closure)."""
    d = _as_array("displacement_m", displacement_m)
    f = _as_array("force_n", force_n)
    if d.size != f.size:
        raise ValueError(f"displacement_m has {d.size} samples but force_n has {f.size}")
    if d.size < 3:
        raise ValueError(f"a cycle needs at least 3 samples, got {d.size}")
    i_max, i_min = int(np.argmax(d)), int(np.argmin(d))
    d_max, d_min = float(d[i_max]), float(d[i_min])
    f_plus, f_minus = float(f[i_max]), float(f[i_min])
    span = d_max - d_min
    edc = loop_area_j(d, f)
    k_eff = (f_plus - f_minus) / span if span > 0 else None
    xi = (2.0 / math.pi) * edc / (k_eff * span ** 2) if k_eff else None
    qd = kd = None
    if span > 0:
        centre, half = 0.5 * (d_max + d_min), 0.5 * span
        up, down = _legs(d)
        f_up = _intercept(d[up], f[up], centre, QD_BAND * half)
        f_down = _intercept(d[down], f[down], centre, QD_BAND * half)
        if f_up is not None and f_down is not None:
            qd = 0.5 * (f_up - f_down)
        up_sel = up[d[up] - centre >= KD_FROM * half]
        down_sel = down[centre - d[down] >= KD_FROM * half]
        slopes = [s for s in (_slope(d[up_sel], f[up_sel]), _slope(d[down_sel], f[down_sel])) if s is not None]
        kd = float(np.mean(slopes)) if slopes else None
    f_span = float(np.ptp(f))
    closure = (abs(d[-1] - d[0]) / span if span > 0 else 0.0) + (abs(f[-1] - f[0]) / f_span if f_span > 0 else 0.0)
    return {
        "d_max_m": d_max,
        "d_min_m": d_min,
        "f_max_n": f_plus,
        "f_min_n": f_minus,
        "k_eff_n_per_m": _float_or_none(k_eff),
        "edc_j": edc,
        "xi_eff": _float_or_none(xi),
        "qd_n": _float_or_none(qd),
        "kd_n_per_m": _float_or_none(kd),
        "f_peak_max_n": float(np.max(f)),
        "f_peak_min_n": float(np.min(f)),
        "closure": float(closure),
    }


def noise_sigma(x: np.ndarray) -> float:
    """Robust estimate of white measurement noise: MAD of the second difference / sqrt(6)."""
    if x.size < 5:
        return 0.0
    dd = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(dd - np.median(dd))) / math.sqrt(6.0))


def _check_time(t: np.ndarray, n: int) -> None:
    if t.size != n:
        raise ValueError(f"time_s has {t.size} samples but displacement_m has {n}")
    if n >= 2 and not np.all(np.diff(t) > 0):
        k = int(np.argmin(np.diff(t) > 0)) + 1
        raise ValueError(f"time_s must increase strictly; it does not at sample {k} (t = {t[k]:g} s)")


def split_cycles(time_s, displacement_m, cycle_starts_s: Sequence[float] | None = None,
                 end_s: float | None = None) -> list[tuple[int, int]]:
    """Sample ranges [i0, i1) of the complete cycles in a record.

    With ``cycle_starts_s`` (the command's phase: start time of every target cycle), cycle k runs from
    start k to start k+1; the last one ends at ``end_s`` if given, else one previous period later. Without
    them, cycles run between upward crossings of the record's centre line (median displacement) with a
    hysteresis band of max(2 % of the robust half-amplitude, 6 sigma of the noise); a record that begins or
    ends inside the band (on its way up) counts as beginning or ending on the centre line. Cycles the record
    does not cover completely (partial cycles) are dropped.
    """
    t = _as_array("time_s", time_s)
    n = len(displacement_m)
    _check_time(t, n)
    if n < MIN_CYCLE_SAMPLES:
        return []
    dt = float(np.median(np.diff(t)))
    if cycle_starts_s is None:  # by the displacement's own crossings: it must be finite
        d = _as_array("displacement_m", displacement_m)
    else:  # by time alone
        starts = np.sort(np.asarray(cycle_starts_s, dtype=float))
        if starts.size == 0:
            return []
        if end_s is None:
            end_s = starts[-1] + (starts[-1] - starts[-2]) if starts.size >= 2 else t[-1] + dt
        bounds = np.append(starts, end_s)
        idx = np.searchsorted(t, bounds - 0.5 * dt)
        out = []
        for k in range(starts.size):
            i0, i1 = int(idx[k]), int(idx[k + 1])
            covered = bounds[k] >= t[0] - 0.5 * dt and bounds[k + 1] <= t[-1] + 1.5 * dt
            if covered and i1 - i0 >= MIN_CYCLE_SAMPLES:
                out.append((i0, i1))
        return out
    centre = float(np.median(d))
    x = d - centre
    half = 0.5 * float(np.percentile(x, 99.0) - np.percentile(x, 1.0))
    if half <= 0:
        return []
    band = max(HYSTERESIS_FRACTION * half, NOISE_FACTOR * noise_sigma(d))
    state = np.where(x > band, 1, np.where(x < -band, -1, 0))
    idx = np.where(state != 0, np.arange(n), 0)
    np.maximum.accumulate(idx, out=idx)
    held = state[idx]  # last state outside the band (0 before the record first leaves it)
    rising = np.nonzero((held[1:] == 1) & (held[:-1] == -1))[0] + 1  # first sample above +band
    last_nonpos = np.maximum.accumulate(np.where(x <= 0, np.arange(n), -1))
    starts = [int(last_nonpos[k - 1]) + 1 for k in rising]
    exits = np.nonzero(state)[0]
    if exits.size and exits[0] > 0 and state[exits[0]] == 1 and (not starts or exits[0] < starts[0]):
        # the record begins inside the band and first leaves it upwards: a complete cycle from the start
        starts.insert(0, 0 if x[0] > 0 else int(last_nonpos[exits[0] - 1]) + 1)
    if starts and held[-1] == -1 and state[-1] == 0:
        # the record ends inside the band on the way up from below: the last cycle is complete to within the band
        starts.append(n if x[-1] <= 0 else min(int(last_nonpos[-1]) + 1, n))
    return [(a, b) for a, b in zip(starts[:-1], starts[1:], strict=False) if b - a >= MIN_CYCLE_SAMPLES]


def cycle_metrics(time_s, displacement_m, force_n, cycle_starts_s: Sequence[float] | None = None,
                  end_s: float | None = None, skip_bad: bool = False, measured=None) -> list[dict]:
    """``loop_metrics`` of every complete cycle, numbered from 1, with its time span and sample range.

    Each loop includes the first sample of the next cycle (when there is one) so that it closes. With
    ``skip_bad`` (and the cycle starts given) a cycle with non-finite samples gets ``{"error": ...}`` instead
    of its metrics, and the others are computed (a record whose sensor failed mid-test). ``measured``: True
    where a period's reading arrived (sim.measurement.measured_rows); the rows of lost periods, which hold an
    older reading, are left out of the loops (``i_start``/``i_end`` still index the whole record).
    """
    t = _as_array("time_s", time_s)
    if skip_bad and cycle_starts_s is not None:
        d, f = np.asarray(displacement_m, dtype=float), np.asarray(force_n, dtype=float)
    else:
        d, f = _as_array("displacement_m", displacement_m), _as_array("force_n", force_n)
    if f.size != d.size:
        raise ValueError(f"displacement_m has {d.size} samples but force_n has {f.size}")
    keep = np.ones(d.size, dtype=bool) if measured is None else np.asarray(measured, dtype=bool)
    if keep.shape != d.shape:
        raise ValueError(f"measured has {keep.size} rows but the record has {d.size}")
    out = []
    for number, (i0, i1) in enumerate(split_cycles(t, d, cycle_starts_s, end_s), start=1):
        j1 = min(i1 + 1, d.size)
        rows = i0 + np.flatnonzero(keep[i0:j1])
        try:
            m = loop_metrics(d[rows], f[rows])
        except ValueError as exc:
            if not skip_bad:
                raise
            m = {"error": str(exc)}
        out.append({"cycle": number, **m, "t_start_s": float(t[i0]),
                    "t_end_s": float(t[j1 - 1]), "i_start": i0, "i_end": i1})
    return out


def profile_cycle_starts_s(blocks) -> tuple[list[float], float]:
    """Start time of every target cycle of a profile (list of SineProfile) and the profile's end time."""
    starts, t0 = [], 0.0
    for b in blocks:
        period = 1.0 / b.frequency_hz
        starts.extend(t0 + k * period for k in range(int(b.cycles)))
        t0 += b.cycles * period
    return starts, t0


HEADLINE_KEYS = ("k_eff_n_per_m", "edc_j", "xi_eff", "qd_n", "kd_n_per_m")


def headline_figures(cycles: list[dict]) -> dict:
    """The test's headline figures: the mean of each of ``HEADLINE_KEYS`` over the steady cycles only.

    ``cycles`` are dicts with the metric keys and a ``phase`` (sim.tracking.cycle_phase); a cycle without a
    phase counts as steady (a record from before phases existed). Taper-in, taper-out and the ramp-out of a
    stop are at a lower amplitude (a stiffer, less damped loop: K_eff 1029 against 884 kN/m on one test) and
    are left out; so are cycles whose metrics could not be computed. Returns the means, the number of cycles
    they come from and the cycles left out by phase."""
    steady = [c for c in cycles if c.get("phase", "steady") == "steady"]
    means = {}
    for key in HEADLINE_KEYS:
        values = [c[key] for c in steady if isinstance(c.get(key), (int, float)) and math.isfinite(c[key])]
        if values:
            means[key] = float(np.mean(values))
    excluded: dict[str, int] = {}
    for c in cycles:
        phase = c.get("phase", "steady")
        if phase != "steady":
            excluded[phase] = excluded.get(phase, 0) + 1
    return {"means": means, "steady_cycles": len(steady), "excluded_cycles": excluded}


def scenario_cycle_metrics(samples, scenario) -> list[dict]:
    """Per-cycle metrics of an engine run (``sim.samples.Samples``), split by the command's phase; the rows of
    lost periods are left out of the loops."""
    from .measurement import measured_rows
    from .tracking import cycle_phases

    starts, end = profile_cycle_starts_s(scenario.profile)
    cycles = cycle_metrics(samples["time_s"], samples["displacement_m"], samples["force_n"], starts, end,
                           skip_bad=True, measured=measured_rows(samples["flags"]))
    phases = cycle_phases(scenario.profile)
    for c in cycles:
        c["phase"] = phases[c["cycle"] - 1] if c["cycle"] <= len(phases) else "steady"
    return cycles


# --- reading a force-displacement record from CSV (any machine's data; other columns ignored) ---

LOOP_COLUMNS = ("time_s", "displacement_m", "force_n")
MIN_RECORD_ROWS = 10


class RecordError(ValueError):
    """A CSV record is unreadable or malformed; the message names the file, row and column."""


def _empty_cell_converter(text):
    text = text.strip()
    return float(text) if text else math.nan


def _first_bad_cell(path, names: list[str], wanted: dict[str, int], allow_empty: set[str]) -> str:
    """Describe the first cell that is not a number (slow path, only when the fast parser failed)."""
    with open(path, newline="") as fh:
        fh.readline()
        for row, line in enumerate(fh, start=2):
            if not line.strip():
                continue
            cells = line.rstrip("\r\n").split(",")
            for name, j in wanted.items():
                if j >= len(cells):
                    return f"{path}: line {row} has {len(cells)} cells but column {name} is number {j + 1}"
                cell = cells[j].strip()
                if not cell and name in allow_empty:
                    continue
                try:
                    value = float(cell)
                except ValueError:
                    return f"{path}: line {row}, column {name}: {cell!r} is not a number"
                if not math.isfinite(value) and name not in allow_empty:
                    return f"{path}: line {row}, column {name}: {cell!r} is not a finite number"
    return f"{path}: could not parse the numbers"


def csv_header_names(line: str) -> list[str]:
    """The column names of a CSV header line (cells stripped of spaces, quotes and a byte-order mark; a cell
    labelled for its controller, ``as_hat: learned frequency (Hz)``, by its key: sim.records.column_key)."""
    from .records import column_key

    return [column_key(h.strip().strip('"').lstrip("\ufeff")) for h in line.rstrip("\r\n").split(",")]


def loadtxt_columns(path, usecols: Sequence[int], converters=None, comments: str | None = "#",
                    encoding: str | None = "utf-8") -> np.ndarray | None:
    """numpy's fast parse of the columns ``usecols`` (file column numbers) below the header row, as a 2-D float
    array; None when a cell does not parse (a careful reader then says which). ``converters`` are keyed by file
    column number, as numpy keys them."""
    try:
        return np.loadtxt(path, delimiter=",", skiprows=1, usecols=list(usecols), ndmin=2, dtype=float,
                          converters=converters, comments=comments, encoding=encoding)
    except (ValueError, IndexError):
        return None


def read_csv_columns(path, required: Sequence[str] = LOOP_COLUMNS, optional: Sequence[str] = (),
                     min_rows: int = MIN_RECORD_ROWS) -> dict[str, np.ndarray]:
    """Columns of a CSV file with a header row, by name; other columns are ignored.

    Required columns must be numbers in every row; optional columns may be absent (not returned) or have
    empty cells (NaN). ``time_s``, if required, must increase strictly. Raises RecordError with one line.
    """
    try:
        with open(path, newline="") as fh:
            header = fh.readline()
    except OSError as exc:
        raise RecordError(f"cannot read {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise RecordError(f"{path} is not a text CSV file") from None
    names = csv_header_names(header)
    missing = [c for c in required if c not in names]
    if missing:
        found = ", ".join(n for n in names if n) or "no header"
        raise RecordError(f"{path}: missing column(s) {', '.join(missing)}; required: {', '.join(required)} "
                          f"(found: {found[:200]})")
    wanted = {c: names.index(c) for c in required}
    wanted.update({c: names.index(c) for c in optional if c in names and c not in wanted})
    may_be_empty = {c for c in wanted if c not in required}
    # Fast path: optional columns empty in the first data row are taken as empty throughout (e.g. the
    # adaptive estimates of a PID run) and skipped; a cell that is still empty sends us to the slow path.
    with open(path, newline="") as fh:
        fh.readline()
        first = fh.readline().rstrip("\r\n").split(",")
    skipped = {c for c in may_be_empty if wanted[c] < len(first) and not first[wanted[c]].strip()}
    order = [c for c in wanted if c not in skipped]
    usecols = [wanted[c] for c in order]
    data = loadtxt_columns(path, usecols)
    if data is None:
        data = loadtxt_columns(path, usecols, {wanted[c]: _empty_cell_converter for c in order if c in may_be_empty})
    if data is None:
        raise RecordError(_first_bad_cell(path, names, wanted, may_be_empty)) from None
    if data.shape[0] < min_rows:
        raise RecordError(f"{path}: has {data.shape[0]} data rows; at least {min_rows} are needed")
    columns = {c: np.ascontiguousarray(data[:, k]) for k, c in enumerate(order)}
    columns.update({c: np.full(data.shape[0], np.nan) for c in skipped})
    for c in required:
        bad = ~np.isfinite(columns[c])
        if bad.any():
            row = int(np.argmax(bad)) + 2
            raise RecordError(f"{path}: line {row}, column {c}: not a finite number")
    if "time_s" in required:
        steps = np.diff(columns["time_s"])
        if not np.all(steps > 0):
            row = int(np.argmin(steps > 0)) + 3
            raise RecordError(f"{path}: time_s must increase strictly, but it does not at line {row} "
                              f"({columns['time_s'][row - 3]:g} s then {columns['time_s'][row - 2]:g} s)")
    return columns
