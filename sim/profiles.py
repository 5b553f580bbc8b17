"""Target displacement profiles: tapered sines (and sequences of them), checked against the rig envelope.

A sine block of ``cycles`` cycles has its first and last ``taper_cycles`` cycles ramped in and out
with a raised-cosine envelope (so the target and its velocity start and end at zero). The target begins
at the first block's ``start_m`` (0 by default: where the table must rest when the test starts); ``offset_m``
is approached smoothly from it over the first cycle and then held (a test about the table's present
position: ``start_m = offset_m``). A profile is packed into an array of blocks for the compiled engine.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from numba import njit

from .errors import FieldError
from .isolator import Isolator
from .rig import BAR_PA, LITRE_PER_MIN_M3_S, RigParameters

MAX_FREQUENCY_HZ = 10.0  # well below the valve's 40 Hz
MAX_CYCLES = 100_000


class ProfileError(FieldError):
    """A profile is malformed or outside the rig's envelope. ``field``, ``value`` and ``limit`` say why."""


@dataclass(frozen=True)
class SineProfile:
    """Sine displacement target: r(t) = start + (offset - start) ramp(t) + A env(t) sin(2 pi f t), the ramp
    raised-cosine over the first cycle (``start_m`` of the first block only: where the table rests)."""

    amplitude_m: float
    frequency_hz: float
    cycles: int
    taper_cycles: int = 1
    offset_m: float = 0.0
    start_m: float = 0.0

    @property
    def reach_m(self) -> float:
        """The largest |r| the block can ask: max(|start|, |offset|) + A."""
        return max(abs(self.start_m), abs(self.offset_m)) + self.amplitude_m

    @property
    def duration_s(self) -> float:
        return self.cycles / self.frequency_hz

    def to_dict(self) -> dict:
        return {"kind": "sine", **asdict(self)}

    def blocks(self) -> list[SineProfile]:
        return [self]


def blocks_from_dicts(blocks: list[dict]) -> list[SineProfile]:
    """Sine blocks from their stored form (``SineProfile.to_dict()``: a record's scenario, a job)."""
    return [SineProfile(float(b["amplitude_m"]), float(b["frequency_hz"]), int(b["cycles"]),
                        int(b.get("taper_cycles", 0)), float(b.get("offset_m", 0.0)), float(b.get("start_m", 0.0)))
            for b in blocks]


# Packed block columns.
B_START, B_AMPLITUDE, B_FREQUENCY, B_CYCLES, B_TAPER, B_OFFSET, B_START_M = range(7)
N_BLOCK_COLUMNS = 7


def pack_profile(blocks: list[SineProfile]) -> np.ndarray:
    """One row per block: start time, amplitude, frequency, cycles, taper cycles, offset, start position."""
    rows = np.zeros((len(blocks), N_BLOCK_COLUMNS))
    start = 0.0
    for i, b in enumerate(blocks):
        rows[i] = (start, b.amplitude_m, b.frequency_hz, b.cycles, b.taper_cycles, b.offset_m, b.start_m)
        start += b.duration_s
    return rows


def profile_duration_s(blocks: list[SineProfile]) -> float:
    return sum(b.duration_s for b in blocks)


@njit(cache=True, error_model="numpy")
def _raised_cosine(x):
    """0 at x <= 0, 1 at x >= 1, smooth in between; returns (value, derivative)."""
    if x <= 0.0:
        return 0.0, 0.0
    if x >= 1.0:
        return 1.0, 0.0
    return 0.5 * (1.0 - np.cos(np.pi * x)), 0.5 * np.pi * np.sin(np.pi * x)


@njit(cache=True, error_model="numpy", inline="always")
def target(t, blocks):
    """Target displacement r(t) in m and its rate r'(t) in m/s."""
    n = blocks.shape[0]
    i = n - 1
    for j in range(n):
        if t < blocks[j, B_START] + blocks[j, B_CYCLES] / blocks[j, B_FREQUENCY]:
            i = j
            break
    f = blocks[i, B_FREQUENCY]
    cycles = blocks[i, B_CYCLES]
    tau = (t - blocks[i, B_START]) * f  # time in cycles within the block
    if tau > cycles:
        tau = cycles
    taper = blocks[i, B_TAPER]
    if taper > 0.0:
        up, dup = _raised_cosine(tau / taper)
        down, ddown = _raised_cosine((cycles - tau) / taper)
        env = up * down
        denv = (dup * down - up * ddown) * f / taper
    else:
        env, denv = 1.0, 0.0
    omega = 2.0 * np.pi * f
    phase = omega * (t - blocks[i, B_START])
    amp = blocks[i, B_AMPLITUDE]
    r = amp * env * np.sin(phase)
    rdot = amp * (denv * np.sin(phase) + env * omega * np.cos(phase))
    # offset: approached from the start position over the first cycle of the first block, then held
    f0 = blocks[0, B_FREQUENCY]
    ramp, dramp = _raised_cosine(t * f0)
    start = blocks[0, B_START_M]
    r += start + (blocks[0, B_OFFSET] - start) * ramp
    rdot += (blocks[0, B_OFFSET] - start) * dramp * f0
    return r, rdot


def target_series(blocks: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    return np.array([target(t, blocks)[0] for t in np.asarray(t_s, float)])


def _number(field, value, lo, hi, unit, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ProfileError(field, value, f"a finite number in [{lo:g}, {hi:g}] {unit}",
                           f"{field} = {value!r} is not a finite number (unit {unit})")
    if integer and float(value) != int(value):
        raise ProfileError(field, value, "a whole number", f"{field} = {value!r} must be a whole number")
    if not (lo <= value <= hi):
        raise ProfileError(field, value, f"[{lo:g}, {hi:g}] {unit}",
                           f"{field} = {value:g} {unit} is outside the allowed range [{lo:g}, {hi:g}] {unit}")


def check_supply(supply_pa: float, rig: RigParameters) -> None:
    lo, hi = rig.min_supply_pa / BAR_PA, rig.max_supply_pa / BAR_PA
    value = supply_pa / BAR_PA if isinstance(supply_pa, (int, float)) else supply_pa
    _number("supply_bar", value, lo, hi, "bar")


def force_estimate_n(block: SineProfile, rig: RigParameters, isolator: Isolator) -> float:
    """Upper estimate of the force a sine block needs: the isolator's peak force at |offset| + A, the
    friction at the test's vertical load (mu N + F_c, eq. 1), viscous force at the peak velocity and the
    table's inertia at the peak acceleration (each at its own peak, so never an underestimate)."""
    omega = 2 * math.pi * block.frequency_hz
    reach = block.reach_m
    return (isolator.peak_force_n(reach) + rig.friction_force_n + rig.viscous_n_s_per_m * omega * block.amplitude_m
            + rig.mass_kg * omega ** 2 * block.amplitude_m)


def motion_summary(blocks: list[SineProfile], rig: RigParameters, isolator: Isolator) -> dict:
    """What a profile asks of the rig, for a confirmation before the valve opens: peak displacement
    (|offset| + A, or |start| + A), peak velocity (2 pi f A), the force estimate (``force_estimate_n``),
    duration, cycles, and where the target begins (``start_position_m``: the table must rest there)."""
    return {"start_position_m": blocks[0].start_m if blocks else 0.0,
            "peak_displacement_m": max(b.reach_m for b in blocks),
            "peak_velocity_m_per_s": max(2 * math.pi * b.frequency_hz * b.amplitude_m for b in blocks),
            "peak_force_n": max(force_estimate_n(b, rig, isolator) for b in blocks),
            "duration_s": sum(b.duration_s for b in blocks),
            "cycles_total": sum(b.cycles for b in blocks)}


def _advice(block: SineProfile, rig: RigParameters, isolator: Isolator, supply_pa: float) -> str:
    """What would fit, checked against every limit: the highest frequency at this amplitude, else the largest
    amplitude at this frequency, else none (the block's offset and start kept)."""
    def fits(**change) -> bool:
        return envelope_problem(replace(block, **change), rig, isolator, supply_pa, advise=False) is None

    f_ok = _largest_allowed(lambda f: fits(frequency_hz=max(f, 1e-9)), MAX_FREQUENCY_HZ)
    if f_ok > 1e-6:
        return f"at this amplitude frequency_hz must be <= {f_ok:.3g} Hz"
    a_ok = _largest_allowed(lambda a: fits(amplitude_m=max(a, 1e-9)), rig.stroke_m)
    if a_ok > 1e-6:
        return (f"no frequency fits amplitude_m = {block.amplitude_m:g} m; at this frequency amplitude_m must be "
                f"<= {a_ok:.3g} m")
    return "no amplitude fits at this offset, vertical load and supply pressure"


def envelope_problem(block: SineProfile, rig: RigParameters, isolator: Isolator, supply_pa: float,
                     advise: bool = True):
    """The first envelope limit a sine block violates, as a ProfileError, or None.

    Limits: stroke; pump flow A_p * 2 pi f A <= Q_pump; force kd (|offset| + A) + kw + friction at the
    test's vertical load (mu N + F_c, eq. 1) + viscous and inertial forces <= A_p P_s pushing and A_B P_s pulling
    (a single-rod actuator's rod side; the same on a double-rod one); valve flow capacity at
    the load pressure of the peak-velocity point, with the valve law's supply share towards -y (sim.rig.supply_share).
    ``rig`` carries the test's vertical load. ``advise``: the
    message ends with what would fit, checked against every limit (``_advice``).
    """
    a, f = block.amplitude_m, block.frequency_hz
    reach = block.reach_m
    if reach > rig.stroke_m:
        start = f" and start_m = {block.start_m:g} m" if block.start_m else ""
        return ProfileError("amplitude_m", a, f"max(|offset_m|, |start_m|) + amplitude_m <= stroke {rig.stroke_m:g} m",
                            f"amplitude_m = {a:g} m with offset_m = {block.offset_m:g} m{start} reaches {reach:g} m, "
                            f"beyond the rig's stroke of +-{rig.stroke_m:g} m")
    omega = 2 * math.pi * f
    v_peak = omega * a
    flow = rig.piston_area_m2 * v_peak
    def then(text: str) -> str:
        return f"{text}; {_advice(block, rig, isolator, supply_pa)}" if advise else text

    if flow > rig.pump_max_flow_m3_per_s:
        return ProfileError("frequency_hz", f, f"pump flow {rig.pump_max_flow_m3_per_s / LITRE_PER_MIN_M3_S:.0f} l/min",
                            then(f"peak flow demand {flow / LITRE_PER_MIN_M3_S:.0f} l/min (amplitude_m = {a:g} m at "
                                 f"frequency_hz = {f:g} Hz) exceeds the pump's "
                                 f"{rig.pump_max_flow_m3_per_s / LITRE_PER_MIN_M3_S:.0f} l/min"))
    force = force_estimate_n(block, rig, isolator)
    # a sine needs its force both ways: a single-rod actuator pulls with its rod side's area only
    push, pull = rig.max_force_n(supply_pa), rig.max_pull_force_n(supply_pa)
    f_max = min(push, pull)
    if force > f_max:
        at = f"amplitude_m = {a:g} m" + (f" about offset_m = {block.offset_m:g} m" if block.offset_m else "")
        can = (f"push at most A_p P_s = {push / 1e3:.1f} kN" if push <= pull else
               f"pull at most A_B P_s = {pull / 1e3:.1f} kN with its rod side (push {push / 1e3:.1f} kN)")
        return ProfileError("amplitude_m", a, f"{'A_p' if push <= pull else 'A_B'} P_s = {f_max / 1e3:.1f} kN",
                            then(f"the test needs up to {force / 1e3:.1f} kN (isolator {isolator.name} at {at}, "
                                 f"friction {rig.friction_force_n / 1e3:.1f} kN at a vertical load of "
                                 f"{rig.vertical_load_n / 1e3:g} kN) but the rig can {can} at "
                                 f"{supply_pa / BAR_PA:g} bar; lower the amplitude, the "
                                 f"offset or the vertical load, or raise supply_bar"))
    # valve capacity where the velocity peaks (d = 0): load pressure from hysteretic + friction forces
    p_load = (isolator.kw_n + rig.friction_force_n + rig.viscous_n_s_per_m * v_peak) / rig.piston_area_m2
    opening = rig.driver_gain_positive * rig.command_limit_v - rig.dead_zone_v
    # the drop across the valve's metering land: s P_s - P_L with the supply's share s of the valve law (sim.rig:
    # A_B / A_A towards -y on a single-rod actuator); a sine runs both ways, so the smaller
    dp = max(min(1.0, rig.area_ratio_b) * supply_pa - p_load, 0.0)
    valve_flow = rig.flow_gain_m3_per_s_v_sqrt_pa * opening * math.sqrt(dp)
    if flow > 0.9 * valve_flow:
        capacity = f"90 % of the valve capacity {valve_flow / LITRE_PER_MIN_M3_S:.0f} l/min"
        return ProfileError("frequency_hz", f, capacity,
                            then(f"peak flow demand {flow / LITRE_PER_MIN_M3_S:.0f} l/min exceeds 90 % of what the "
                                 f"valve passes at {supply_pa / BAR_PA:g} bar ({valve_flow / LITRE_PER_MIN_M3_S:.0f} "
                                 f"l/min); lower amplitude_m or frequency_hz, or raise supply_bar"))
    return None


def check_vertical_load(vertical_load_n: float, rig: RigParameters) -> None:
    """The vertical load must be a number of newtons within [0, the jack's capacity]."""
    _number("vertical_load_n", vertical_load_n, 0.0, rig.max_vertical_load_n, "N")


def validate_profile(blocks: list[SineProfile], rig: RigParameters, isolator: Isolator, supply_pa: float) -> None:
    """Raise ProfileError if any block is malformed or outside the envelope (before anything runs);
    ``rig`` carries the test's vertical load."""
    check_supply(supply_pa, rig)
    check_vertical_load(rig.vertical_load_n, rig)
    if not blocks:
        raise ProfileError("profile", [], "at least one block", "the profile has no sine block")
    for i, b in enumerate(blocks):
        _number("start_m", b.start_m, -rig.stroke_m, rig.stroke_m, "m")
        if i and b.start_m:
            raise ProfileError("start_m", b.start_m, "0 after the first block", f"start_m = {b.start_m:g} m on "
                               f"block {i + 1}: only the first block says where the test starts")
        _number("amplitude_m", b.amplitude_m, 1e-5, rig.stroke_m, "m")
        _number("frequency_hz", b.frequency_hz, 1e-3, MAX_FREQUENCY_HZ, "Hz")
        _number("cycles", b.cycles, 1, MAX_CYCLES, "cycles", integer=True)
        _number("taper_cycles", b.taper_cycles, 0, MAX_CYCLES, "cycles", integer=True)
        _number("offset_m", b.offset_m, -rig.stroke_m, rig.stroke_m, "m")
        if 2 * b.taper_cycles > b.cycles:
            raise ProfileError("taper_cycles", b.taper_cycles, f"<= cycles / 2 = {b.cycles / 2:g}",
                               f"taper_cycles = {b.taper_cycles} ramps in and out, so it must be at most half of "
                               f"cycles = {b.cycles}")
        problem = envelope_problem(b, rig, isolator, supply_pa)
        if problem is not None:
            raise problem


def _largest_allowed(fits, hi: float) -> float:
    """Largest x in [0, hi] with fits(x) true, for fits true at 0 and monotonic (bisection)."""
    lo = 0.0
    if fits(hi):
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    return lo


def max_amplitude_m(frequency_hz: float, rig: RigParameters, isolator: Isolator, supply_pa: float) -> float:
    """Largest amplitude the envelope allows at this frequency."""
    return _largest_allowed(
        lambda a: envelope_problem(SineProfile(a, frequency_hz, 1, 0), rig, isolator, supply_pa,
                                   advise=False) is None,
        rig.stroke_m)


def max_frequency_hz(amplitude_m: float, rig: RigParameters, isolator: Isolator, supply_pa: float) -> float:
    """Highest frequency the envelope allows at this amplitude (0 if no frequency fits it)."""
    return _largest_allowed(
        lambda f: envelope_problem(SineProfile(amplitude_m, max(f, 1e-9), 1, 0), rig, isolator, supply_pa,
                                   advise=False) is None,
        MAX_FREQUENCY_HZ)


def start_velocity_m_per_s(block: SineProfile) -> float:
    """The target's velocity at t = 0 of a test beginning with ``block``: 2 pi f A without a taper (the sine starts
    at its full velocity while the table rests), 0 with one (the raised cosine starts the sine from rest)."""
    return 0.0 if block.taper_cycles > 0 else 2 * math.pi * block.frequency_hz * block.amplitude_m


def start_problem(scenario, limits, override: str = "set limits.actions.{key} to indicate"):
    """A test whose untapered start is expected to trip a limit, as a ProfileError on ``taper_cycles``; else None.

    A sine with ``taper_cycles = 0`` asks the table, at rest, for 2 pi f A at once: the target runs ahead and the
    loop's catch-up overshoots that velocity (IUT_b at 100 bar, 20 mm at 1.25 Hz: 157 mm/s asked, 410 mm/s
    reached in 20 ms, beyond the 391 mm/s the pump feeds). The test's first cycle is simulated on the rig model
    the controller is told of (sim.detectors.predict_first_trip, with ``limits``: an ``indicate`` limit trips
    nothing, and ``limits`` None, a run without the limit detectors, is never refused); the start is refused when
    it trips a limit and the same test with ``taper_cycles = 1`` does not (a trip that a taper does not cure is
    the first-cycle warning's to tell). ``override`` (``{key}``: the limit's name) ends the message with how
    to run it anyway. The loop does not blend the target in: a test without a taper (the
    paper's, which start at rest) runs as asked whenever it stays within the limits."""
    if limits is None or scenario.history is not None or not scenario.profile:
        return None
    first = scenario.profile[0]
    v0 = start_velocity_m_per_s(first)
    if v0 <= 0.0:
        return None
    from .detectors import first_cycle_s, predict_first_trip  # the engine: imported only for an untapered start
    from .safety import DETECTORS

    on_model = replace(scenario, plant_changes={}, timed_changes=[], foreign_rig=None)
    predicted = predict_first_trip(on_model, limits)
    if predicted is None or predicted.trip.detector not in DETECTORS:
        return None  # nothing trips, or not a limit (a sensor detector, a diverged model): the warning says it
    tapered = replace(first, taper_cycles=1, cycles=max(first.cycles, 2))
    with_taper = replace(on_model, profile=[tapered, *on_model.profile[1:]])
    if predict_first_trip(with_taper, limits) is not None:
        return None
    more = "" if first.cycles >= 2 else " (and cycles >= 2: a taper ramps in and out)"
    trip = predicted.trip
    return ProfileError(
        "taper_cycles", first.taper_cycles, "taper_cycles >= 1 (the target then starts from rest)",
        f"taper_cycles >= 1 needed{more}: a sine of {first.amplitude_m * 1e3:g} mm at {first.frequency_hz:g} Hz "
        f"without a taper starts at {v0 * 1e3:.0f} mm/s from rest, and the table's catch-up is expected to trip a "
        f"limit ({predicted.controller} controller on the rig model): {trip.message}; with taper_cycles = 1 the "
        f"target starts from rest and its first {first_cycle_s(with_taper):.3g} s are expected to trip nothing"
        + (f" (or {override.format(key=DETECTORS[trip.detector])})" if override else ""))

