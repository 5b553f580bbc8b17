"""Commissioning through the service: the bounded excitation as a run of its own, the fit after it, the result.

A commissioning is a record like a manual move (profile kind ``commissioning``, controller ``excitation``):
the same worker, limits, stop paths, record and live stream as a test, the table held where it rests
(sim.commission.identify.excitation_scenario). When the run has ended the service fits its stored record
(sim.commission.identify.identify) in a thread of its own, off the event loop: the record's
``summary.commissioning`` says ``fitting``, then the result (``trusted``, ``not_trusted`` with each reason, or
``fit_failed`` with the error: the samples are kept either way), and an event says the verdict. A fit the
service did not finish (it stopped meanwhile) is done again at the next start. Numerics are sim's; here only
orchestration. Making a trusted rig file the service's rig is backend.rig_in_force.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from datetime import UTC, datetime

from sqlalchemy import select

from sim.commission import identify as commission
from sim.engine import Scenario
from sim.isolator import NO_SPECIMEN
from sim.rig import BAR_PA, DEFAULT_RIG
from sim.rigfile import rig_file_data

from . import store
from .errors import ApiError
from .models import FINAL_STATUSES, TestRecord, as_utc
from .safety import make_limits
from .store import clean_json

log = logging.getLogger("isorig.commissioning")

KIND = "commissioning"  # the profile kind of a commissioning record
CONTROLLER = "excitation"
PHASES = ("valve sweeps", "dither", "return", "rest", "valve null")  # the excitation's phase, its as_hat column (0-4)


def is_commissioning(test) -> bool:
    return ((test.request or {}).get("profile") or {}).get("kind") == KIND


def motion_words(conditions: commission.Conditions, duration_s: float) -> str:
    """What will move and why, in words (SI in the API; the console says it in its units)."""
    return (f"the table moves at most +-{conditions.max_stroke_m * 1e3:g} mm about where it rests "
            f"({conditions.start_m * 1e3:.2f} mm), below {conditions.max_velocity_m_per_s * 1e3:g} mm/s, for at most "
            f"{duration_s:.0f} s: the valve's null with the table held, valve sweeps, then a small dither, then back "
            "to where it rested; to measure the valve, the oil column, the moving mass and the sensor delay")


def build(session, body, request) -> dict:
    """The record of a commissioning run from where the table rests; refusals name the field (422) or say
    what the rig's state forbids (409)."""
    from .api.isolators import resolve_isolator
    from .drivers import SIMULATED
    from .settings import MIN_SPEED

    settings = request.app.state.settings
    service = request.app.state.service
    running = service.running_test_id()
    if running is not None:
        raise ApiError(409, f"test {running} is running; the rig is commissioned only when no test runs (nothing "
                            "moved)")
    if not (MIN_SPEED <= body.speed <= settings.max_speed):  # the schema bounds it to [MIN_SPEED, MAX_SPEED_LIMIT]
        raise ApiError(422, f"speed = {body.speed:g} is outside [{MIN_SPEED:g}, {settings.max_speed:g}] (this "
                            "service's max_speed)", "speed", body.speed, f"[{MIN_SPEED:g}, {settings.max_speed:g}]")
    if body.speed != 1.0 and service.driver != SIMULATED:
        raise ApiError(422, f"the rig {service.driver} runs in real time: speed must be 1", "speed", body.speed, "1")
    start_m = service.resting_position_m()
    if start_m is None and service.driver != SIMULATED:
        raise ApiError(409, f"the rig at {service.driver} does not answer: its table position is unknown, so it "
                            "cannot be commissioned about it (nothing moved)")
    start_m = float(start_m or 0.0)
    rig = request.app.state.rig
    isolator = NO_SPECIMEN if body.isolator == NO_SPECIMEN.name \
        else resolve_isolator(session, body.isolator)
    load_n = Scenario(isolator, body.supply_bar * BAR_PA, [], rig=rig,
                      vertical_load_n=body.vertical_load_n).effective_vertical_load_n
    conditions = commission.Conditions(service.driver, body.supply_bar * BAR_PA, load_n, isolator.name, start_m,
                                       body.max_stroke_m, body.max_velocity_m_per_s)
    scenario = commission.excitation_scenario(isolator, conditions, rig)  # CommissioningError (422) on bad bounds
    scenario.validate()  # supply pressure, vertical load within the rig (ProfileError: 422 with the field)
    limits = make_limits(rig, commission.excitation_limits(conditions))
    duration_s = scenario.duration_s
    profile = {"kind": KIND, "start_m": start_m, "max_stroke_m": body.max_stroke_m,
               "max_velocity_m_per_s": body.max_velocity_m_per_s, "duration_s": duration_s,
               "what": motion_words(conditions, duration_s)}
    job_scenario = {"isolator": isolator.to_dict(), "supply_pa": scenario.supply_pa, "vertical_load_n": load_n,
                    "profile": [], "controller": CONTROLLER, "controller_options": scenario.controller_options,
                    "commissioning": conditions.to_dict(), "rig_changes": scenario.describe()["rig_changes"]}
    described = request.app.state.rig_description
    return {
        "label": (f"commissioning +-{body.max_stroke_m * 1e3:g} mm about {start_m * 1e3:.2f} mm below "
                  f"{body.max_velocity_m_per_s * 1e3:g} mm/s"),
        "specimen_id": "", "operator_name": body.operator_name.strip(), "notes": "", "isolator": isolator.name,
        "supply_bar": body.supply_bar, "vertical_load_n": load_n, "controller": CONTROLLER, "speed": body.speed,
        "driver": service.driver,
        "request": {**body.model_dump(mode="json"), "profile": profile, "job_scenario": job_scenario,
                    "rig_name": described.name, "rig_source": described.source,
                    "rig_file": clean_json(described.to_dict())},
        "scenario": clean_json(scenario.describe()), "limits": limits.to_dict(),
        "duration_s": duration_s, "cycles_total": 0,
    }


def start(session, body, request, actor: str) -> dict:
    """Create the record and start it at once; a refused start leaves no record behind."""
    fields = build(session, body, request)
    test = store.create_test(session, rig_name=request.app.state.service.rig_name, **fields)
    store.add_event(session, test.id, "operator", f"commissioning {test.id} requested by {actor}: "
                    f"{fields['request']['profile']['what']}", {"action": "commission"}, actor=actor)
    session.commit()
    test_id = test.id
    try:
        request.app.state.service.start(test_id, actor)
    except BaseException:
        session.rollback()
        stale = store.get_test(session, test_id)
        if stale is not None and stale.status == "ready":
            store.delete_test(session, stale)
            session.commit()
        raise
    session.expire_all()
    return store.test_record(session, store.get_test(session, test_id))


# --- the fit after the run ---------------------------------------------------------------------------------

def rig_file_name(rig_name: str | None, date: str) -> str:
    """The commissioned rig file's name: the rig's, without an earlier commissioning's date, with this one's."""
    base = rig_name or "rig"
    while re.search(r" \((commissioned [^)]*|sim\.rig)\)$", base):  # "isorig default rig (sim.rig)" -> "isorig ..."
        base = re.sub(r" \((commissioned [^)]*|sim\.rig)\)$", "", base)
    return f"{base[:70]} (commissioned {date})"


class Fitter:
    """Fits each commissioning record once its run has ended, in a thread (one fit at a time)."""

    def __init__(self, service, sessions):
        self.service = service
        self.sessions = sessions
        self.lock = threading.Lock()  # one fit at a time: the fit takes a core for 5-20 s
        self.active: set[int] = set()

    def on_end(self, session, test, status: str, reason: str | None):
        """RigService end hook: a commissioning run's summary says ``fitting``; the fit starts once the end
        is committed."""
        if not is_commissioning(test):
            return None
        test.summary = {**(test.summary or {}), "commissioning": {"state": "fitting", "since": _now()}}
        return lambda: self.start(test.id)

    def start(self, test_id: int) -> None:
        self.active.add(test_id)
        threading.Thread(target=self.fit, args=(test_id,), daemon=True, name=f"isorig-fit-{test_id}").start()

    def resume(self) -> list[int]:
        """At service start: fit again every commissioning of this service's rig whose fit was not finished (the
        service stopped); another rig's are its own service's."""
        with self.sessions() as session:
            todo = [t.id for t in session.scalars(select(TestRecord).where(
                        TestRecord.controller == CONTROLLER, TestRecord.rig_name == self.service.rig_name))
                    if t.status in FINAL_STATUSES and is_commissioning(t)
                    and ((t.summary or {}).get("commissioning") or {}).get("state", "fitting") == "fitting"]
            for test_id in todo:
                test = store.get_test(session, test_id)
                test.summary = {**(test.summary or {}), "commissioning": {"state": "fitting", "since": _now(),
                                                                          "resumed": True}}
            session.commit()
        for test_id in todo:
            self.start(test_id)
        return todo

    def fit(self, test_id: int) -> None:
        """Fit the stored record; store the result (or what failed) in the summary, with an event."""
        with self.lock:
            t0 = time.monotonic()
            try:
                result = self._identify(test_id)
            except Exception as exc:  # the record keeps its samples; the summary says what failed
                log.exception("fit of commissioning %s", test_id)
                result = {"state": "fit_failed", "error": f"{type(exc).__name__}: {exc}",
                          "words": f"the fit failed ({type(exc).__name__}: {exc}); the record keeps every sample "
                                   "(data.csv) and no rig file was written"}
            result["fit_s"] = round(time.monotonic() - t0, 2)
            result["fitted_at"] = _now()
            try:
                self._store(test_id, result)
            finally:
                self.active.discard(test_id)

    def _identify(self, test_id: int) -> dict:
        with self.sessions() as session:
            test = store.get_test(session, test_id)
            spec = test.request["job_scenario"]
            status, reason = test.status, test.reason
            rig_name, source = test.request.get("rig_name"), test.request.get("rig_source") or "unknown"
            started = test.started_at or test.created_at
            driver = test.driver
            samples = store.load_samples(session, test_id)
        started = as_utc(started)
        conditions = commission.Conditions(**spec["commissioning"])
        declared = DEFAULT_RIG.with_changes(**spec["rig_changes"]) if spec.get("rig_changes") else DEFAULT_RIG
        ident = commission.identify(samples, declared, conditions)
        if status != "completed":
            ident.problems.insert(0, f"the run ended {status}" + (f": {reason}" if reason else ""))
        out = {"state": "trusted" if ident.trusted else "not_trusted", "identification": ident.to_dict(),
               "declared": commission.declared_values(ident) if ident.fit is not None else {}}
        if ident.trusted:
            date = started.date().isoformat()
            name = rig_file_name(rig_name, date)
            out["rig_file"] = rig_file_data(
                ident.rig, name, f"commissioned by the isorig service (commissioning {test_id}) on {driver} at "
                f"{date}", commission.provenance(ident, source, started), always=tuple(ident.changed()))
            r = ident.response
            out["words"] = (f"trusted: {len(ident.fit.estimates)} parameters fitted (flow balance R2 "
                            f"{ident.fit.flow_r2:.4f}, force balance R2 {ident.fit.force_r2:.3f}"
                            + (f", the fitted rig replays the velocity to {100 * r.velocity_nrmse:.1f} % RMS"
                               if r else "") + f"); the rig file '{name}' can be made the service's rig")
        else:
            out["words"] = "NOT trusted, no rig file: " + "; ".join(ident.problems)
            retry = ident.second_attempt()
            if retry is not None:
                out["words"] += (f". A second attempt may help: the same at max_velocity_m_per_s "
                                 f"{retry['max_velocity_m_per_s']:g}")
        return clean_json(out)

    def _store(self, test_id: int, result: dict) -> None:
        with self.sessions() as session:
            test = store.get_test(session, test_id)
            test.summary = {**(test.summary or {}), "commissioning": result}
            message = f"commissioning {test_id} {result['words']}"
            values = {"state": result["state"], "trusted": result["state"] == "trusted",
                      "problems": (result.get("identification") or {}).get("problems", [])}
            store.add_event(session, test_id, "commissioning", message, values, time_s=test.time_s)
            session.commit()
            time_s = test.time_s
        self.service.publish_event(test_id, time_s, "commissioning", message, values)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# --- what GET /api/commissioning/{id} answers ----------------------------------------------------------------

def state_of(test) -> str:
    """``ready``, ``running``, ``fitting``, ``trusted``, ``not_trusted`` or ``fit_failed``."""
    if test.status in ("ready", "running"):
        return test.status
    return ((test.summary or {}).get("commissioning") or {}).get("state", "fitting")


def result(session, test, fitter: Fitter | None = None) -> dict:
    """A commissioning's record in the page's terms: what ran, the state, the identification and the rig file."""
    c = dict((test.summary or {}).get("commissioning") or {})
    state = state_of(test)
    record = store.test_record(session, test, with_events=False)
    out = {"id": test.id, "status": test.status, "reason": test.reason, "state": state,
           "words": c.get("words") or {"ready": "not started", "running": "the excitation runs",
                                       "fitting": "the run has ended; fitting its record (5-20 s)"}.get(state, ""),
           "profile": record["profile"], "conditions": test.request["job_scenario"].get("commissioning"),
           "operator_name": test.operator_name, "isolator": test.isolator, "supply_bar": test.supply_bar,
           "vertical_load_n": test.vertical_load_n, "speed": test.speed, "driver": test.driver,
           "rig": record["rig"], "plant_changes": test.request.get("plant_changes") or {},
           "created_at": record["created_at"], "started_at": record["started_at"], "ended_at": record["ended_at"],
           "time_s": test.time_s, "duration_s": test.duration_s, "limits": test.limits,
           "identification": c.get("identification"), "declared": c.get("declared"),
           "error": c.get("error"), "fit_s": c.get("fit_s"), "fitted_at": c.get("fitted_at"),
           "applied": c.get("applied"), "record": f"/api/tests/{test.id}"}
    data = c.get("rig_file")
    out["rig_file"] = {"name": data["name"], "description": data.get("description", ""),
                       "download": f"/api/commissioning/{test.id}/rig.json"} if data else None
    return clean_json(out)


def rig_file_of(test) -> dict:
    """The trusted commissioning's rig file data, else ApiError 409 saying why there is none."""
    c = (test.summary or {}).get("commissioning") or {}
    state = state_of(test)
    if state == "trusted" and c.get("rig_file"):
        return c["rig_file"]
    if state in ("ready", "running", "fitting"):
        raise ApiError(409, f"commissioning {test.id} is {state}: its rig file exists once the fit is trusted")
    if state == "fit_failed":
        raise ApiError(409, f"commissioning {test.id} has no rig file: its fit failed ({c.get('error')})")
    problems = (c.get("identification") or {}).get("problems") or []
    raise ApiError(409, f"commissioning {test.id} is not trusted, so it has no rig file: " + "; ".join(problems))
