"""Safety limit detectors, like the limit and error detectors of a commercial servo-hydraulic controller.

Each block of samples the worker produces is checked before it is released. Operator limits (per test,
``limits`` in ``POST /api/tests``, bounded by the rig's hard limits): displacement (stroke), force, table
velocity, load pressure, tracking error |y - r|, each with an action (``ACTIONS``, MTS limit detectors are
the anchor): ``indicate`` records an event and the test goes on; ``controlled_stop`` brakes the target to rest
within every displacement limit (sim.loop.ClosedLoop.brake; a displacement limit with this action is guarded:
the target brakes before it); ``valve_close`` ramps the valve command to 0 V in 0.1 s, open loop.
Built-in detectors, always ``valve_close``: non-finite readings or commands, a fault the rig reports in its
status bits (sensor fault, watchdog, interlock), the supply pressure lost (below ``SUPPLY_LOSS_FRACTION``
of the test's setting), a position reading beyond the rig's stroke (``sensor_range_m``: no table can be
there, whatever the operator's displacement limit and its action) and a frozen position reading (unchanged
for ``FROZEN_TIERS`` periods while the valve command stayed beyond the tier's voltage: the valve is open, so
the table moves, unless the sensor is stuck; a table the controller does not drive may rest). Detectors read
what the rig measures (``measured_displacement_m``; the velocity is its difference over
``VELOCITY_SPAN_PERIODS``), never a simulation's true state. After a sensor fault (``SENSOR_FAULTS``) the
last command was computed from a reading that cannot be trusted: the valve closes at once, not over a ramp
(``Trip.close_at_once``).

The first sample that trips (an action other than ``indicate``) ends the test ``aborted``, the trip recorded
with its values and its action. During a controlled stop a ``valve_close`` trip still closes the valve.

The detector of a rig the controller cannot follow (sim.follow: an oscillation, or tracking the learning does not
bring within 1 %) is an operator's limit too, ``limits.actions.follow`` (``FOLLOW_ACTIONS``): ``controlled_stop``
(the default; a tracking stop brakes the target to rest under control, an oscillation closes the valve at once,
since the loop itself is what oscillates) or ``indicate`` (an event, the test goes on: the paper's MRAC runs to
its end; ``follow_trip``).

Plain numerics, in sim so that the engine (sim.detectors: ``isorig simulate``, ``hybrid``, ``compare`` and the
check of a test) judges a test with the very detectors the service's worker runs; backend.safety re-exports it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from sim.errors import FieldError
from sim.loop import CONTROL_PERIOD_S
from sim.measurement import RIG_FAULT_BITS, describe_status, measured_rows
from sim.rig import RigParameters
from sim.samples import Samples

DEFAULT_TRACKING_ERROR_M = 0.05  # the paper's MRAC reaches ~31 mm peak |y - r| on IUT_b, 30 mm at 1 Hz
SUPPLY_LOSS_FRACTION = 0.5  # a measured supply pressure below this share of the test's setting trips
FROZEN_PERIODS = 100  # a position reading unchanged this many periods ...
FROZEN_COMMAND_V = 2.0  # ... while |valve command| stayed at least this (20 % of the range): the sensor is stuck
FROZEN_SATURATED_PERIODS = 20  # ... or this many with the valve nearly wide open (the table would move 8 mm)
FROZEN_SATURATED_V = 8.0
FROZEN_TIERS = ((FROZEN_COMMAND_V, FROZEN_PERIODS), (FROZEN_SATURATED_V, FROZEN_SATURATED_PERIODS))
SENSOR_FAULTS = ("non_finite", "rig_fault", "sensor_range", "position_frozen")  # the reading is not trusted
#: the valve closes at once, without a ramp from the last command: a reading that cannot be trusted, or a
#: controller that cannot follow this rig (sim.follow: its last command may be the peak of an oscillation)
CLOSE_AT_ONCE = (*SENSOR_FAULTS, "not_following")
VELOCITY_SPAN_PERIODS = 5  # velocity = measured displacement difference over 5 periods (5 ms): noise / 5
INDICATIONS_RECORDED = 10  # events per indicating limit and test; further excursions are only counted

ACTIONS = {
    "indicate": "an event is recorded, the test goes on",
    "controlled_stop": ("the target brakes to rest from where it is, within every displacement limit (one with this "
                        "action is never passed: the target brakes before it), and holds there under control; the "
                        "test ends aborted"),
    "valve_close": ("the valve command ramps to 0 V in 0.1 s, open loop; the table coasts on by its stopping distance, "
                    "so the limit can be passed; the test ends aborted"),
}
DEFAULT_ACTION = "valve_close"
LIMIT_KEYS = ("displacement_m", "force_n", "velocity_m_per_s", "load_pressure_pa", "tracking_error_m")
UNITS = {"displacement_m": "m", "force_n": "N", "velocity_m_per_s": "m/s", "load_pressure_pa": "Pa",
         "tracking_error_m": "m"}
#: how a trip's message names each quantity and writes its value (the values themselves stay SI in the event)
QUANTITY_WORDS = {"displacement_m": "|displacement|", "force_n": "|force|", "velocity_m_per_s": "|velocity|",
                  "load_pressure_pa": "|load pressure|", "tracking_error_m": "|y - r|"}
READABLE = {"displacement_m": ("mm", 1e3), "force_n": ("kN", 1e-3), "velocity_m_per_s": ("mm/s", 1e3),
            "load_pressure_pa": ("bar", 1e-5), "tracking_error_m": ("mm", 1e3)}
DETECTORS = {"displacement": "displacement_m", "force": "force_n", "velocity": "velocity_m_per_s",
             "load_pressure": "load_pressure_pa", "tracking_error": "tracking_error_m"}
#: the follow detector's action (``limits.actions.follow``): not a value limit, its thresholds are sim.follow's
FOLLOW_KEY = "follow"
FOLLOW_ACTIONS = {
    "controlled_stop": ("the table did not follow: a tracking stop brakes the target to rest under control, an "
                        "oscillation closes the valve at once (the loop itself oscillates); the test ends aborted"),
    "indicate": ("an event says what the detector saw and when, the test goes on (the tracking verdict still says "
                 "how well the table followed)"),
}
DEFAULT_FOLLOW_ACTION = "controlled_stop"


class LimitError(FieldError):
    """A requested limit is outside what the rig allows; names field, value and limit."""


@dataclass(frozen=True)
class SafetyLimits:
    """Trip thresholds (absolute values, SI units) and the action of each (``ACTIONS``; default valve_close)."""

    displacement_m: float
    force_n: float
    load_pressure_pa: float
    tracking_error_m: float
    velocity_m_per_s: float | None = None  # None: not checked (records made before velocity limits existed)
    actions: dict = field(default_factory=dict)  # every limit's action (those not given: DEFAULT_ACTION)

    def __post_init__(self):
        actions = {key: self.actions.get(key) or DEFAULT_ACTION for key in LIMIT_KEYS}
        follow = self.actions.get(FOLLOW_KEY) or DEFAULT_FOLLOW_ACTION
        if follow != DEFAULT_FOLLOW_ACTION:  # kept only when set otherwise: a record without it is a default one
            actions[FOLLOW_KEY] = follow
        object.__setattr__(self, "actions", actions)

    def action(self, key: str) -> str:
        if key == FOLLOW_KEY:
            return self.actions.get(FOLLOW_KEY, DEFAULT_FOLLOW_ACTION)
        return self.actions[key]

    def to_dict(self) -> dict:
        """The limits as stored with a test, with the follow detector's action and thresholds (``follow``)."""
        from .follow import follow_thresholds

        return {**asdict(self), FOLLOW_KEY: {"action": self.action(FOLLOW_KEY), **follow_thresholds()}}

    @classmethod
    def from_dict(cls, values: dict) -> SafetyLimits:
        """The limits as stored with a test (older records: no velocity limit, every action valve_close)."""
        known = {k: values[k] for k in (*LIMIT_KEYS, "actions") if values.get(k) is not None}
        return cls(**known)


def hard_limits(rig: RigParameters) -> SafetyLimits:
    """The largest limits a test may ask for: the rig's stroke, A_p P_s,max, the velocity the pump's flow
    can drive (Q_pump / A_p), P_s,max, and twice the stroke."""
    return SafetyLimits(displacement_m=rig.stroke_m, force_n=rig.max_force_n(rig.max_supply_pa),
                        load_pressure_pa=rig.max_supply_pa, tracking_error_m=2 * rig.stroke_m,
                        velocity_m_per_s=rig.pump_max_flow_m3_per_s / rig.piston_area_m2)


def default_limits(rig: RigParameters) -> SafetyLimits:
    hard = hard_limits(rig)
    return SafetyLimits(displacement_m=hard.displacement_m, force_n=hard.force_n,
                        load_pressure_pa=hard.load_pressure_pa, tracking_error_m=DEFAULT_TRACKING_ERROR_M,
                        velocity_m_per_s=hard.velocity_m_per_s)


def _actions(requested) -> dict:
    if requested is None:
        return {}
    if not isinstance(requested, dict):
        raise LimitError("limits.actions", requested, "an object: limit -> action",
                         "limits.actions must map a limit to an action, e.g. {\"force_n\": \"indicate\"}")
    actions = {}
    keys = (*LIMIT_KEYS, FOLLOW_KEY)
    for key, action in requested.items():
        if key not in keys:
            raise LimitError(f"limits.actions.{key}", action, ", ".join(keys),
                             f"limits.actions.{key}: {key} is not a limit; allowed: {', '.join(keys)}")
        if action is None:
            continue
        if key == FOLLOW_KEY and action not in FOLLOW_ACTIONS:
            raise LimitError(f"limits.actions.{key}", action, ", ".join(FOLLOW_ACTIONS),
                             f"limits.actions.follow = {action!r} is not an action of the follow detector; allowed: "
                             f"{', '.join(FOLLOW_ACTIONS)}")
        if action not in ACTIONS:
            raise LimitError(f"limits.actions.{key}", action, ", ".join(ACTIONS),
                             f"limits.actions.{key} = {action!r} is not an action; allowed: {', '.join(ACTIONS)}")
        actions[key] = action
    return actions


def make_limits(rig: RigParameters, requested: dict | None) -> SafetyLimits:
    """Defaults overridden by ``requested`` (values, and ``actions``: limit -> action); each value must be
    positive and within the hard limit."""
    values = default_limits(rig).to_dict()
    values.pop("actions")
    values.pop(FOLLOW_KEY)
    hard = hard_limits(rig).to_dict()
    requested = dict(requested or {})
    actions = _actions(requested.pop("actions", None))
    for key, value in requested.items():
        if value is None:
            continue
        if key not in values:
            raise LimitError(f"limits.{key}", value, ", ".join(values), f"limits.{key} is not a limit; "
                             f"allowed: {', '.join(values)}, actions")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise LimitError(f"limits.{key}", value, f"a positive number <= {hard[key]:g} {UNITS[key]}",
                             f"limits.{key} = {value!r} must be a positive number (unit {UNITS[key]})")
        if value > hard[key]:
            raise LimitError(f"limits.{key}", value, f"<= {hard[key]:g} {UNITS[key]}",
                             f"limits.{key} = {value:g} {UNITS[key]} is beyond the rig's hard limit of "
                             f"{hard[key]:g} {UNITS[key]}")
        values[key] = float(value)
    return SafetyLimits(**values, actions=actions)


@dataclass
class Trip:
    """A limit detector that fired: which, at which sample, with the values that broke it, and its action
    (``indicate``: an indication, the test goes on)."""

    detector: str
    index: int
    time_s: float
    message: str
    values: dict
    action: str = DEFAULT_ACTION

    @property
    def close_at_once(self) -> bool:
        """A sensor fault (the last command came from a reading that cannot be trusted) or a controller that
        does not follow the rig: no ramp from the last command."""
        return self.detector in CLOSE_AT_ONCE


def follow_trip(lost, action: str = DEFAULT_FOLLOW_ACTION) -> Trip:
    """The follow detector's finding (sim.follow.FollowTrip) as a trip with the operator's ``action``
    (``FOLLOW_ACTIONS``): ``indicate``, an indication; ``controlled_stop``, a braking stop for tracking and a valve
    closed at once for an oscillation (the loop itself oscillates: a braking target would not be followed)."""
    values = {**lost.values, "follow_action": action}
    at = f"at t = {lost.time_s:.3f} s"

    def said(words: str) -> str:  # what was done, after when: the advice stays last
        return lost.message.replace(at, f"{at} ({words})", 1)

    if action == "indicate":
        message = said("indicated: the follow detector is set to indicate, the test goes on")
        return Trip("not_following", lost.index, lost.time_s, message, values, "indicate")
    if lost.kind == "tracking":
        message = said("controlled stop: the target brakes to rest under control")
        return Trip("not_following", lost.index, lost.time_s, message, values, "controlled_stop")
    return Trip("not_following", lost.index, lost.time_s, lost.message, values, "valve_close")


def velocity_readings(rows: Samples) -> np.ndarray:
    """The position readings for the velocity: NaN in the rows of lost periods, which hold an older reading
    (a difference across them would divide the motion of more periods by n T)."""
    return np.where(measured_rows(rows["flags"]), rows["measured_displacement_m"], np.nan)


def measured_velocity(y: np.ndarray, before: np.ndarray | None = None) -> np.ndarray:
    """Table velocity from the measured displacement: (y[k] - y[k - n]) / (n T) with n =
    ``VELOCITY_SPAN_PERIODS``; ``before``: the readings that came before ``y`` (NaN where there are none).
    NaN where either reading is missing (``velocity_readings``): not checked there."""
    n = VELOCITY_SPAN_PERIODS
    head = np.full(n, np.nan) if before is None else np.concatenate([np.full(n, np.nan), before])[-n:]
    full = np.concatenate([head, y])
    return (full[n:] - full[:-n]) / (n * CONTROL_PERIOD_S)


def _values(rows: Samples, i: int, velocity: np.ndarray) -> dict:
    y, r = rows["measured_displacement_m"][i], rows["target_m"][i]
    return {"time_s": float(rows["time_s"][i]), "displacement_m": float(y), "force_n": float(rows["force_n"][i]),
            "velocity_m_per_s": float(velocity[i]), "load_pressure_pa": float(rows["load_pressure_pa"][i]),
            "supply_pressure_pa": float(rows["supply_pressure_pa"][i]), "target_m": float(r),
            "tracking_error_m": float(abs(y - r)), "voltage_v": float(rows["voltage_v"][i]),
            "flags": int(np.nan_to_num(rows["flags"][i]))}


def limit_masks(rows: Samples, limits: SafetyLimits, velocity: np.ndarray) -> dict[str, np.ndarray]:
    """For each operator limit (detector name -> mask): the samples beyond it."""
    y, r = rows["measured_displacement_m"], rows["target_m"]
    with np.errstate(invalid="ignore"):
        masks = {"displacement": np.abs(y) > limits.displacement_m,
                 "force": np.abs(rows["force_n"]) > limits.force_n,
                 "load_pressure": np.abs(rows["load_pressure_pa"]) > limits.load_pressure_pa,
                 # rows without a target (open-loop ramp) have r = NaN and are not checked for tracking
                 "tracking_error": np.isfinite(r) & (np.abs(y - r) > limits.tracking_error_m)}
        if limits.velocity_m_per_s is not None:
            masks["velocity"] = np.abs(velocity) > limits.velocity_m_per_s
    return masks


def _limit_trip(rows: Samples, i: int, detector: str, limits: SafetyLimits, velocity: np.ndarray) -> Trip:
    key = DETECTORS[detector]
    limit, action = getattr(limits, key), limits.action(key)
    values = _values(rows, i, velocity)
    values.update(limit=limit, limit_name=key, action=action)
    t = values["time_s"]
    verb = "exceeded (indicated)" if action == "indicate" else f"tripped ({action.replace('_', ' ')})"
    shown = READABLE[key]  # SI with a prefix a person reads at a glance: mm, kN, mm/s, bar
    value, bound = abs(values[key]) * shown[1], limit * shown[1]
    message = (f"{detector.replace('_', ' ')} limit {verb} at t = {t:.3f} s: {QUANTITY_WORDS[key]} {value:.4g} "
               f"{shown[0]} beyond the limit of {bound:.4g} {shown[0]}")
    return Trip(detector, i, t, message, values, action)


def check_block(rows: Samples, limits: SafetyLimits, supply_pa: float | None = None,
                velocity: np.ndarray | None = None, skip: tuple[str, ...] = ("indicate",),
                sensor_range_m: float | None = None) -> Trip | None:
    """The first sample of ``rows`` that trips a detector (stateless; limits whose action is in ``skip``
    are not checked: ``indicate`` ones are left to ``SafetyMonitor``), or None.

    ``supply_pa``: the test's supply pressure setting, for the supply-loss detector (skipped if None);
    ``velocity``: the measured velocity of each row (``measured_velocity``; from this block alone if None);
    ``sensor_range_m``: the rig's stroke, beyond which a position reading is a sensor fault (None: unchecked).
    """
    if len(rows) == 0:
        return None
    y, f, pl = rows["measured_displacement_m"], rows["force_n"], rows["load_pressure_pa"]
    ps, u = rows["supply_pressure_pa"], rows["voltage_v"]
    if velocity is None:
        velocity = measured_velocity(velocity_readings(rows))
    flags = np.nan_to_num(rows["flags"]).astype(np.int64)
    finite = np.isfinite(y) & np.isfinite(f) & np.isfinite(pl) & np.isfinite(u) & np.isfinite(ps)
    checks = [("non_finite", ~finite), ("rig_fault", (flags & RIG_FAULT_BITS) != 0)]
    if sensor_range_m is not None:
        with np.errstate(invalid="ignore"):
            checks.append(("sensor_range", np.abs(y) > sensor_range_m))
    checks += [(name, mask) for name, mask in limit_masks(rows, limits, velocity).items()
               if limits.action(DETECTORS[name]) not in skip]
    if supply_pa is not None:
        checks.append(("supply_pressure", ps < SUPPLY_LOSS_FRACTION * supply_pa))
    first = None
    for name, mask in checks:
        hits = np.flatnonzero(mask)
        if hits.size and (first is None or hits[0] < first[1]):
            first = (name, int(hits[0]))
    if first is None:
        return None
    name, i = first
    if name in DETECTORS:
        return _limit_trip(rows, i, name, limits, velocity)
    values = _values(rows, i, velocity)
    t = values["time_s"]
    if name == "non_finite":
        message = f"non-finite rig state or reading at t = {t:.3f} s"
    elif name == "rig_fault":
        message = f"the rig reports a fault at t = {t:.3f} s: {describe_status(values['flags'] & RIG_FAULT_BITS)}"
    elif name == "sensor_range":
        values.update(limit=sensor_range_m, limit_name="sensor_range_m")
        message = (f"position reading out of range at t = {t:.3f} s: {values['displacement_m'] * 1e3:.6g} mm is "
                   f"beyond the rig's stroke of +-{sensor_range_m * 1e3:g} mm (a sensor fault; the valve closes)")
    else:
        floor = SUPPLY_LOSS_FRACTION * supply_pa
        values.update(limit=floor, limit_name="supply_pressure_pa")
        message = (f"supply pressure lost at t = {t:.3f} s: {values['supply_pressure_pa'] / 1e5:.4g} bar < "
                   f"{floor / 1e5:.4g} bar ({SUPPLY_LOSS_FRACTION:.0%} of the test's {supply_pa / 1e5:.4g} bar)")
    return Trip(name, i, t, message, values)


class SafetyMonitor:
    """Every detector over a test's blocks in order: ``check_block``, the frozen-reading detector and the
    velocity (which need what came before the block), and the indications of ``indicate`` limits: one per
    excursion beyond the limit, the first ``INDICATIONS_RECORDED`` of each limit kept for events
    (``take_indications``), all of them counted (``indication_counts``)."""

    def __init__(self, limits: SafetyLimits, supply_pa: float | None = None, sensor_range_m: float | None = None):
        self.limits = limits
        self.supply_pa = supply_pa
        self.sensor_range_m = sensor_range_m
        self._last_reading = np.nan
        self._run_periods = [0] * len(FROZEN_TIERS)  # per tier: periods unchanged, valve open, before the block
        self._recent = np.zeros(0)  # the last readings, for the velocity
        self._beyond: dict[str, bool] = {}  # an indicating limit was exceeded at the end of the last block
        self.indication_counts: dict[str, int] = {}
        self._indications: list[Trip] = []

    def check(self, rows: Samples, valve_close_only: bool = False) -> Trip | None:
        """The first trip in ``rows`` (``valve_close_only``: during a controlled stop, only what closes the
        valve), or None; indications are kept for ``take_indications``."""
        y = velocity_readings(rows)
        velocity = measured_velocity(y, self._recent)
        self._recent = np.concatenate([self._recent, y])[-VELOCITY_SPAN_PERIODS:]
        self._indicate(rows, velocity)
        skip = ("indicate", "controlled_stop") if valve_close_only else ("indicate",)
        trip = check_block(rows, self.limits, self.supply_pa, velocity, skip, self.sensor_range_m)
        frozen = self._frozen(rows, velocity)
        if frozen is not None and (trip is None or frozen.index < trip.index):
            return frozen
        return trip

    def indicate_follow(self, trip: Trip) -> None:
        """An indication of the follow detector (``follow_trip`` with ``indicate``): counted, kept for events."""
        count = self.indication_counts.get(FOLLOW_KEY, 0) + 1
        self.indication_counts[FOLLOW_KEY] = count
        trip.values["indication"] = count
        if count <= INDICATIONS_RECORDED:
            self._indications.append(trip)

    def take_indications(self) -> list[Trip]:
        out, self._indications = self._indications, []
        return out

    def _indicate(self, rows: Samples, velocity: np.ndarray) -> None:
        if len(rows) == 0:
            return
        for name, mask in limit_masks(rows, self.limits, velocity).items():
            key = DETECTORS[name]
            if self.limits.action(key) != "indicate":
                continue
            before = np.concatenate([[self._beyond.get(name, False)], mask[:-1]])
            for i in np.flatnonzero(mask & ~before):
                count = self.indication_counts.get(key, 0) + 1
                self.indication_counts[key] = count
                if count <= INDICATIONS_RECORDED:
                    trip = _limit_trip(rows, int(i), name, self.limits, velocity)
                    trip.values["indication"] = count
                    if count == INDICATIONS_RECORDED:
                        trip.message += f" (indication {count}; further ones are counted in the test's summary)"
                    self._indications.append(trip)
            self._beyond[name] = bool(mask[-1])

    def _frozen(self, rows: Samples, velocity: np.ndarray) -> Trip | None:
        """The first sample whose reading has not changed for a tier's periods with the valve open beyond
        the tier's voltage (``FROZEN_TIERS``), or None. Lost periods (FLAG_LOST) hold an older reading: a host
        that did not get a measurement says nothing about the sensor, so they neither count nor break a run."""
        fresh = np.flatnonzero(measured_rows(rows["flags"]))
        n = fresh.size
        if n == 0:
            return None
        y = rows["measured_displacement_m"][fresh]
        command = rows["voltage_v"][fresh]
        same = np.empty(n, dtype=bool)
        same[0] = y[0] == self._last_reading
        same[1:] = y[1:] == y[:-1]
        self._last_reading = y[-1]
        index = np.arange(n)
        first = None
        for tier, (command_v, periods) in enumerate(FROZEN_TIERS):
            with np.errstate(invalid="ignore"):
                changed = ~same | ~(np.abs(command) >= command_v)  # a run counts valve-open periods
            start = np.maximum.accumulate(np.where(changed, index, -1))  # where the current run began (-1: before)
            run = np.where(start >= 0, index - start, index + 1 + self._run_periods[tier])
            self._run_periods[tier] = int(run[-1])
            hits = np.flatnonzero(run >= periods)
            if hits.size and (first is None or hits[0] < first[0]):
                first = (int(hits[0]), int(run[hits[0]]), command_v)
        if first is None:
            return None
        j, unchanged, command_v = first
        i = int(fresh[j])
        values = _values(rows, i, velocity)
        values.update(unchanged_periods=unchanged, command_at_least_v=command_v)
        message = (f"position reading frozen at t = {values['time_s']:.3f} s: {values['displacement_m']:.6g} m for "
                   f"{unchanged} periods with the valve command beyond +-{command_v:g} V (a stuck sensor)")
        return Trip("position_frozen", i, values["time_s"], message, values)
