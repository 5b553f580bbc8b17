"""The report renderer warmed up in the background at the service's start (backend.reports.warm): on by default
(the setting report_warm_up; off in the other backend tests), once per process, never in the way of the service."""

from __future__ import annotations

import gc
import io
import threading

from conftest import create_and_start, make_settings, wait_for
from fastapi.testclient import TestClient

from backend.app import create_app
from backend.reports import warm
from backend.settings import Settings


def test_the_warm_up_is_on_by_default_and_runs_in_the_background(tmp_path, monkeypatch):
    assert Settings.model_fields["report_warm_up"].default is True
    monkeypatch.setitem(warm.WARM_TIME, "done", False)  # as in a fresh process
    release = threading.Event()
    calls = []
    real = warm.warm_up

    def slow_warm_up():  # the real one, held back until the service has answered
        release.wait(60)
        calls.append(threading.current_thread().name)
        real()

    monkeypatch.setattr(warm, "warm_up", slow_warm_up)
    gc.unfreeze()  # as in a fresh process: nothing frozen yet
    app = create_app(make_settings(tmp_path, report_warm_up=True))
    with TestClient(app) as client:
        assert client.get("/api/rig/state").status_code == 200  # the service answers while the warm-up waits
        done = app.state.report_warm
        assert isinstance(done, threading.Event) and not done.is_set()
        release.set()
        assert done.wait(120), "the warm-up did not end"
        assert calls == ["isorig-report-warm-up"] and warm.WARM_TIME["done"] and warm.WARM_TIME["s"] > 0
        # what the start made is out of the collector's reach: a report's full collection does not traverse it
        assert gc.get_freeze_count() > 10_000, gc.get_freeze_count()
        test_id = create_and_start(client)
        assert wait_for(client, test_id)["status"] == "completed"
        r = client.get(f"/api/tests/{test_id}/report.pdf")
        assert r.status_code == 200 and r.content[:5] == b"%PDF-"
    # once per process: a second service finds it done and does not warm again
    app = create_app(make_settings(tmp_path / "second", report_warm_up=True))
    with TestClient(app):
        assert app.state.report_warm.wait(30)
    assert calls == ["isorig-report-warm-up"]
    gc.unfreeze()


def test_without_the_setting_nothing_is_warmed(tmp_path):
    app = create_app(make_settings(tmp_path))  # the backend tests' settings: report_warm_up off
    with TestClient(app):
        assert app.state.report_warm is None
        assert not any(t.name == "isorig-report-warm-up" for t in threading.enumerate())


def test_a_failed_warm_up_costs_nothing_but_time(tmp_path, monkeypatch, caplog):
    monkeypatch.setitem(warm.WARM_TIME, "done", False)
    monkeypatch.setitem(warm.WARM_TIME, "s", None)

    def broken():
        raise RuntimeError("no fonts today")

    monkeypatch.setattr(warm, "warm_up", broken)
    app = create_app(make_settings(tmp_path, report_warm_up=True))
    with TestClient(app) as client:
        assert app.state.report_warm.wait(60)
        assert warm.WARM_TIME["done"] and warm.WARM_TIME["s"] is None
        assert "could not be warmed up" in caplog.text
        assert client.get("/api/rig/state").status_code == 200


def test_the_warm_up_record_makes_every_page_a_long_test_has():
    """What warm_up draws: loops, time histories, the detail of a record longer than 30 s, the per-cycle table,
    the verdicts and events, and the Bouc-Wen fit (the fonts, sizes and weights of a real report)."""
    from backend.reports import render_report_pdf, report_json
    from backend.reports.lab import lab_header

    bundle = warm.warm_bundle()
    lab = lab_header(use_settings=False)
    report = report_json(bundle, lab=lab)
    assert report["identification"]["available"] is True and report["headline"]["steady_cycles"] == 30
    assert [c["phase"] for c in bundle.cycles][:2] == ["taper_in", "steady"] and len(bundle.cycles) == 32
    buf = io.BytesIO()
    render_report_pdf(bundle, buf, report=report, lab=lab)
    pdf = buf.getvalue()
    assert pdf.count(b"/Type /Page") - pdf.count(b"/Type /Pages") == 7  # header, setup, loops, time, detail, ...
