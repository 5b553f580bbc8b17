"""Pydantic models at the API's edge (requests and responses). SI units, the unit in every name.

Every request model is strict (``StrictModel``): a JSON number is a number, never a string ("100") or a boolean
(true); an integer is accepted where a decimal is asked, a decimal is not where a whole number is. The numbers
that size what a request makes (a test's speed factor, a move's speed) are bounded here, before anything is built;
the rest are bounded by the numerics that use them (sim.profiles, sim.protocols, sim.earthquake: cycles, tapers,
durations, samples) before any array is sized, and the query parameters by their ``Query`` bounds.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Discriminator, Field, Tag

from sim.controllers import DEFAULT_CONTROLLER
from sim.errors import FieldError
from sim.motion import MAX_DURATION_S, MAX_SPEED_M_PER_S, MIN_SPEED_M_PER_S, check_speed

from .settings import MAX_SPEED_LIMIT, MIN_SPEED

SPEED_RANGE = f"[{MIN_SPEED:g}, {MAX_SPEED_LIMIT:g}] (and at most the service's max_speed, GET /api/rig)"


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def _test_speed(value: float) -> float:
    if not MIN_SPEED <= value <= MAX_SPEED_LIMIT:
        raise FieldError("speed", value, SPEED_RANGE,
                         f"speed = {value!r} is outside {SPEED_RANGE}: a simulated test runs from {MIN_SPEED:g} "
                         f"(10 times slower than real time) to the service's max_speed times faster; 1 is real time")
    return value


# the speed factor of a simulated test or commissioning (1 = real time); the service's max_speed is checked after
SpeedFactor = Annotated[float, AfterValidator(_test_speed),
                        Field(json_schema_extra={"minimum": MIN_SPEED, "maximum": MAX_SPEED_LIMIT})]
# the peak speed of a manual move (sim.motion.check_speed: a MotionError names the range)
MoveSpeed = Annotated[float, AfterValidator(check_speed),
                      Field(json_schema_extra={"minimum": MIN_SPEED_M_PER_S, "maximum": MAX_SPEED_M_PER_S})]


class SineProfileIn(StrictModel):
    """A tapered sine (sim.profiles.SineProfile)."""

    kind: Literal["sine"]
    amplitude_m: float = Field(description="sine amplitude in m")
    frequency_hz: float = Field(description="frequency in Hz")
    cycles: int = Field(description="number of cycles, taper included")
    taper_cycles: int = Field(1, description="cycles of ramp-in and of ramp-out")
    offset_m: float = Field(0.0, description="mean displacement in m, approached from start_m over the first cycle")
    start_m: float = Field(0.0, description="where the target begins, m: the table must rest there (a test about "
                                          "the table's present position: start_m = offset_m = that position)")


class ProtocolProfileIn(StrictModel):
    """A test protocol (sim.protocols): a shipped one by ``name`` or an inline ``protocol`` object."""

    kind: Literal["protocol"]
    name: str | None = Field(None, max_length=200, description="a shipped protocol's name")
    protocol: dict[str, Any] | None = Field(None, description="an inline protocol definition")
    design_displacement_m: float | None = Field(None, description="scale the protocol's levels to this design "
                                                "displacement, m (levels given as fractions)")
    frequency_hz: float | None = Field(None, description="run every level at this frequency, Hz (EN 15129: the "
                                       "specimen's design frequency); default: each level's own")


MAX_INLINE_SAMPLES = 200_000  # sim.earthquake.MAX_INLINE_SAMPLES
# a sample of an inline record: NaN, infinities and nulls reach sim.earthquake, which names the sample
# (strict: a string or a boolean is not a number; an integer is)
Sample = Annotated[float, Field(allow_inf_nan=True, strict=True)] | None


class InlineGroundMotionIn(StrictModel):
    """A ground acceleration record given inline: uniformly sampled, at most 200 000 samples."""

    time_s: list[Sample] = Field(max_length=MAX_INLINE_SAMPLES, description="times in s, increasing, uniform step")
    acceleration_m_per_s2: list[Sample] = Field(max_length=MAX_INLINE_SAMPLES,
                                                description="the ground acceleration at each time, in ``units``")
    units: Literal["m/s2", "g", "cm/s2"] | None = Field(None, description="the values' unit (default m/s2, "
                                                        "assumed); a peak outside 0.005-3 g in it is refused")
    check_units: bool = Field(True, strict=True, description="false: accept a peak outside 0.005-3 g")


def _ground_motion_tag(value) -> str:
    return "preset" if isinstance(value, str) else "inline"


GroundMotionIn = Annotated[
    Annotated[str, Tag("preset"), Field(max_length=64, description="a shipped synthetic ground motion: "
                                                                   "near_field_short, far_field_long, soft_site")]
    | Annotated[InlineGroundMotionIn, Tag("inline")],
    Discriminator(_ground_motion_tag)]


class InlineDisplacementIn(StrictModel):
    """A displacement history given inline: uniformly sampled, at most 200 000 samples."""

    time_s: list[Sample] = Field(max_length=MAX_INLINE_SAMPLES, description="times in s, increasing, uniform step")
    displacement_m: list[Sample] = Field(max_length=MAX_INLINE_SAMPLES, description="the displacement at each "
                                         "time, m")


class HistoryProfileIn(StrictModel):
    """A time history (sim.earthquake): the isolator's displacement demand under a ground motion, or a
    displacement history; resampled to the control period, tapered, checked against the envelope."""

    kind: Literal["history"]
    ground_motion: GroundMotionIn | None = Field(None, description="a preset name or an inline acceleration "
                                                 "record; the isolator's demand under it is the target")
    displacement: InlineDisplacementIn | None = Field(None, description="or the displacement history itself")
    scale: float = Field(1.0, description="scale of the ground acceleration (0 < scale <= 10; the isolator is "
                                          "nonlinear) or of the displacement (0 < |scale| <= 100)")
    mass_kg: float | None = Field(None, description="the mass of the demand model (a rigid mass on the "
                                  "isolator), kg; default: the vertical load / g")
    taper_in_s: float = Field(0.5, description="raised-cosine taper at the start, s")
    taper_out_s: float = Field(0.5, description="raised-cosine taper at the end, s")


class StructureIn(StrictModel):
    """The shear building above the isolator (sim.structure.ShearBuilding)."""

    base_mass_kg: float = Field(description="the base slab's mass above the isolator, kg")
    masses_kg: list[float] = Field(max_length=1000, description="storey masses, kg, bottom up")
    stiffness_n_per_m: list[float] = Field(max_length=1000, description="storey springs, N/m; the first joins "
                                           "storey 1 to the base")
    damping_ratio: float = Field(description="Rayleigh damping at the first two fixed-base modes, 0 < z < 1")
    name: str = Field("", max_length=64)
    description: str = Field("", max_length=200)


class StabilityIn(StrictModel):
    """The stability monitor (sim.hybrid_metrics.EnergyMonitor): trips when the energy the tracking error adds
    exceeds max(limit_j, relative_limit x the structure's input energy)."""

    limit_j: float | None = Field(None, description="absolute floor of the limit, J (default 100)")
    relative_limit: float | None = Field(None, description="fraction of the input energy (default 0.5)")


class HybridProfileIn(StrictModel):
    """Real-time hybrid simulation (sim.hybrid): the building in the computer, the isolator on the rig."""

    kind: Literal["hybrid"]
    structure: StructureIn
    ground_motion: GroundMotionIn
    scale: float = Field(1.0, description="scale of the ground acceleration, 0 < scale <= 10")
    stability: StabilityIn | None = None


ProfileIn = Annotated[SineProfileIn | ProtocolProfileIn | HistoryProfileIn | HybridProfileIn,
                      Field(discriminator="kind")]
EARTHQUAKE_PROFILES = (HistoryProfileIn, HybridProfileIn)


class LimitsIn(StrictModel):
    """Safety limits of one test (absolute values); each defaults to the rig's, none may exceed the rig's."""

    displacement_m: float | None = Field(None, description="stroke limit on |y| in m")
    force_n: float | None = Field(None, description="limit on |force| in N")
    velocity_m_per_s: float | None = Field(None, description="limit on the measured table velocity |dy/dt| in m/s")
    load_pressure_pa: float | None = Field(None, description="limit on |P_L| in Pa")
    tracking_error_m: float | None = Field(None, description="limit on |y - r| in m (error detector)")
    # names and values checked by sim.safety.make_limits (a 422 naming the allowed ones: the follow detector's
    # differ from a value limit's)
    actions: dict[str, str | None] | None = Field(
        None, description="the action of each limit (key: a limit above): indicate (an event, the test goes on), "
                          "controlled_stop (the target brakes to rest within every displacement limit), "
                          "valve_close (the command ramps to 0 V in 0.1 s, open loop; the default); and of the "
                          "detector of a table that does not follow its target (key: follow): controlled_stop "
                          "(the default) or indicate (an event, the test goes on; the paper's mrac runs to its end)")


class TestCreate(StrictModel):
    """``POST /api/tests``: what to run."""

    __test__ = False

    isolator: str = Field(min_length=1, max_length=64, description="a preset or a user isolator's name")
    supply_bar: float = Field(description="supply pressure in bar")
    vertical_load_n: float | None = Field(None, description="vertical load on the specimen in N, from 0 to the "
                                          "rig's jack capacity (GET /api/rig); default: the isolator's design "
                                          "load, else the rig's default (1.25e5 N)")
    controller: str = Field(DEFAULT_CONTROLLER, max_length=32, description="controller name")
    controller_options: dict[str, float | bool] | None = Field(
        None, description="overrides of the controller's defaults (GET /api/rig lists each controller's options "
                          "with range and unit)")
    speed: SpeedFactor = Field(1.0, description=f"time scale of a simulated test: 1 = real time, 20 = 20x "
                               f"faster ({MIN_SPEED:g} to the service's max_speed, at most {MAX_SPEED_LIMIT:g}; a "
                               "real rig: 1)")
    profile: ProfileIn
    limits: LimitsIn | None = None
    label: str = Field("", max_length=200, description="free text")
    specimen_id: str = Field("", max_length=64, description="the lab's identifier of the specimen (bearing) tested")
    operator_name: str = Field("", max_length=64, description="who runs the test")
    notes: str = Field("", max_length=2000, description="free notes kept with the test")

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [{
        "isolator": "IUT_b", "supply_bar": 70, "controller": "mrac", "speed": 1.0,
        "profile": {"kind": "sine", "amplitude_m": 0.03, "frequency_hz": 1.0, "cycles": 10, "taper_cycles": 1}}]})


class ApproveIn(StrictModel):
    """``POST /api/tests/{id}/approve``: an approver's note (optional)."""

    note: str = Field("", max_length=400, description="a note printed with the approval (in the report's approval "
                      "block)")


class ToleranceIn(StrictModel):
    """``PUT /api/acceptance/tolerances/{protocol}``: the lab's tolerances against the specimen's design values,
    as fractions (0.15 is +-15 %)."""

    k_eff: float = Field(gt=0, le=1, description="each test cycle's K_eff from the level's design value")
    edc: float = Field(gt=0, le=1, description="each test cycle's EDC from the level's design value")
    xi_eff: float = Field(gt=0, le=1, description="each test cycle's xi_eff from the level's design value")
    mean: float = Field(gt=0, le=1, description="the mean of a level's test cycles from its design values")


class RejectIn(StrictModel):
    """``POST /api/tests/{id}/reject``: why the record needs another look."""

    reason: str = Field(min_length=3, max_length=400, description="why (at least 3 characters)")


class ArchiveIn(StrictModel):
    """Who archives (or restores) a test and why: a test that ran is never erased through the API."""

    by: str = Field("", max_length=64, description="who: the logged-in account (leave it out; another name is "
                    "refused, except through the service account 'automation', which keeps it beside its own)")
    reason: str = Field(min_length=3, max_length=400, description="why")


class EnvelopeCheckOut(BaseModel):
    """``POST /api/tests/check``: would this test be accepted, and what does the envelope allow around it."""

    ok: bool
    detail: str = Field(description="why it is refused, or that it fits")
    field: str | None = None
    value: Any = None
    limit: str | None = None
    max_amplitude_m: float | None = Field(None, description="largest amplitude at this frequency (sine only)")
    max_frequency_hz: float | None = Field(None, description="highest frequency at this amplitude (sine only; "
                                           "null when no frequency fits the amplitude)")
    max_force_n: float | None = Field(None, description="A_p P_s at this supply pressure: what the actuator pushes")
    max_pull_force_n: float | None = Field(None, description="A_B P_s at this supply pressure: what a single-rod "
                                           "actuator pulls with its rod side (A_p P_s on a double-rod one)")
    max_vertical_load_n: float | None = Field(None, description="the vertical jack's capacity, N")
    start_position_m: float | None = Field(None, description="where the target begins: the table must rest there "
                                           "(within the rig's start tolerance) for the test to start")
    peak_displacement_m: float | None = Field(None, description="the largest |offset| + amplitude of the profile")
    peak_velocity_m_per_s: float | None = Field(None, description="the largest 2 pi f A of the profile")
    peak_force_n: float | None = Field(None, description="upper estimate of the force the profile needs: isolator, "
                                       "friction at the vertical load, viscous and inertial forces")
    duration_s: float | None = Field(None, description="how long the profile runs (test time)")
    cycles_total: int | None = Field(None, description="cycles of the profile, tapers included (0: a history)")
    profile: dict | None = Field(None, description="a history or hybrid profile as built (source, peaks, "
                                 "duration, the ground motion, the structure): what the record's profile will say")
    warnings: list[str] = Field(default_factory=list, description="what the operator should know before the "
                                "valve opens, each to be acknowledged: a limit the first cycle is expected to trip")
    predicted_trip: dict | None = Field(None, description="the trip the first cycle is expected to meet (the "
                                        "test's controller on the rig model, the service's detectors): detector, "
                                        "action, time_s, message, values (SI), simulated_s, controller")
    prediction: str | None = Field(None, description="what the first-cycle prediction ran and found, or why it "
                                   "did not run")


class IsolatorIn(StrictModel):
    """A user isolator: Bouc-Wen parameters of eq. (4), SI units."""

    name: str = Field(min_length=1, max_length=64)
    rho_bw_per_m: float
    sigma_bw: float
    n: float
    kd_n_per_m: float
    kw_n: float
    description: str = Field("", max_length=200)
    design_vertical_load_n: float | None = Field(None, description="the vertical load its tests run under by "
                                                 "default, N")


class ErrorOut(BaseModel):
    """Every error: ``detail`` says what is wrong; ``field``, ``value`` and ``limit`` when one input is."""

    detail: str
    field: str | None = None
    value: Any = None
    limit: str | None = None
    errors: list[dict] | None = None


class TestOut(BaseModel):
    """A test record (``GET /api/tests/{id}``)."""

    __test__ = False
    model_config = ConfigDict(extra="allow")

    id: int
    rig_name: str  # the rig it runs on (the service's --rig-name; several rigs may share the database)
    status: Literal["ready", "running", "completed", "stopped", "aborted", "interrupted", "failed"]
    reason: str | None
    label: str
    specimen_id: str = ""
    operator_name: str = ""
    notes: str = ""
    created_at: str | None
    started_at: str | None
    ended_at: str | None
    isolator: str
    supply_bar: float
    vertical_load_n: float | None
    controller: str
    speed: float
    driver: str
    rig: str | None = None  # the rig description the service ran with (settings.rig_file), None before they existed
    #: that rig file: name, source, what it changes, its commissioning (sim.rigfile); None before they were kept
    rig_file: dict | None = None
    profile: dict | None
    limits: dict
    duration_s: float
    cycles_total: int
    cycles_done: int
    time_s: float
    progress: float
    samples_stored: int
    scenario: dict
    summary: dict | None
    archived: dict | None = None
    review: dict | None = Field(None, description="state (unreviewed, approved, rejected), by, at, note, and for an "
                                "approved record the SHA-256 it was approved with (backend.review)")
    events: list[dict] | None = None


class IsolatorOut(BaseModel):
    model_config = ConfigDict(extra="allow")

    name: str
    source: Literal["preset", "user"]
    rho_bw_per_m: float
    sigma_bw: float
    n: float
    kd_n_per_m: float
    kw_n: float
    description: str = ""
    design_vertical_load_n: float | None = None


ERROR_RESPONSES = {
    401: {"model": ErrorOut, "description": "not logged in, or the credential is not valid"},
    403: {"model": ErrorOut, "description": "the account's role does not allow this (or a cross-site request)"},
    404: {"model": ErrorOut, "description": "no such record"},
    409: {"model": ErrorOut, "description": "not allowed in the current state"},
    422: {"model": ErrorOut, "description": "invalid input: names the field, the value and the limit"},
}


class MoveIn(StrictModel):
    """``POST /api/rig/move`` (``/api/rig/zero``: position 0): move the table under control when no test runs."""

    position_m: float = Field(0.0, description="where to move the table, m (within the stroke and the "
                                               "displacement limit)")
    speed_m_per_s: MoveSpeed = Field(0.005, description=f"peak speed of the move, m/s ({MIN_SPEED_M_PER_S:g} to "
                                     f"{MAX_SPEED_M_PER_S:g}; a move lasts at most {MAX_DURATION_S:g} s)")
    isolator: str = Field(min_length=1, max_length=64, description="the isolator mounted (a preset or user isolator)")
    supply_bar: float = Field(description="supply pressure in bar")
    vertical_load_n: float | None = Field(None, description="vertical load in N (default as for a test)")
    limits: LimitsIn | None = Field(None, description="the same limits as a test's (default: the rig's)")
    operator_name: str = Field("", max_length=64, description="who moves the table")


class CommissioningIn(StrictModel):
    """``POST /api/commissioning``: commission the rig (sim.commission): a bounded excitation about where the
    table rests, then a fit of the rig's parameters; SI units."""

    supply_bar: float = Field(description="supply pressure of the run in bar")
    isolator: str = Field("none", min_length=1, max_length=64, description="the specimen mounted: none (default), "
                          "a preset or a user isolator; its force is measured, not assumed")
    vertical_load_n: float | None = Field(None, description="vertical load in N (default: the specimen's design "
                                          "load; 0 with no specimen)")
    max_stroke_m: float = Field(0.002, description="the table stays within this of where it rests, m "
                                                   "(0.0002 to 0.01)")
    max_velocity_m_per_s: float = Field(0.02, description="... and below this velocity, m/s (0.01 to 0.1)")
    operator_name: str = Field("", max_length=64, description="who commissions the rig")
    speed: SpeedFactor = Field(1.0, description=f"simulated rig only: time scale of the run ({MIN_SPEED:g} to the "
                               "service's max_speed; a real rig runs at 1)")


class ApplyRigIn(StrictModel):
    """``POST /api/commissioning/{id}/apply``: who makes the commissioned rig file the service's rig."""

    operator_name: str = Field("", max_length=64, description="who applies it (default: the token's holder)")
