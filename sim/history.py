"""Displacement time histories for the rig: reading records, preparing targets, the envelope check.

Sources
- ``read_displacement_csv``: CSV ``time_s, displacement_m`` (a displacement history, e.g. from an analysis).
- ``read_acceleration_csv``: CSV ``time_s, acceleration_m_per_s2`` (or ``acceleration_g``, ``..._cm_per_s2``).
- ``read_at2``: the PEER NGA ``.AT2`` format (header lines, a line with NPTS and DT, values in g).
- ``read_ground_motion``: either, by the file's suffix.
- ``isolation_displacement``: the isolator's displacement demand under a ground acceleration record, through
  a base-isolated rigid mass on the Bouc-Wen isolator of eq. (4).

CSV files: ``#`` comments and blank lines are skipped; an optional header row names the columns (the time
column ``time_s``/``time``/``t``, the value column by its name, else the first two columns); separators
``,``, ``;`` (then ``,`` is a decimal comma), tab or spaces. Records must be uniformly sampled. Every refusal
is one ``HistoryError`` (a ValueError, and a ``FieldError`` with ``field``, ``value``, ``limit``) whose
message names the file, the line and what is wrong; ``path`` and ``line`` are attributes too.

Targets: ``prepare_history`` resamples a history to the control period with a cubic spline, scales it,
tapers it in and out with raised cosines and gives r, r', r'' at the control period (``HistoryTarget``);
``history_envelope_problem`` refuses what the rig cannot do, naming the sample (time in s) and the limit.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import FieldError
from .isolator import Isolator
from .profiles import ProfileError
from .rig import BAR_PA, LITRE_PER_MIN_M3_S, RigParameters
from .structure import G_M_PER_S2, simulate_isolated_system

MIN_ROWS = 10
MAX_ROWS = 5_000_000
MAX_DURATION_S = 3600.0
STEP_TOLERANCE = 0.01  # a time step may differ from the record's step by 1 % (rounding in the file)
PLAUSIBLE_PGA_G = (0.005, 3.0)  # peak ground accelerations of records worth a test; the largest recorded ~3 g
UNIT_TO_M_PER_S2 = {"m/s2": 1.0, "g": G_M_PER_S2, "cm/s2": 0.01}
REST_TOLERANCE_M = 1.0e-5  # an untapered end must be at rest within 10 um ...
REST_TOLERANCE_M_PER_S = 1.0e-4  # ... and 0.1 mm/s
RESAMPLING = "cubic spline (not-a-knot) through the record's samples; r', r'' its derivatives"
TIME_NAMES = ("time_s", "time", "t", "t_s", "time_sec")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[EeDd][-+]?\d+)?")


class HistoryError(FieldError):
    """A record or a history refused: the message names the file, the line and what is wrong.

    ``field`` is ``"history"`` (or the argument at fault), ``path`` the file (or None) and ``line`` the
    1-based line of the file (or None)."""

    def __init__(self, message: str, *, path=None, line: int | None = None, field: str = "history", value=None,
                 limit: str = ""):
        super().__init__(field, value, limit, message)
        self.path = None if path is None else str(path)
        self.line = line


# ---- reading ---------------------------------------------------------------------------------------------
def _read_lines(path) -> list[str]:
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise HistoryError(f"cannot read {path}: {exc.strerror}", path=path, value=str(path),
                           limit="a readable file") from None
    return text.lstrip("\ufeff").splitlines()


def _split(line: str) -> list[str]:
    if ";" in line:
        return [c.strip().replace(",", ".") for c in line.split(";")]
    if "," in line:
        return [c.strip() for c in line.split(",")]
    return line.split()


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _read_csv(path, value_names: tuple[str, ...], what: str):
    """(time, values, line numbers, value column header or None) of a two-column CSV."""
    lines = _read_lines(path)
    header = None
    rows: list[tuple[int, list[str]]] = []
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = _split(line)
        if header is None and not rows and not all(_is_number(c) for c in cells if c):
            header = (number, [c.strip().strip('"').strip("'").lower() for c in cells])
            continue
        rows.append((number, cells))
        if len(rows) > MAX_ROWS:
            raise HistoryError(f"{path}: more than {MAX_ROWS} data rows", path=path, line=number,
                               value=len(rows), limit=f"at most {MAX_ROWS} rows")
    it, iv, value_header = 0, 1, None
    if header is not None:
        names = header[1]
        if len(names) < 2:
            raise HistoryError(f"{path}, line {header[0]}: the header has {len(names)} column(s); expected "
                               f"time_s and {what}", path=path, line=header[0], value=names,
                               limit="two columns")
        it = next((i for i, n in enumerate(names) if n in TIME_NAMES), 0)
        iv = next((i for i, n in enumerate(names) if i != it and n.startswith(value_names)),
                  1 if it == 0 else 0)
        value_header = names[iv]
    if len(rows) < MIN_ROWS:
        raise HistoryError(f"{path}: only {len(rows)} data row(s); a history needs at least {MIN_ROWS}",
                           path=path, line=rows[-1][0] if rows else None, value=len(rows),
                           limit=f">= {MIN_ROWS} rows")
    t = np.empty(len(rows))
    y = np.empty(len(rows))
    numbers = np.empty(len(rows), dtype=np.int64)
    need = max(it, iv) + 1
    column = {it: "time_s", iv: what}
    for k, (number, cells) in enumerate(rows):
        if len(cells) < need or any(not cells[i] for i in (it, iv)):
            raise HistoryError(f"{path}, line {number}: expected {need} values (time_s and {what}), found "
                               f"{sum(1 for c in cells if c)}: a missing value", path=path, line=number,
                               value=", ".join(cells), limit=f"{need} columns")
        for i, target in ((it, t), (iv, y)):
            try:
                target[k] = float(cells[i])
            except ValueError:
                raise HistoryError(f"{path}, line {number}: {column[i]} = {cells[i]!r} is not a number", path=path,
                                   line=number, value=cells[i], limit="a number") from None
        numbers[k] = number
    return t, y, numbers, value_header


def _check_values(path, t, y, numbers, what: str, unit: str, step_tolerance: float, *, inline: bool = False,
                  fields: tuple[str, str] = ("history", "history")) -> None:
    """Finite values, increasing and uniformly sampled time: else a HistoryError naming the line (or, for arrays
    given ``inline``, the sample: 0-based index into the arrays; ``fields`` then names the time and value
    arrays in the error's ``field``)."""
    def at(k: int) -> str:
        return f"{path}, sample {k}" if inline else f"{path}, line {numbers[k]}"

    def line(k: int):
        return None if inline else int(numbers[k])

    for arr, name, u, fld in ((t, "time_s", "s", fields[0]), (y, what, unit, fields[1])):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            k = bad[0]
            raise HistoryError(f"{at(k)}: {name} = {float(arr[k])!r} is not a finite number", path=path, line=line(k),
                               field=fld, value=float(arr[k]), limit=f"a finite number ({u})")
    steps = np.diff(t)
    back = np.flatnonzero(steps <= 0.0)
    if back.size:
        k = back[0] + 1
        raise HistoryError(f"{at(k)}: time {t[k]:g} s is not after the previous {'sample' if inline else 'row'}'s "
                           f"{t[k - 1]:g} s; time must increase", path=path, line=line(k), field=fields[0],
                           value=float(t[k]), limit=f"> {t[k - 1]:g} s")
    dt = float(np.median(steps))
    off = np.flatnonzero(np.abs(steps - dt) > step_tolerance * dt)
    if off.size:
        k = off[0] + 1
        kind = ("a gap (missing " + ("samples" if inline else "rows") + "?)") if steps[k - 1] > 1.5 * dt \
            else "a non-uniform step"
        raise HistoryError(f"{at(k)}: time steps from {t[k - 1]:g} s to {t[k]:g} s, a step of "
                           f"{steps[k - 1]:.6g} s where the record's step is {dt:.6g} s: {kind}; records must be "
                           f"uniformly sampled (within {100 * step_tolerance:g} %)", path=path,
                           line=line(k), field=fields[0], value=float(steps[k - 1]), limit=f"step {dt:.6g} s")
    if t[-1] - t[0] > MAX_DURATION_S:
        raise HistoryError(f"{path}: the record lasts {t[-1] - t[0]:g} s, longer than {MAX_DURATION_S:g} s",
                           path=path, line=line(t.size - 1), field=fields[0], value=float(t[-1] - t[0]),
                           limit=f"<= {MAX_DURATION_S:g} s")


def check_inline_record(time_s, values, *, name: str, what: str, unit: str, fields: tuple[str, str],
                        max_samples: int = MAX_ROWS, step_tolerance: float = STEP_TOLERANCE
                        ) -> tuple[np.ndarray, np.ndarray]:
    """A record given as two arrays (e.g. in an API request): the checks of a file (``_check_values``: finite
    values, increasing and uniform time, at most MAX_DURATION_S), with the sample named by its 0-based index
    instead of a line; ``name`` (e.g. "profile.ground_motion") starts the messages and ``fields`` (time, values)
    are the errors' ``field``. Returns float64 arrays."""
    arrays = []
    for raw, fld in ((time_s, fields[0]), (values, fields[1])):
        if not isinstance(raw, (list, tuple, np.ndarray)):
            raise HistoryError(f"{fld} must be an array of numbers (got {type(raw).__name__})", field=fld,
                               value=None, limit="an array of numbers")
        if len(raw) > max_samples:
            raise HistoryError(f"{fld} has {len(raw)} samples; at most {max_samples} are accepted inline",
                               field=fld, value=len(raw), limit=f"at most {max_samples} samples")
        missing = next((k for k, v in enumerate(raw) if v is None or isinstance(v, (bool, str))), None)
        if missing is not None:
            raise HistoryError(f"{name}, sample {missing}: {fld.rsplit('.', 1)[-1]} = {raw[missing]!r} is not a "
                               "number (a missing value?)", field=fld, value=raw[missing], limit="a number")
        arrays.append(np.asarray(raw, dtype=np.float64))
    t, y = arrays
    if t.ndim != 1 or y.ndim != 1 or t.size != y.size:
        raise HistoryError(f"{name}: {fields[0]} has {t.size} samples but {fields[1]} has {y.size}; give one value "
                           "per time", field=fields[1], value=y.size, limit=f"{t.size} samples, as {fields[0]}")
    if t.size < MIN_ROWS:
        raise HistoryError(f"{name}: only {t.size} sample(s); a record needs at least {MIN_ROWS}", field=fields[0],
                           value=t.size, limit=f">= {MIN_ROWS} samples")
    _check_values(name, t, y, np.arange(t.size), what, unit, step_tolerance, inline=True, fields=fields)
    return t, y


def check_acceleration_units(acc, units: str, how: str, *, name: str, field: str) -> None:
    """The unit check of a ground acceleration record (``_check_units``) for values already read (in
    ``units``): a peak outside 0.005-3 g is refused, saying what was assumed (``how``) and which unit would be
    plausible; the error's ``field`` is ``field``."""
    if units not in UNIT_TO_M_PER_S2:
        raise HistoryError(f"{name}: units = {units!r}; use one of " + ", ".join(map(repr, UNIT_TO_M_PER_S2)),
                           field=field, value=units, limit=", ".join(UNIT_TO_M_PER_S2))
    try:
        _check_units(name, float(np.max(np.abs(acc))), units, how)
    except HistoryError as exc:  # said for an API form: set units, or check_units to false
        text = str(exc).replace("read it with units=", "set units to ").replace(" or units=", " or ")
        text = text.replace("pass check_units=False", "set check_units to false")
        raise HistoryError(text, field=field, value=exc.value, limit=exc.limit) from None


def read_displacement_csv(path, step_tolerance: float = STEP_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, displacement_m) from a CSV ``time_s, displacement_m`` (s, m); uniformly sampled."""
    t, y, numbers, _ = _read_csv(path, ("displacement", "disp", "d_", "x_", "r_"), "displacement_m")
    _check_values(path, t, y, numbers, "displacement_m", "m", step_tolerance)
    return t, y


def _header_unit(name: str | None) -> str | None:
    if not name:
        return None
    n = name.replace(" ", "")
    if n.endswith(("_m_per_s2", "[m/s2]", "(m/s2)", "[m/s^2]", "(m/s^2)", "_mps2", "m/s2", "m/s^2")) \
            and "cm" not in n:
        return "m/s2"
    if n.endswith(("_cm_per_s2", "[cm/s2]", "(cm/s2)", "[cm/s^2]", "(cm/s^2)", "_gal", "[gal]", "(gal)")):
        return "cm/s2"
    if n.endswith(("_g", "[g]", "(g)")):
        return "g"
    return None


def _check_units(path, peak: float, units: str, how: str) -> None:
    """Refuse a record whose peak is implausible in the assumed unit; say what was assumed and the other
    choices. ``peak`` in the record's own numbers."""
    lo, hi = PLAUSIBLE_PGA_G
    pga_g = peak * UNIT_TO_M_PER_S2[units] / G_M_PER_S2
    if lo <= pga_g <= hi:
        return
    alternatives = []
    for other, factor in UNIT_TO_M_PER_S2.items():
        other_g = peak * factor / G_M_PER_S2
        if other != units and lo <= other_g <= hi:
            alternatives.append(f"units='{other}' (a peak of {other_g:.3g} g)")
    problem = "beyond any recorded ground motion" if pga_g > hi else "weaker than any record worth a test"
    advice = ("if the record is in another unit, read it with " + " or ".join(alternatives)) if alternatives \
        else "check the file"
    raise HistoryError(f"{path}: the record's peak {peak:.4g} read as {units} ({how}) is {pga_g:.3g} g, {problem} "
                       f"(plausible: {lo:g} to {hi:g} g); {advice}, or pass check_units=False to accept it",
                       path=path, field="units", value=units, limit=f"a peak of {lo:g} to {hi:g} g")


def _units_argument(path, units: str | None) -> None:
    if units is not None and units not in UNIT_TO_M_PER_S2:
        raise HistoryError(f"{path}: units = {units!r}; use one of " + ", ".join(map(repr, UNIT_TO_M_PER_S2)),
                           path=path, field="units", value=units, limit=", ".join(UNIT_TO_M_PER_S2))


def read_acceleration_csv(path, units: str | None = None, check_units: bool = True,
                          step_tolerance: float = STEP_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, acceleration_m_per_s2) from a CSV ``time_s, acceleration_...`` (s; returned in m/s2).

    ``units``: "m/s2", "g" or "cm/s2" of the file's values; None takes the header's (``acceleration_g``,
    ``acceleration_m_per_s2``, ``acceleration_cm_per_s2``, ...) and else assumes m/s2. A header naming another
    unit than ``units`` is refused. With ``check_units`` a peak outside 0.005-3 g in the assumed unit is
    refused, the message saying what was assumed and which unit would be plausible.
    """
    _units_argument(path, units)
    t, y, numbers, header = _read_csv(path, ("acc", "a_", "ag"), "acceleration")
    _check_values(path, t, y, numbers, "acceleration", units or "m/s2", step_tolerance)
    declared = _header_unit(header)
    if units is not None and declared is not None and declared != units:
        raise HistoryError(f"{path}: the header names the column {header!r} ({declared}) but units='{units}' was "
                           f"given; drop units or rename the column", path=path, field="units", value=units,
                           limit=f"the header's unit {declared}")
    chosen = units or declared or "m/s2"
    how = "given" if units else ("from the header" if declared else "assumed: no unit in the header")
    if check_units:
        _check_units(path, float(np.max(np.abs(y))), chosen, how)
    return t, y * UNIT_TO_M_PER_S2[chosen]


@dataclass(frozen=True)
class At2Record:
    """A PEER NGA ``.AT2`` record as read: the values in the file's unit (``units``: g, or cm/s2 when the header
    says CM/S), how that unit was known, and the header lines above the NPTS, DT line (title, event, ...)."""

    time_s: np.ndarray
    values: np.ndarray
    units: str
    units_how: str
    header: tuple[str, ...]
    dt_s: float

    @property
    def acceleration_m_per_s2(self) -> np.ndarray:
        return self.values * UNIT_TO_M_PER_S2[self.units]


def read_at2(path, check_units: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, acceleration_m_per_s2) from a PEER NGA ``.AT2`` file (``parse_at2`` on its text)."""
    record = parse_at2(_read_lines(path), path, check_units)
    return record.time_s, record.acceleration_m_per_s2


def parse_at2(lines: list[str] | str, path="record.AT2", check_units: bool = True) -> At2Record:
    """A PEER NGA ``.AT2`` record from its text (or its lines); ``path`` names it in the messages.

    Format: header lines (title, event, "ACCELERATION TIME HISTORY IN UNITS OF G"), a line with NPTS and
    DT (``NPTS=  3900, DT=   .0050 SEC``; also the older ``3900  .0050  NPTS, DT``, any order or
    separator), then NPTS values in g, several per line (Fortran E or F fields, D exponents accepted). The
    line with NPTS and DT is searched in the first 10 lines. Values are in g unless the header says CM/S
    (then cm/s2). Extra trailing values are accepted only if zero (padding of the last line).
    """
    if isinstance(lines, str):
        lines = lines.lstrip("\ufeff").splitlines()
    head = None
    for number, line in enumerate(lines[:10], start=1):
        up = line.upper()
        m_n = re.search(r"NPTS\s*[=:]?\s*(\d+)", up)
        m_dt = re.search(r"\bDT\s*[=:]?\s*(" + _NUMBER.pattern + ")", up)
        if m_n and m_dt:
            head = (number, int(m_n.group(1)), float(m_dt.group(1).replace("D", "E")))
            break
        tokens = _NUMBER.findall(up)
        if "NPTS" in up and len(tokens) >= 2 and re.fullmatch(r"\d+", tokens[0]):  # 3900 .0050 NPTS, DT
            head = (number, int(tokens[0]), float(tokens[1].replace("D", "E")))
            break
    if head is None:
        raise HistoryError(f"{path}: no line with NPTS and DT in the first 10 lines; not a PEER .AT2 file "
                           f"(expected e.g. 'NPTS=  3900, DT=   .0050 SEC' after the header)", path=path,
                           value=None, limit="an NPTS, DT line")
    head_line, npts, dt = head
    if not (MIN_ROWS <= npts <= MAX_ROWS):
        raise HistoryError(f"{path}, line {head_line}: NPTS = {npts}; a record needs {MIN_ROWS} to {MAX_ROWS} "
                           f"values", path=path, line=head_line, field="NPTS", value=npts,
                           limit=f"[{MIN_ROWS}, {MAX_ROWS}]")
    if not (0.0 < dt <= 1.0):
        raise HistoryError(f"{path}, line {head_line}: DT = {dt:g} s must be in (0, 1] s", path=path,
                           line=head_line, field="DT", value=dt, limit="(0, 1] s")
    if npts * dt > MAX_DURATION_S:
        raise HistoryError(f"{path}, line {head_line}: NPTS x DT = {npts * dt:g} s, longer than "
                           f"{MAX_DURATION_S:g} s", path=path, line=head_line, value=npts * dt,
                           limit=f"<= {MAX_DURATION_S:g} s")
    header_text = " ".join(lines[:head_line]).upper()
    units, how = "g", "the .AT2 convention"
    if re.search(r"CM\s*/\s*S", header_text):
        units, how = "cm/s2", "the header"
    elif re.search(r"UNITS OF G\b|\bIN G\b|\(G\)", header_text):
        how = "the header"
    values = np.empty(npts)
    count = 0
    extra_nonzero = None
    last_line = head_line
    for number, line in enumerate(lines[head_line:], start=head_line + 1):
        if not line.strip():
            continue
        tokens = _NUMBER.findall(line)
        rest = _NUMBER.sub(" ", line).replace(",", " ").strip()
        if rest:
            bad = next((tok for tok in line.replace(",", " ").split() if not _NUMBER.fullmatch(tok)), rest)
            raise HistoryError(f"{path}, line {number}: {bad!r} is not a number", path=path, line=number,
                               value=bad, limit="numbers in g")
        for tok in tokens:
            v = float(tok.replace("D", "E").replace("d", "e"))
            if count < npts:
                values[count] = v
            elif v != 0.0 and extra_nonzero is None:
                extra_nonzero = number
            count += 1
        last_line = number
    if count < npts:
        raise HistoryError(f"{path}, line {last_line}: the file ends after {count} values but NPTS = {npts} "
                           f"(line {head_line}): a truncated record", path=path, line=last_line, value=count,
                           limit=f"NPTS = {npts} values")
    if extra_nonzero is not None:
        raise HistoryError(f"{path}, line {extra_nonzero}: more than NPTS = {npts} values (line {head_line}); "
                           f"{count} found", path=path, line=extra_nonzero, value=count,
                           limit=f"NPTS = {npts} values")
    if check_units:
        _check_units(path, float(np.max(np.abs(values))), units, how)
    return At2Record(time_s=np.arange(npts) * dt, values=values, units=units, units_how=how,
                     header=tuple(line.strip() for line in lines[:head_line - 1] if line.strip()), dt_s=dt)


def read_ground_motion(path, units: str | None = None, check_units: bool = True):
    """(time_s, acceleration_m_per_s2) from ``.AT2`` (by suffix, any case) or CSV (``read_acceleration_csv``)."""
    if str(path).lower().endswith(".at2"):
        if units not in (None, "g"):
            _units_argument(path, units)
            raise HistoryError(f"{path}: a PEER .AT2 file is in g; units='{units}' does not apply", path=path,
                               field="units", value=units, limit="g")
        return read_at2(path, check_units)
    return read_acceleration_csv(path, units, check_units)


# ---- the isolator's displacement demand -------------------------------------------------------------------
def isolation_displacement(time_s, ground_acc_m_per_s2, isolator: Isolator, mass_kg: float,
                           substeps: int | None = None) -> np.ndarray:
    """The isolator's displacement demand (m, relative to the ground) under a ground acceleration (m/s2).

    Model: a rigid mass ``mass_kg`` (the isolated superstructure; vertical load / g is the natural choice) on
    the isolator, eq. (4), no other damping than the isolator's hysteresis:

        m d'' + k_d d + k_w w = -m a_g(t),    w' = rho d' {1 + |w|^n sigma [1 - sgn(d' w) - 1/sigma]}

    from rest, a_g linear between samples; classical RK4 with a substep of at most 0.1 ms and 0.05/omega_0
    (omega_0^2 = (k_d + k_w rho max(1, 2 sigma)) / m, the stiffest tangent), as
    ``sim.structure.simulate_isolated_system``. ``time_s`` must be uniform; the result is on the same grid.
    """
    if isinstance(mass_kg, bool) or not isinstance(mass_kg, (int, float)) or not (math.isfinite(mass_kg)
                                                                                    and mass_kg > 0):
        raise HistoryError(f"mass_kg = {mass_kg!r} must be a positive number of kg", field="mass_kg",
                           value=mass_kg, limit="> 0 kg")
    one = np.ones(1)
    sol = simulate_isolated_system(one * float(mass_kg), np.zeros((1, 1)), np.zeros((1, 1)), isolator, time_s,
                                   ground_acc_m_per_s2, substeps)
    return sol["u_m"][:, 0].copy()


# ---- targets ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class HistoryTarget:
    """A displacement target at the control period: r (m), r' (m/s), r'' (m/s2) for t_k = k dt_s.

    Arrays are float64 and C-contiguous; r and r' are zero at both ends (tapered). ``to_dict`` gives the
    metadata only."""

    r_m: np.ndarray = field(repr=False)
    r_dot_m_per_s: np.ndarray = field(repr=False)
    r_ddot_m_per_s2: np.ndarray = field(repr=False)
    dt_s: float
    source: str
    scale: float
    taper_in_s: float
    taper_out_s: float
    duration_s: float
    source_dt_s: float
    source_samples: int
    lowpass_hz: float | None = None
    resampling: str = RESAMPLING
    #: the scale of the ground acceleration the history was computed from (None: ``scale`` is the history's)
    ground_motion_scale: float | None = None

    @property
    def n_samples(self) -> int:
        return self.r_m.size

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.r_m.size) * self.dt_s

    def to_dict(self) -> dict:
        return {"kind": "history", "source": self.source, "scale": self.scale, "dt_s": self.dt_s,
                "duration_s": self.duration_s, "samples": self.n_samples, "taper_in_s": self.taper_in_s,
                "taper_out_s": self.taper_out_s, "source_dt_s": self.source_dt_s,
                "source_samples": self.source_samples, "lowpass_hz": self.lowpass_hz,
                "resampling": self.resampling, "ground_motion_scale": self.ground_motion_scale,
                "peak_displacement_m": float(np.max(np.abs(self.r_m))),
                "peak_velocity_m_per_s": float(np.max(np.abs(self.r_dot_m_per_s))),
                "peak_acceleration_m_per_s2": float(np.max(np.abs(self.r_ddot_m_per_s2)))}


def _raised_cosine(t: np.ndarray, width: float):
    """e = (1 - cos(pi t / T)) / 2 on [0, T], 1 beyond; with e' and e''."""
    e = np.ones_like(t)
    de = np.zeros_like(t)
    dde = np.zeros_like(t)
    if width > 0.0:
        inside = t < width
        x = np.pi * np.clip(t[inside], 0.0, None) / width
        e[inside] = 0.5 * (1.0 - np.cos(x))
        de[inside] = 0.5 * np.pi / width * np.sin(x)
        dde[inside] = 0.5 * (np.pi / width) ** 2 * np.cos(x)
    return e, de, dde


def _argument(name: str, value, lo: float, hi: float, unit: str, lo_open: bool = False) -> float:
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) \
        and (lo < value if lo_open else lo <= value) and value <= hi
    if not ok:
        bracket = "(" if lo_open else "["
        raise HistoryError(f"{name} = {value!r} must be a number in {bracket}{lo:g}, {hi:g}] {unit}", field=name,
                           value=value, limit=f"{bracket}{lo:g}, {hi:g}] {unit}")
    return float(value)


def prepare_history(time_s, displacement_m, dt_s: float = 1.0e-3, scale: float = 1.0, taper_in_s: float = 1.0,
                    taper_out_s: float = 1.0, *, source: str = "", lowpass_hz: float | None = None,
                    require_rest: bool = True) -> HistoryTarget:
    """A displacement history made into a rig target at the control period ``dt_s``.

    1. Resampling: a not-a-knot cubic spline s(t) through the samples (C2: smooth r, r', r''), evaluated at
       t_k = k dt_s from the record's first time (shifted to 0) up to its last. With ``lowpass_hz`` the
       resampled r is then filtered by a zero-phase 4th-order Butterworth (sosfiltfilt) and a new spline
       through the filtered samples gives the derivatives.
    2. Scale: x = scale s.
    3. Tapers: r = e(t) x with e = e_in e_out, raised cosines (1 - cos(pi t / T_in)) / 2 over the first
       ``taper_in_s`` and mirrored over the last ``taper_out_s``: r = r' = 0 at both ends.
       r' = e' x + e x', r'' = e'' x + 2 e' x' + e x'' (exact derivatives of the tapered spline).
       A taper of 0 s is accepted only where the history is already at rest (|r| <= 10 um, |r'| <= 0.1 mm/s),
       unless ``require_rest`` is False.
    """
    t = np.asarray(time_s, dtype=np.float64)
    x = np.asarray(displacement_m, dtype=np.float64)
    if t.ndim != 1 or x.shape != t.shape:
        raise HistoryError(f"time_s and displacement_m must be 1-D of the same length (got {t.shape} and "
                           f"{x.shape})", value=None, limit="same length")
    if t.size < MIN_ROWS:
        raise HistoryError(f"the history has {t.size} samples; at least {MIN_ROWS} are needed", value=t.size,
                           limit=f">= {MIN_ROWS} samples")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
        k = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(x)))[0])
        raise HistoryError(f"sample {k} (row {k + 1}) is not finite: time {float(t[k])!r} s, displacement "
                           f"{float(x[k])!r} m", value=None, limit="finite numbers")
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise HistoryError(f"sample {k} (row {k + 1}): time {t[k]:g} s is not after {t[k - 1]:g} s", value=t[k],
                           limit="increasing time")
    dt = _argument("dt_s", dt_s, 1.0e-4, 0.1, "s")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale == 0 \
            or abs(scale) > 100:
        raise HistoryError(f"scale = {scale!r} must be a non-zero number with |scale| <= 100", field="scale",
                           value=scale, limit="0 < |scale| <= 100")
    duration = float(t[-1] - t[0])
    if duration > MAX_DURATION_S:
        raise HistoryError(f"the history lasts {duration:g} s, longer than {MAX_DURATION_S:g} s", value=duration,
                           limit=f"<= {MAX_DURATION_S:g} s")
    t_in = _argument("taper_in_s", taper_in_s, 0.0, duration, "s")
    t_out = _argument("taper_out_s", taper_out_s, 0.0, duration, "s")
    n = int(math.floor(duration / dt + 1e-9)) + 1
    if n < MIN_ROWS:
        raise HistoryError(f"the history lasts {duration:g} s: {n} samples at dt_s = {dt:g} s, fewer than "
                           f"{MIN_ROWS}", value=duration, limit=f">= {MIN_ROWS} samples")
    end = (n - 1) * dt
    if t_in + t_out > end:
        raise HistoryError(f"taper_in_s + taper_out_s = {t_in + t_out:g} s is longer than the history "
                           f"({end:g} s)", field="taper_in_s", value=t_in, limit=f"taper_in_s + taper_out_s <= "
                           f"{end:g} s")
    from scipy.interpolate import CubicSpline

    tk = np.arange(n) * dt
    spline = CubicSpline(t - t[0], x, bc_type="not-a-knot")
    if lowpass_hz is not None:
        from scipy.signal import butter, sosfiltfilt

        fc = _argument("lowpass_hz", lowpass_hz, 0.0, 0.45 / dt, "Hz", lo_open=True)
        if n <= 30:
            raise HistoryError("lowpass_hz needs a history of more than 30 samples", field="lowpass_hz",
                               value=lowpass_hz, limit="> 30 samples")
        filtered = sosfiltfilt(butter(4, fc, fs=1.0 / dt, output="sos"), spline(tk))
        spline = CubicSpline(tk, filtered, bc_type="not-a-knot")
    s = float(scale)
    xk, vk, ak = s * spline(tk), s * spline(tk, 1), s * spline(tk, 2)
    e_in, de_in, dde_in = _raised_cosine(tk, t_in)
    e_out, de_out, dde_out = _raised_cosine(end - tk, t_out)
    de_out, dde_out = -de_out, dde_out  # d/dt of a function of (end - t)
    e = e_in * e_out
    de = de_in * e_out + e_in * de_out
    dde = dde_in * e_out + 2.0 * de_in * de_out + e_in * dde_out
    r = np.ascontiguousarray(e * xk)
    r_dot = np.ascontiguousarray(de * xk + e * vk)
    r_ddot = np.ascontiguousarray(dde * xk + 2.0 * de * vk + e * ak)
    if require_rest:
        for where, k, width, arg in (("starts", 0, t_in, "taper_in_s"), ("ends", n - 1, t_out, "taper_out_s")):
            if width == 0.0 and (abs(r[k]) > REST_TOLERANCE_M or abs(r_dot[k]) > REST_TOLERANCE_M_PER_S):
                raise HistoryError(f"the history {where} away from rest (r = {r[k] * 1e3:.4g} mm, r' = "
                                   f"{r_dot[k] * 1e3:.4g} mm/s) with {arg} = 0: a step the rig cannot follow; "
                                   f"set {arg} > 0", field=arg, value=0.0, limit="> 0 s unless at rest")
    if not source:
        source = "history"
    return HistoryTarget(r, r_dot, r_ddot, dt, str(source), s, t_in, t_out, end, float(np.median(np.diff(t))),
                         int(t.size), None if lowpass_hz is None else float(lowpass_hz))


# ---- envelope --------------------------------------------------------------------------------------------
def _refusal(target: HistoryTarget, k: int, value: float, limit: str, message: str) -> ProfileError:
    err = ProfileError("history", float(value), limit, f"history sample {k} at t = {k * target.dt_s:.3f} s: "
                       + message)
    err.time_s = k * target.dt_s
    err.sample = int(k)
    return err


def _mm(x_m: float) -> str:
    """A displacement in mm, to 0.01 mm (in exponent form beyond a metre: a history in the wrong unit)."""
    x = float(x_m) * 1e3
    return f"{x:.2f}" if abs(x) < 1e4 else f"{x:.4g}"


def history_envelope_problem(target: HistoryTarget, rig: RigParameters, isolator: Isolator,
                             supply_pa: float) -> ProfileError | None:
    """The first envelope limit a history breaks, as a ProfileError naming the sample (time in s), or None.

    Per sample k, in this order (the same limits as the sine check, sim.profiles.envelope_problem):
    - stroke: |r| <= stroke_m;
    - velocity: A_p |r'| <= Q_pump (pump flow);
    - force (and acceleration): k_d |r| + k_w + (mu N + F_c) + sigma |r'| + m |r''| <= A_p P_s, the isolator's
      largest force at that displacement, friction at the test's vertical load, viscous and inertial
      forces; <= A_B P_s where the actuator pulls (k_d r + m r'' + sgn(r') (...) < 0) on a single-rod actuator.
      This is also the acceleration limit: the rig can give the table at most
      (A_p P_s - the other terms) / m; no separate acceleration bound is applied;
    - valve: A_p |r'| <= 90 % of K_q (k_ep 10 V - dead zone) sqrt(s P_s - P_L) (s = A_B / A_A towards -y on a
      single-rod actuator, sim.rig.supply_share), with the load pressure in the
      direction of motion P_L = sgn(r') (k_d r + m r'' + sigma r') / A_p + (k_w + mu N + F_c) / A_p.
    ``rig`` carries the test's vertical load; check the supply itself with sim.profiles.check_supply. The
    error's ``field`` is "history", ``value`` the offending sample's quantity, ``limit`` the bound;
    ``time_s`` and ``sample`` are set on it.
    """
    r, v, a = target.r_m, target.r_dot_m_per_s, target.r_ddot_m_per_s2
    gm_scale = target.ground_motion_scale
    scale_note = f" (scale {target.scale:g})" if gm_scale is None else f" (ground-motion scale {gm_scale:g})"

    def fits(ratio: float, what: str = "") -> str:  # what would fit, said in the scale the user chose
        if gm_scale is None:
            return f"a scale of at most {ratio * abs(target.scale):.3g} fits{what}"
        return (f"the history would fit{what} at {ratio:.3g} times its size; lower the ground-motion scale (the "
                f"isolator is nonlinear: its displacement is not proportional to the ground motion's scale)")

    over = np.flatnonzero(np.abs(r) > rig.stroke_m)
    if over.size:
        k = over[0]
        return _refusal(target, k, r[k], f"|r| <= stroke {rig.stroke_m:g} m",
                        f"r = {_mm(r[k])} mm is beyond the rig's stroke of +-{rig.stroke_m * 1e3:g} mm"
                        f"{scale_note}; the peak is {_mm(np.max(np.abs(r)))} mm: "
                        f"{fits(rig.stroke_m / np.max(np.abs(r)))}")
    q_pump = rig.pump_max_flow_m3_per_s
    flow = rig.piston_area_m2 * np.abs(v)
    over = np.flatnonzero(flow > q_pump)
    if over.size:
        k = over[0]
        return _refusal(target, k, v[k], f"A_p |r'| <= pump flow {q_pump / LITRE_PER_MIN_M3_S:.0f} l/min",
                        f"velocity {v[k]:.4g} m/s needs {flow[k] / LITRE_PER_MIN_M3_S:.0f} l/min (A_p = "
                        f"{rig.piston_area_m2:g} m2), more than the pump's {q_pump / LITRE_PER_MIN_M3_S:.0f} l/min "
                        f"(|r'| <= {q_pump / rig.piston_area_m2:.3g} m/s){scale_note}; "
                        f"{fits(q_pump / np.max(flow), ' the pump')}")
    fixed = isolator.kw_n + rig.friction_force_n
    force = isolator.kd_n_per_m * np.abs(r) + fixed + rig.viscous_n_s_per_m * np.abs(v) + rig.mass_kg * np.abs(a)
    # the way the actuator's force goes (the isolator's spring, the inertia, and friction and damping against the
    # motion): a single-rod actuator pulls towards -y with its rod side's area only
    pulling = isolator.kd_n_per_m * r + rig.mass_kg * a + np.sign(v) * (fixed + rig.viscous_n_s_per_m * np.abs(v)) < 0
    push, pull = rig.max_force_n(supply_pa), rig.max_pull_force_n(supply_pa)
    f_max = np.where(pulling, pull, push)
    over = np.flatnonzero(force > f_max)
    if over.size:
        k = over[0]
        inertial = rig.mass_kg * abs(a[k])
        way, law = ("pull", "A_B P_s") if pulling[k] and pull != push else ("push", "A_p P_s")
        return _refusal(target, k, force[k], f"{law} = {f_max[k]:.4g} N",
                        f"the rig must {way} up to {force[k]:.4g} N (isolator {isolator.name} "
                        f"{isolator.kd_n_per_m * abs(r[k]) + isolator.kw_n:.4g} N at r = {r[k]:.4g} m, friction "
                        f"{rig.friction_force_n:.4g} N at a vertical load of {rig.vertical_load_n / 1e3:g} kN, "
                        f"viscous {rig.viscous_n_s_per_m * abs(v[k]):.4g} N, inertial m r'' = {inertial:.4g} N "
                        f"at {a[k]:.4g} m/s2) but at most {law} = {f_max[k]:.4g} N at {supply_pa / BAR_PA:g} bar"
                        f"{' (its rod side)' if law == 'A_B P_s' else ''}"
                        f"{scale_note}; lower the scale or the vertical load, or raise supply_bar")
    sign = np.sign(v)
    p_load = (sign * (isolator.kd_n_per_m * r + rig.mass_kg * a) + rig.viscous_n_s_per_m * np.abs(v)
              + fixed) / rig.piston_area_m2
    opening = rig.driver_gain_positive * rig.command_limit_v - rig.dead_zone_v
    share = np.where(v < 0.0, rig.area_ratio_b, 1.0)  # the valve law's supply share (sim.rig.supply_share)
    capacity = 0.9 * rig.flow_gain_m3_per_s_v_sqrt_pa * opening * np.sqrt(np.maximum(share * supply_pa - p_load, 0.0))
    over = np.flatnonzero((flow > capacity) & (flow > 0.0))
    if over.size:
        k = over[0]
        return _refusal(target, k, v[k], f"90 % of the valve capacity {capacity[k] / LITRE_PER_MIN_M3_S:.0f} l/min",
                        f"velocity {v[k]:.4g} m/s needs {flow[k] / LITRE_PER_MIN_M3_S:.0f} l/min but the valve "
                        f"passes at most {capacity[k] / 0.9 / LITRE_PER_MIN_M3_S:.0f} l/min there (load pressure "
                        f"{p_load[k] / BAR_PA:.0f} bar of {supply_pa / BAR_PA:g} bar supply; 90 % is the limit)"
                        f"{scale_note}; lower the scale or raise supply_bar")
    return None


def history_motion_summary(target: HistoryTarget, rig: RigParameters, isolator: Isolator) -> dict:
    """What a history asks of the rig, for the confirmation before the valve opens (the keys of
    sim.profiles.motion_summary): peak |r|, peak |r'|, the largest force of the envelope's force check
    (isolator at |r|, friction at the rig's vertical load, viscous and inertial forces: an upper estimate),
    duration, and no cycles."""
    r, v, a = np.abs(target.r_m), np.abs(target.r_dot_m_per_s), np.abs(target.r_ddot_m_per_s2)
    force = isolator.kd_n_per_m * r + isolator.kw_n + rig.friction_force_n + rig.viscous_n_s_per_m * v \
        + rig.mass_kg * a
    return {"peak_displacement_m": float(np.max(r)), "peak_velocity_m_per_s": float(np.max(v)),
            "peak_force_n": float(np.max(force)), "duration_s": float(target.n_samples * target.dt_s),
            "cycles_total": 0}

