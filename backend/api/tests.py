"""Tests: create, list, read, start (role operator), stop/abort (anyone), cycles, samples as CSV, reports, delete."""

from __future__ import annotations

import io
from dataclasses import dataclass
from datetime import datetime
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Body, Path, Query, Request
from fastapi.responses import Response, StreamingResponse

from sim.controllers import CONTROLLER_NAMES, make_controller
from sim.engine import Scenario
from sim.errors import FieldError
from sim.follow import commissioning_facts
from sim.isolator import IsolatorError
from sim.profiles import ProfileError, SineProfile, max_amplitude_m, max_frequency_hz, motion_summary
from sim.records import column_labels
from sim.rig import BAR_PA, RigParameters
from sim.samples import RECORD_FIELDS, Samples
from sim.tracking import cycle_windows

from .. import earthquake_view, review, store
from .. import lab as lab_settings
from ..errors import ApiError, ProtocolError, _jsonable
from ..safety import make_limits
from ..schemas import (
    EARTHQUAKE_PROFILES,
    ERROR_RESPONSES,
    ApproveIn,
    ArchiveIn,
    EnvelopeCheckOut,
    ProtocolProfileIn,
    RejectIn,
    SineProfileIn,
    TestCreate,
    TestOut,
    ToleranceIn,
)
from ..settings import MIN_SPEED
from ..store import clean_json
from .deps import AdminDep, AnyoneDep, ApproverDep, OperatorDep, SessionDep, TestId, acting_name, not_found
from .isolators import resolve_isolator

router = APIRouter(tags=["tests"])

Status = Literal["ready", "running", "completed", "stopped", "aborted", "interrupted", "failed"]
ReviewState = Literal["unreviewed", "approved", "rejected"]


def profile_blocks(profile: SineProfileIn | ProtocolProfileIn) -> list[SineProfile]:
    """The profile's sine blocks, parsed by the one profile parser (sim.protocols.profile_from_spec); a
    protocol is named among the shipped ones (never a path on the server) or given inline."""
    try:
        from sim.protocols import profile_from_spec
    except ImportError:
        raise ApiError(422, "profile kind 'protocol' is not available in this version (sim.protocols missing)",
                       "profile.kind", "protocol", "sine") from None
    blocks, _protocol = profile_from_spec(profile.model_dump())
    return list(blocks)


def earthquake_profile(body: TestCreate, isolator, rig):
    """A history or hybrid profile built by the one profile parser (sim.protocols.profile_from_spec, which hands
    it to sim.earthquake), with the vertical load it runs under: the request's, else for a hybrid test the
    building's weight, else the isolator's design load or the rig's default. Refusals name the field."""
    from sim.earthquake import structure_weight_n, too_heavy_for_the_jack
    from sim.profiles import check_vertical_load
    from sim.protocols import profile_from_spec

    spec = body.profile.model_dump()  # non-finite samples stay what they are: sim names them
    load = body.vertical_load_n
    if load is None:
        weight = structure_weight_n(spec)
        if weight is not None:
            why = too_heavy_for_the_jack(weight, rig.max_vertical_load_n)
            if why is not None:  # the user never set vertical_load_n: say where the load came from
                raise ApiError(422, why, "vertical_load_n", weight, f"[0, {rig.max_vertical_load_n:g}] N")
            load = weight
        else:
            load = Scenario(isolator, body.supply_bar * BAR_PA, [], rig=rig).effective_vertical_load_n
    check_vertical_load(load, rig)
    _blocks, profile = profile_from_spec(spec, isolator, load)
    return profile, load


@dataclass(frozen=True)
class TestEnv:
    """What building a test takes from the service, as plain data (a check builds it in a worker process)."""

    __test__ = False  # not a pytest test class
    max_speed: float
    max_test_duration_s: float
    driver: str
    rig: RigParameters
    rig_description: object  # sim.rigfile.RigDescription


def test_env(request: Request) -> TestEnv:
    state = request.app.state
    return TestEnv(state.settings.max_speed, state.settings.max_test_duration_s, state.service.driver, state.rig,
                   state.rig_description)


def build_test(isolator, body: TestCreate, env: TestEnv) -> dict:
    """Everything a test record needs, validated against the rig envelope (errors name field and limit). A
    history or hybrid test's built profile comes back under ``_earthquake`` (not a record field)."""
    if body.controller not in CONTROLLER_NAMES:
        raise ApiError(422, f"controller {body.controller!r} is unknown; allowed: {', '.join(CONTROLLER_NAMES)}",
                       "controller", body.controller, ", ".join(CONTROLLER_NAMES))
    options = dict(body.controller_options or {})
    # ControllerOptionError (422) names the option and its range; on the rig in force, so that a servo that cannot
    # keep its loop's margin there (sim.controllers.servo.loop_design) is refused before anything moves
    make_controller(body.controller, rig=env.rig, **options)
    if not (MIN_SPEED <= body.speed <= env.max_speed):  # the schema bounds it to [MIN_SPEED, MAX_SPEED_LIMIT]
        raise ApiError(422, f"speed = {body.speed:g} is outside [{MIN_SPEED:g}, {env.max_speed:g}] (this service's "
                            "max_speed)", "speed", body.speed, f"[{MIN_SPEED:g}, {env.max_speed:g}]")
    from ..drivers import SIMULATED

    if body.speed != 1.0 and env.driver != SIMULATED:
        raise ApiError(422, f"the rig {env.driver} runs in real time: speed must be 1", "speed", body.speed, "1")
    earthquake = None
    if isinstance(body.profile, EARTHQUAKE_PROFILES):
        earthquake, load = earthquake_profile(body, isolator, env.rig)
        blocks = []
        scenario = Scenario(isolator, body.supply_bar * BAR_PA, [], body.controller, options,
                            rig=env.rig, vertical_load_n=load, history=earthquake.target)
    else:
        blocks = profile_blocks(body.profile)
        scenario = Scenario(isolator, body.supply_bar * BAR_PA, blocks, body.controller, options,
                            rig=env.rig, vertical_load_n=body.vertical_load_n)
    scenario.validate()  # ProfileError -> 422 with field, value, limit (vertical_load_n among them)
    if scenario.duration_s > env.max_test_duration_s:
        raise ApiError(422, f"the profile lasts {scenario.duration_s:g} s, longer than the allowed "
                            f"{env.max_test_duration_s:g} s", "profile", scenario.duration_s,
                       f"<= {env.max_test_duration_s:g} s")
    limits = make_limits(env.rig, body.limits.model_dump() if body.limits else None)
    job_scenario = {"isolator": isolator.to_dict(), "supply_pa": scenario.supply_pa,
                    "vertical_load_n": scenario.effective_vertical_load_n,
                    "profile": [b.to_dict() for b in blocks], "controller": body.controller,
                    "controller_options": options, "rig_changes": scenario.describe()["rig_changes"],
                    # the commissioned latency's uncertainty and the follow monitor's advice (sim.follow)
                    "rig_commissioning": commissioning_facts(getattr(env.rig_description, "commissioning", None))}
    asked = body.model_dump(mode="json")
    if earthquake is not None:  # the spec as asked rebuilds the target (the worker); the record shows it built
        job_scenario["earthquake"] = asked["profile"]
        job_scenario["earthquake_fingerprint"] = earthquake.fingerprint
        asked["profile"] = clean_json(earthquake.description)
    return {
        "label": body.label, "specimen_id": body.specimen_id.strip(), "operator_name": body.operator_name.strip(),
        "notes": body.notes, "isolator": isolator.name, "supply_bar": body.supply_bar,
        "vertical_load_n": scenario.effective_vertical_load_n,
        "controller": body.controller, "speed": body.speed, "driver": env.driver,
        "request": {**asked, "job_scenario": job_scenario, "rig_name": env.rig_description.name,
                    "rig_file": clean_json(env.rig_description.to_dict())},
        "scenario": clean_json(scenario.describe()), "limits": limits.to_dict(),
        "duration_s": scenario.duration_s, "cycles_total": len(cycle_windows(scenario)),
        "_earthquake": earthquake,
    }


def isolator_or_refusal(session, name: str):
    """(the isolator, None), or (None, the refusal a check answers with) if the name is unknown or bad."""
    try:
        return resolve_isolator(session, name), None
    except ApiError as exc:
        return None, {"detail": exc.detail, "field": exc.field, "value": _jsonable(exc.value), "limit": exc.limit}
    except IsolatorError as exc:
        return None, {"detail": str(exc), "field": "isolator"}


def envelope_check(body: TestCreate, isolator, isolator_refusal: dict | None, env: TestEnv) -> dict:
    """The answer of POST /api/tests/check (a plain function: a history or hybrid profile is built in a check
    worker process, backend.checks)."""
    earthquake, load = None, None
    refusal = isolator_refusal
    if refusal is None:
        try:
            fields = build_test(isolator, body, env)
            earthquake, load = fields["_earthquake"], fields["vertical_load_n"]
        except FieldError as exc:  # the envelope, a controller option
            field = exc.field
            if isinstance(exc, ProfileError) and isinstance(body.profile, EARTHQUAKE_PROFILES) \
                    and field not in ("supply_bar", "vertical_load_n"):
                field = f"profile.{field}"  # as POST /api/tests names it
            refusal = {"detail": str(exc), "field": field, "value": _jsonable(exc.value), "limit": exc.limit}
        except ApiError as exc:
            refusal = {"detail": exc.detail, "field": exc.field, "value": _jsonable(exc.value), "limit": exc.limit}
        except (IsolatorError, ProtocolError) as exc:
            refusal = {"detail": str(exc), "field": "profile" if isinstance(exc, ProtocolError) else "isolator"}
    out = {"ok": refusal is None, **(refusal or {"detail": "within the rig envelope"})}
    rig = env.rig
    if refusal is None and earthquake is not None:  # what the history asks of the rig (hybrid: as predicted)
        from sim.history import history_motion_summary

        out.update(history_motion_summary(earthquake.target, rig.with_changes(vertical_load_n=load), isolator))
        out["profile"] = clean_json(earthquake.description)
    elif refusal is None:  # what the motion asks of the rig, for the confirmation before the valve opens
        blocks = profile_blocks(body.profile)
        scenario = Scenario(isolator, body.supply_bar * BAR_PA, blocks, rig=rig,
                            vertical_load_n=body.vertical_load_n)
        loaded = rig.with_changes(vertical_load_n=scenario.effective_vertical_load_n)
        out.update(motion_summary(blocks, loaded, scenario.isolator))
    supply_pa = body.supply_bar * BAR_PA
    if rig.min_supply_pa <= supply_pa <= rig.max_supply_pa:
        out["max_force_n"] = rig.max_force_n(supply_pa)
        out["max_pull_force_n"] = rig.max_pull_force_n(supply_pa)
        out["max_vertical_load_n"] = rig.max_vertical_load_n
        if isinstance(body.profile, SineProfileIn) and isolator is not None:
            out["max_amplitude_m"] = max_amplitude_m(body.profile.frequency_hz, rig, isolator, supply_pa)
            f_max = max_frequency_hz(body.profile.amplitude_m, rig, isolator, supply_pa)
            out["max_frequency_hz"] = f_max if f_max > 0 else None  # None: no frequency fits this amplitude
    return out


def first_cycle_prediction(body: TestCreate, isolator, env: TestEnv) -> dict:
    """What the test's first cycle is expected to trip (sim.detectors.predict_first_trip: the taper-in and the
    first steady cycle on the rig model, with the test's controller and limits and the service's detectors),
    as the check's ``warnings``, ``predicted_trip`` and ``prediction`` (a plain function: run in a check
    worker process, backend.checks, whose engine is loaded)."""
    from sim.detectors import first_cycle_s, predict_first_trip

    scenario, limits = _scenario_and_limits(body, isolator, env)
    predicted = predict_first_trip(scenario, limits)
    window_s = first_cycle_s(scenario)
    simulated = (f"the first {window_s:.3g} s (the taper-in and the first steady cycle) simulated with the "
                 f"{body.controller} controller on the rig model, with the test's limits")
    if predicted is None:
        return {"prediction": f"{simulated}: no limit trips", "predicted_trip": None, "warnings": []}
    out = {"prediction": f"{simulated}: {predicted.trip.message}", "predicted_trip": clean_json(predicted.to_dict()),
           "warnings": [predicted.warning()]}
    refusal = start_refusal(body, isolator, env)
    if refusal is not None:  # a start a taper would cure: refused, as POST /api/tests refuses it
        field, value, limit, detail = refusal
        out.update(ok=False, detail=detail, field=field, value=value, limit=limit, warnings=[])
    return out


def _scenario_and_limits(body: TestCreate, isolator, env: TestEnv):
    scenario = Scenario(isolator, body.supply_bar * BAR_PA, profile_blocks(body.profile), body.controller,
                        dict(body.controller_options or {}), rig=env.rig, vertical_load_n=body.vertical_load_n)
    return scenario, make_limits(env.rig, body.limits.model_dump() if body.limits else None)


def untapered_start(body: TestCreate) -> bool:
    """A sine or protocol test whose first block has no taper: its target starts at full velocity from rest."""
    if isinstance(body.profile, EARTHQUAKE_PROFILES):
        return False
    blocks = profile_blocks(body.profile)
    return bool(blocks) and blocks[0].taper_cycles == 0


def start_refusal(body: TestCreate, isolator, env: TestEnv) -> tuple | None:
    """(field, value, limit, message) of a start refused by sim.profiles.start_problem (an untapered sine whose
    catch-up is expected to trip a limit that a taper would not), else None; plain values, so that a check
    worker hands them back (a FieldError does not survive pickling). A plain function: run in a check worker."""
    from sim.profiles import start_problem

    if not untapered_start(body):
        return None
    problem = start_problem(*_scenario_and_limits(body, isolator, env))
    return None if problem is None else (problem.field, problem.value, problem.limit, str(problem))


def check_start(body: TestCreate, isolator, env: TestEnv, checks) -> None:
    """POST /api/tests: refuse (422, ``profile.taper_cycles``) a start the set-up check refuses; simulated in the
    check pool (a busy pool: 503 with Retry-After), only for an untapered start."""
    if not untapered_start(body):
        return
    refusal = checks.run("check a test's start", start_refusal, body, isolator, env, small=True)
    if refusal is not None:
        raise ProfileError(*refusal[:3], refusal[3])


def with_first_cycle_prediction(out: dict, body: TestCreate, isolator, env: TestEnv, checks) -> dict:
    """A check that fits, with what its first cycle is expected to trip (a sine or protocol test; in the check
    pool: its cost is bounded there, a few milliseconds of the engine). A busy pool leaves the prediction out
    and says so."""
    if not out.get("ok") or isinstance(body.profile, EARTHQUAKE_PROFILES):
        if out.get("ok"):
            out["prediction"] = "not run: a time history has no first cycle to predict"
        return out
    try:
        out.update(checks.run("predict a test's first cycle", first_cycle_prediction, body, isolator, env,
                              small=True))
    except ApiError as exc:
        if exc.status != 503:
            raise
        out["prediction"] = f"not run: {exc.detail}"
    return out


@router.post("/api/tests/check", summary="Check a test against the rig envelope without creating it (no login)",
             responses={**ERROR_RESPONSES, 503: {"description": "busy: too many history or hybrid checks at once "
                                                 "(Retry-After)"}})
def check_test(body: TestCreate, request: Request, session: SessionDep) -> EnvelopeCheckOut:
    """Answers 200 either way (``ok`` says which), so a form can ask at every keystroke; nothing is stored. A
    history or hybrid profile is built in a check worker process (backend.checks: a few at a time, 503 with
    Retry-After beyond); there too a sine or protocol test that fits has its first cycle simulated: a trip
    expected there comes back in ``warnings`` (for the confirmation) and ``predicted_trip``."""
    isolator, refusal = isolator_or_refusal(session, body.isolator)
    env = test_env(request)
    if refusal is None and isinstance(body.profile, EARTHQUAKE_PROFILES):
        out = request.app.state.checks.run(f"build a {body.profile.kind} profile", envelope_check, body, isolator,
                                           refusal, env)
    else:
        out = envelope_check(body, isolator, refusal, env)
    return EnvelopeCheckOut(**with_first_cycle_prediction(out, body, isolator, env, request.app.state.checks))


@router.post("/api/tests", status_code=201, summary="Create a test (role operator); status 'ready' (start=true: "
             "and start it, or leave nothing behind)", responses=ERROR_RESPONSES)
def create_test(body: TestCreate, request: Request, session: SessionDep, actor: OperatorDep,
                start: Annotated[bool, Query(description="start it at once; if the start is refused, nothing "
                                                         "is kept")] = False) -> TestOut:
    isolator, env = resolve_isolator(session, body.isolator), test_env(request)
    fields = build_test(isolator, body, env)
    check_start(body, isolator, env, request.app.state.checks)  # after the envelope: a start that would trip
    fields.pop("_earthquake")
    fields["operator_name"] = acting_name(actor, body.operator_name, "operator_name")
    rig_name = request.app.state.service.rig_name  # a test of this service's rig
    test = store.create_test(session, rig_name=rig_name, **fields)
    store.add_event(session, test.id, "operator", f"test {test.id} created by {actor}", {"action": "create"},
                    actor=actor)
    session.commit()
    if start:
        test_id = test.id
        try:
            request.app.state.service.start(test_id, actor)
        except BaseException:  # refused (another test runs, the rig does not answer ...): leave no orphan behind
            session.rollback()
            stale = store.get_test(session, test_id)
            if stale is not None and stale.status == "ready":
                store.delete_test(session, stale)
                store.add_event(session, test_id, "operator", f"test {test_id} not kept: its start was refused",
                                {"action": "discard"}, actor=actor, rig_name=rig_name)
                session.commit()
            raise
        session.expire_all()
        test = store.get_test(session, test_id)
    return store.test_record(session, test)


@router.get("/api/tests", summary="Tests of every rig, newest first; filter by rig, status, isolator, creation date",
            responses=ERROR_RESPONSES)
def list_tests(session: SessionDep,
               rig_name: Annotated[str | None, Query(max_length=64, description="only this rig's tests (GET "
                                                                                 "/api/rigs names them)")] = None,
               status: Annotated[Status | None, Query(description="only tests with this status")] = None,
               archived: Annotated[bool, Query(description="the archived tests instead")] = False,
               isolator: Annotated[str | None, Query(max_length=64)] = None,
               since: Annotated[datetime | None, Query(description="created at or after (ISO 8601)")] = None,
               until: Annotated[datetime | None, Query(description="created at or before (ISO 8601)")] = None,
               limit: Annotated[int, Query(ge=1, le=1000)] = 100,
               offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
               review: Annotated[ReviewState | None, Query(description="only records in this review state")] = None,
               ) -> list[TestOut]:
    tests = store.list_tests(session, status, isolator, since, until, limit, offset, archived, review,
                             rig_name=rig_name)
    return [store.test_record(session, t, with_events=False) for t in tests]


CSV_FORMATS = ["%.9g"] + ["%.7g"] * (len(RECORD_FIELDS) - 1)  # stored samples keep 7 significant digits


def samples_csv(block: Samples, header: bool, controller: str | None = None) -> str:
    """CSV text of the record fields (as ``isorig simulate`` writes them, the header labelled for the test's
    ``controller``: sim.records.column_labels; NaN -> empty cell)."""
    buf = io.StringIO()
    if header:
        buf.write(",".join(column_labels(controller)) + "\n")
    if len(block):
        np.savetxt(buf, block.select(RECORD_FIELDS), fmt=CSV_FORMATS, delimiter=",")
    return buf.getvalue().replace("nan", "")


def _unlocked(test, action: str) -> None:
    try:
        review.check_unlocked(test, action)
    except review.ReviewError as exc:
        raise ApiError(exc.status, exc.detail) from None


def _test_or_404(session, test_id: int):
    test = store.get_test(session, test_id)
    if test is None:
        raise not_found(f"test {test_id}")
    return test


@router.get("/api/tests/{test_id}", summary="One test: status, scenario, summary metrics, events",
            responses=ERROR_RESPONSES)
def get_test(test_id: TestId, session: SessionDep) -> TestOut:
    return store.test_record(session, _test_or_404(session, test_id))


def _record_after(session, test_id: int, action) -> TestOut:
    """Run an operator action on an existing test and answer with its record as it is afterwards."""
    _test_or_404(session, test_id)
    action()
    session.expire_all()
    return store.test_record(session, _test_or_404(session, test_id))


@router.post("/api/tests/{test_id}/start", summary="Start a ready test (role operator)", responses=ERROR_RESPONSES)
def start_test(test_id: TestId, request: Request, session: SessionDep, actor: OperatorDep) -> TestOut:
    return _record_after(session, test_id, lambda: request.app.state.service.start(test_id, actor))


@router.post("/api/tests/{test_id}/stop", summary="Stop the running test with a ramp-out (no token needed: "
             "ending a test is never refused; who asked is recorded)", responses=ERROR_RESPONSES)
def stop_test(test_id: TestId, request: Request, session: SessionDep, actor: AnyoneDep) -> TestOut:
    return _record_after(session, test_id, lambda: request.app.state.service.command(test_id, "stop", actor))


@router.post("/api/tests/{test_id}/abort", summary="Abort the running test at once (no token needed, like an "
             "emergency stop; who asked is recorded); answers once it has ended",
             responses={**ERROR_RESPONSES, 202: {"description": "the abort is under way but the test had not ended "
                                                 "within abort_wait_s: follow the Location (the record)"}})
def abort_test(test_id: TestId, request: Request, response: Response, session: SessionDep,
               actor: AnyoneDep) -> TestOut:
    """200 with the final record once the test has ended (its worker gone, the rig free for the next test),
    waiting at most ``abort_wait_s`` (5 s); if it has not ended by then, 202 with the record as it is and
    ``Location: /api/tests/{id}`` to poll until its status is final."""
    service = request.app.state.service

    def abort() -> None:
        service.command(test_id, "abort", actor)
        if not service.wait_ended(test_id, request.app.state.settings.abort_wait_s):
            response.status_code = 202
            response.headers["Location"] = f"/api/tests/{test_id}"

    return _record_after(session, test_id, abort)


def _is_running(test, request: Request) -> bool:
    """The record says running, or the service is starting it. The record's end is committed (everything of
    it written) before the service lets go of the run: an ended record is not running."""
    starting = test.status == "ready" and request.app.state.service.running_test_id() == test.id
    return test.status == "running" or starting


@router.delete("/api/tests/{test_id}", status_code=204, summary="Delete a test that never ran (role operator)",
               responses=ERROR_RESPONSES)
def delete_test(test_id: TestId, request: Request, session: SessionDep, actor: OperatorDep) -> Response:
    """Only a test that never ran (status ``ready``) is erased; the record of a test that ran is a lab's
    record: archive it (``POST /api/tests/{id}/archive``, who and why), never erase it."""
    test = _test_or_404(session, test_id)
    if _is_running(test, request):
        raise ApiError(409, f"test {test_id} is running; stop or abort it before deleting it")
    rig_name = request.app.state.service.rig_name
    if test.rig_name != rig_name:  # its own service may be starting it now
        raise ApiError(409, f"test {test_id} belongs to the rig {test.rig_name!r}; this service drives the rig "
                            f"{rig_name!r}: delete it from the service of {test.rig_name!r}", "rig_name",
                       test.rig_name, rig_name)
    if test.status != "ready":
        raise ApiError(409, f"test {test_id} ran ({test.status}): its record is kept; archive it instead with "
                            f"POST /api/tests/{test_id}/archive and {{\"reason\": <why>}}",
                       "status", test.status, "ready (a test that never ran)")
    store.delete_test(session, test)
    store.add_event(session, test_id, "operator", f"test {test_id} deleted by {actor}", {"action": "delete"},
                    actor=actor, rig_name=rig_name)
    session.commit()
    request.app.state.hub.forget(test_id)
    return Response(status_code=204)


@router.post("/api/tests/{test_id}/archive", summary="Archive a test that ran: hidden from the list, kept, "
             "restorable (role operator)", responses=ERROR_RESPONSES)
def archive_test(test_id: TestId, body: ArchiveIn, request: Request, session: SessionDep,
                 actor: OperatorDep) -> TestOut:
    test = _test_or_404(session, test_id)
    if _is_running(test, request):
        raise ApiError(409, f"test {test_id} is running; it can be archived once it has ended")
    if test.archived_at is not None:
        raise ApiError(409, f"test {test_id} is archived already (by {test.archived_by})")
    _unlocked(test, "archived")
    by = acting_name(actor, body.by, "by")
    store.archive_test(session, test, by, body.reason)
    store.add_event(session, test_id, "operator", f"test {test_id} archived by {by}: {body.reason}",
                    {"action": "archive", "by": by, "reason": body.reason}, actor=actor)
    session.commit()
    return store.test_record(session, test)


@router.post("/api/tests/{test_id}/restore", summary="Restore an archived test (role operator)",
             responses=ERROR_RESPONSES)
def restore_test(test_id: TestId, body: ArchiveIn, session: SessionDep, actor: OperatorDep) -> TestOut:
    test = _test_or_404(session, test_id)
    if test.archived_at is None:
        raise ApiError(409, f"test {test_id} is not archived")
    _unlocked(test, "restored")
    by = acting_name(actor, body.by, "by")
    store.restore_test(session, test)
    store.add_event(session, test_id, "operator", f"test {test_id} restored by {by}: {body.reason}",
                    {"action": "restore", "by": by, "reason": body.reason}, actor=actor)
    session.commit()
    return store.test_record(session, test)


def _reviewed(session, test_id: int, decide) -> TestOut:
    """Approve or reject (``decide(test)``, backend.review) and answer with the record as it is then; a refusal
    (or a report that cannot be made) leaves nothing changed."""
    test = _test_or_404(session, test_id)
    try:
        decide(test)
    except review.ReviewError as exc:
        session.rollback()
        raise ApiError(exc.status, exc.detail) from None
    session.commit()
    return store.test_record(session, test)


def _approval_renderer(session, request: Request):
    """``render_report`` for backend.review.approve: the PDF as it is served, with the lab's header, units and
    tolerances as they are now; None for a record that has no report (a manual move, a commissioning)."""
    reports = _reports()
    from ..reports.design import with_tolerances

    lab = with_tolerances(session, lab_settings.header(session, request.app.state.settings))

    def render(test):
        kind = (test.request.get("profile") or {}).get("kind")
        if kind in ("move", "commissioning"):
            return None
        pdf = reports.report_pdf_bytes(store.load_test_bundle(session, test.id), lab=lab)
        return pdf, lab.name or "", lab.units

    return render


@router.post("/api/tests/{test_id}/approve", summary="Approve a record that has ended (role approver, not who ran "
             "it): it is locked, its SHA-256 kept, and its report rendered and kept as served from then on",
             responses=ERROR_RESPONSES)
def approve_test(test_id: TestId, request: Request, session: SessionDep, actor: ApproverDep,
                 body: Annotated[ApproveIn | None, Body()] = None) -> TestOut:
    """The report PDF is made now (the lab's header and units as they are) and stored with its SHA-256
    (``review.report_sha256``); ``GET /api/tests/{id}/report.pdf`` serves those bytes from then on. A report that
    cannot be made refuses the approval (422) and changes nothing."""
    note = body.note if body else ""
    render = _approval_renderer(session, request)
    return _reviewed(session, test_id, lambda test: review.approve(session, test, actor.name, note, render))


@router.post("/api/tests/{test_id}/reject", summary="Reject a record, with the reason (role approver, not who ran "
             "it)", responses=ERROR_RESPONSES)
def reject_test(test_id: TestId, body: RejectIn, session: SessionDep, actor: ApproverDep) -> TestOut:
    return _reviewed(session, test_id, lambda test: review.reject(session, test, actor.name, body.reason))


@router.get("/api/tests/{test_id}/approval", summary="The record's review, and for an approved one its SHA-256 "
            "recomputed now against the approved one (intact: true when they agree)", responses=ERROR_RESPONSES)
def get_approval(test_id: TestId, session: SessionDep) -> dict:
    return review.verify(session, _test_or_404(session, test_id))


@router.get("/api/tests/{test_id}/cycles", summary="Per-cycle loop metrics (arrays=true adds the loops)",
            responses=ERROR_RESPONSES)
def get_cycles(test_id: TestId, session: SessionDep, arrays: bool = False) -> list[dict]:
    _test_or_404(session, test_id)
    cycles = store.load_cycles(session, test_id, arrays=arrays)
    for c in cycles:
        for key in ("displacement_m", "force_n"):
            if key in c:
                c[key] = c[key].tolist()
    return clean_json(cycles)


@router.get("/api/tests/{test_id}/data.csv", summary="All samples as CSV (the columns of isorig simulate; model_m, "
            "ar_hat, ay_hat, as_hat labelled 'KEY: NAME (UNIT)' where the test's controller puts another quantity "
            "there than the MRAC's)",
            response_class=StreamingResponse, responses=ERROR_RESPONSES)
def get_csv(test_id: TestId, request: Request, session: SessionDep) -> StreamingResponse:
    controller = _test_or_404(session, test_id).controller
    sessions = request.app.state.sessions

    def generate():
        with sessions() as s:
            yield samples_csv(Samples.empty(), header=True, controller=controller)
            for block in store.iter_sample_blocks(s, test_id):
                yield samples_csv(block, header=False)

    return StreamingResponse(generate(), media_type="text/csv",
                             headers={"Content-Disposition": f'attachment; filename="test-{test_id}.csv"'})


@router.get("/api/tests/{test_id}/earthquake", summary="A history or hybrid test: the planned target, and once it "
            "ran the J criteria, command and measurement, the structure beside its reference (thinned)",
            responses=ERROR_RESPONSES)
def get_earthquake(test_id: TestId, request: Request, session: SessionDep,
                   points: Annotated[int, Query(ge=100, le=200_000, description="at most this many points per "
                                                                                "series (every k-th sample)")] = 2000
                   ) -> dict:
    """``planned``: the target the test runs (a history) or the reference's base displacement it is predicted
    to command (a hybrid test), with the ground acceleration of a hybrid test, from the spec the test was created
    with. ``record`` (None before the test ran): sim.earthquake.record_figures on the stored samples (what the
    summary holds, computed again now) with ``series``: time, command, measurement and, for a hybrid test, the
    structure's channels replayed from the record and the reference's, every k-th sample so that no series has
    more than ``points``. While the test runs: ``so_far``, the stored samples' time, target and measurement at the
    planned series' step (what a page that joins late draws before the websocket's rows), and no figures.

    Rebuilding the profile and the figures takes seconds of CPU for a long test, and anyone may ask: it runs in the
    check pool (backend.checks: bounded, 503 when busy), and the answer for an ended test is kept
    (backend.earthquake_view.ViewCache), so asking again costs nothing."""
    test = _test_or_404(session, test_id)
    return earthquake_view.answer(request.app, session, test, points)


@router.get("/api/tests/{test_id}/acceptance", summary="A protocol test: its acceptance verdict, the verdict of "
            "each rule and cycle, and the figures of each level (steady cycles)", responses=ERROR_RESPONSES)
def get_acceptance(test_id: TestId, session: SessionDep) -> dict:
    """What the report's acceptance page says, without the report: ``verdict`` (PASSED, FAILED, INCOMPLETE or
    NO VERDICT), ``summary`` (verdicts, failed, the failing rules with their cycles), ``verdicts``, ``rules`` and
    ``levels`` (each level's amplitude, frequency and means of K_eff, EDC, xi_eff over its steady cycles), from
    the stored cycles (sim.protocols.evaluate_acceptance via backend.reports.content). 422 for a test that did not
    run a protocol."""
    test = _test_or_404(session, test_id)
    _reports()
    from ..reports.content import protocol_acceptance
    from ..reports.design import stored_tolerances
    from ..reports.lab import LabHeader

    out = protocol_acceptance(store.test_record(session, test, with_events=False),
                              store.load_cycles(session, test_id, arrays=False),
                              LabHeader(tolerances=stored_tolerances(session)))
    if out is None:
        raise ApiError(422, f"test {test_id} did not run a protocol: it has no acceptance rules", "test_id",
                       test_id, "a test with a protocol profile")
    return clean_json(out)


@router.get("/api/acceptance/tolerances", summary="The lab's tolerances against the specimen's design values, per "
            "protocol (EN 15129's type-test tolerances where the lab set none)", responses=ERROR_RESPONSES)
def get_tolerances(session: SessionDep) -> dict:
    """``default``: EN 15129's type-test tolerances (fractions: each test cycle's K_eff, EDC, xi_eff and each
    level's mean); ``protocols``: what the lab set, by protocol name."""
    from ..reports.design import DEFAULT_SOURCE, EN15129_TYPE_TEST, stored_tolerances

    return {"default": {**EN15129_TYPE_TEST, "source": DEFAULT_SOURCE}, "protocols": stored_tolerances(session)}


@router.put("/api/acceptance/tolerances/{protocol}", summary="Set a protocol's tolerances against design values "
            "(role admin); fractions: 0.15 is +-15 %", responses=ERROR_RESPONSES)
def put_tolerances(protocol: Annotated[str, Path(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")],
                   body: ToleranceIn, session: SessionDep, actor: AdminDep) -> dict:
    from ..reports.design import ToleranceError, set_tolerances

    try:
        set_tolerances(session, protocol, body.model_dump(), actor.name)
    except ToleranceError as exc:
        raise ApiError(422, str(exc), exc.field) from None
    session.commit()
    return get_tolerances(session)


@router.delete("/api/acceptance/tolerances/{protocol}", summary="Back to EN 15129's tolerances for a protocol "
               "(role admin)", responses=ERROR_RESPONSES)
def delete_tolerances(protocol: Annotated[str, Path(min_length=1, max_length=64)], session: SessionDep,
                      actor: AdminDep) -> dict:
    from ..reports.design import set_tolerances

    set_tolerances(session, protocol, None, actor.name)
    session.commit()
    return get_tolerances(session)


def _reportable(session, test_id: int):
    """The test, if a report can be made of it (404 unknown; 422 for a manual move, which has none)."""
    test = _test_or_404(session, test_id)
    kind = (test.request.get("profile") or {}).get("kind")
    if kind in ("move", "commissioning"):
        what = "a manual move of the table" if kind == "move" else \
            f"a commissioning of the rig (its result: GET /api/commissioning/{test_id})"
        raise ApiError(422, f"test {test_id} is {what}: it has no report; its record "
                            f"(GET /api/tests/{test_id}) and samples (data.csv) are kept", "test_id", test_id,
                       "a test that is not a manual move or a commissioning")
    return test


def _reports():
    try:
        from .. import reports
    except ImportError:
        raise ApiError(503, "reports are not available in this installation (backend.reports is missing)") from None
    return reports


@router.get("/api/tests/{test_id}/report.pdf", summary="The test report as PDF (an approved record: the PDF kept at "
            "its approval)", response_class=Response,
            responses={**ERROR_RESPONSES, 503: {"description": "reports not available"}})
def report_pdf(test_id: TestId, request: Request, session: SessionDep) -> Response:
    """An approved record's report is the PDF rendered at its approval, byte for byte (its SHA-256 in the
    ``X-Report-SHA256`` header and the record's ``review.report_sha256``); any other record's is made now."""
    test = _reportable(session, test_id)
    headers = {"Content-Disposition": f'inline; filename="test-{test_id}-report.pdf"'}
    kept = review.stored_report(session, test)
    if kept is not None:
        if review.sha256_of(kept.pdf) != test.report_sha256:
            raise ApiError(409, f"the report kept with test {test_id}'s approval no longer matches its SHA-256 "
                                f"{test.report_sha256}: it was changed in the database; it is not served",
                           "test_id", test_id)
        return Response(kept.pdf, media_type="application/pdf",
                        headers={**headers, "X-Report-SHA256": kept.sha256, "X-Report-Kept": "approval"})
    reports = _reports()
    from ..reports.design import with_tolerances

    buf = io.BytesIO()
    lab = with_tolerances(session, lab_settings.header(session, request.app.state.settings))
    reports.render_report_pdf(store.load_test_bundle(session, test_id), buf, lab=lab)
    return Response(buf.getvalue(), media_type="application/pdf", headers=headers)


@router.get("/api/tests/{test_id}/report.json", summary="The test report as JSON",
            responses={**ERROR_RESPONSES, 503: {"description": "reports not available"}})
def report_json(test_id: TestId, request: Request, session: SessionDep) -> dict:
    _reportable(session, test_id)
    reports = _reports()
    from ..reports.design import with_tolerances

    lab = with_tolerances(session, lab_settings.header(session, request.app.state.settings))
    return clean_json(reports.report_json(store.load_test_bundle(session, test_id), lab=lab))


@router.get("/api/tests/{test_id}/bundle.zip", summary="The whole test as a zip: record.json, report.json, "
            "samples.csv, cycles.csv, report.pdf", response_class=Response,
            responses={**ERROR_RESPONSES, 503: {"description": "reports not available"}})
def bundle_zip(test_id: TestId, request: Request, session: SessionDep) -> Response:
    """The record as GET /api/tests/{id}, the report (JSON and PDF, with the lab's header: backend.lab), every
    sample (the columns of data.csv) and every cycle with its phase (CSV, SI units), and a README. An approved
    record's report.pdf is the one kept at its approval."""
    test = _reportable(session, test_id)
    reports = _reports()
    from ..reports.design import with_tolerances

    lab = with_tolerances(session, lab_settings.header(session, request.app.state.settings))
    kept = review.stored_report(session, test)
    data = reports.bundle_zip_bytes(store.load_test_bundle(session, test_id), lab=lab,
                                    pdf=kept.pdf if kept is not None else None)
    return Response(data, media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="test-{test_id}-bundle.zip"'})


@router.get("/api/events", summary="The audit log: operator actions, limit trips, status changes",
            tags=["events"])
def list_events(session: SessionDep,
                test_id: Annotated[int | None, Query(ge=1, le=2**53)] = None,
                rig_name: Annotated[str | None, Query(
                    min_length=1, max_length=64,
                    description="only this rig's events (and those of no rig, such as an isolator added)")] = None,
                limit: Annotated[int, Query(ge=1, le=10000)] = 1000) -> list[dict]:
    """The newest ``limit`` events, oldest first: of one test, of one rig, or all."""
    return store.load_events(session, test_id, rig_name=rig_name, limit=limit)
