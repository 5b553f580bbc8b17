"""Test reports: PDF pages rendered to PNG and checked, report.json, stored tests, CSV records, the CLI."""

import json
import shutil
import subprocess

import numpy as np
import pytest

from backend.reports import ReportBundle, bundle_from_csv, render_report_pdf, report_json
from backend.reports.data import rig_text
from backend.reports.layout import PAGE_BOTTOM
from sim.engine import Scenario, Simulation
from sim.isolator import PRESETS
from sim.metrics import scenario_cycle_metrics
from sim.protocols import load_protocol
from sim.records import write_csv
from sim.samples import SAMPLE_FIELDS, Samples

PDFTOPPM = shutil.which("pdftoppm") or ("/usr/bin/pdftoppm" if shutil.os.path.exists("/usr/bin/pdftoppm") else None)


def protocol_run(name="quick_check", controller="pid", degrade_cycle=None):
    """An engine run of a protocol as a store-like bundle (cycles with loop arrays, events)."""
    protocol = load_protocol(name)
    scenario = Scenario(PRESETS["IUT_a"], 100e5, protocol.blocks, controller=controller)
    samples = Simulation(scenario).run().samples
    if degrade_cycle is not None:  # a softening isolator in one cycle
        p = protocol.cycle_plan()[degrade_cycle - 1]
        t = samples["time_s"]
        samples["force_n"][(t >= p["t_start_s"] - 5e-4) & (t < p["t_end_s"] + 5e-4)] *= 0.7
    cycles = scenario_cycle_metrics(samples, scenario)
    for c in cycles:
        j = min(c["i_end"] + 1, len(samples))
        c["displacement_m"] = samples["displacement_m"][c["i_start"]:j]
        c["force_n"] = samples["force_n"][c["i_start"]:j]
    record = {"id": 7, "label": "report test", "status": "completed", "created_at": "2026-01-02T03:04:05+00:00",
              "isolator": "IUT_a", "supply_bar": 100.0, "controller": controller, "driver": "simulated",
              "profile": {"kind": "protocol", "name": name}, "duration_s": scenario.duration_s,
              "scenario": scenario.describe()}
    events = [{"kind": "operator", "actor": "alice", "time_s": 0.0, "message": "test 7 started by alice",
               "values": {"action": "start"}},
              {"kind": "limit_trip", "time_s": 3.2, "message": "force above the limit",
               "values": {"detector": "force", "time_s": 3.2, "displacement_m": 0.0101, "force_n": 5.1e4,
                          "limit": 5.0e4, "limit_name": "force_n", "flags": 1}}]
    return ReportBundle(record, samples, cycles, events)


def png_pages(pdf, tmp_path, dpi=40):
    """Render every page with pdftoppm; return the pages as arrays (height, width, 3)."""
    from PIL import Image

    subprocess.run([PDFTOPPM, "-r", str(dpi), "-png", str(pdf), str(tmp_path / "page")], check=True,
                   capture_output=True, timeout=60)
    files = sorted(tmp_path.glob("page-*.png"))
    return [np.asarray(Image.open(f).convert("RGB")) for f in files]


def ink(page) -> float:
    """Share of pixels that are not (near) white."""
    return float(np.mean(page.min(axis=2) < 200))


def colour(page) -> float:
    """Share of clearly coloured pixels (plots), as opposed to black or grey text."""
    p = page.astype(int)
    return float(np.mean(p.max(axis=2) - p.min(axis=2) > 60))


@pytest.mark.skipif(PDFTOPPM is None, reason="pdftoppm (poppler-utils) is not installed")
def test_pdf_pages_render_and_are_not_blank(tmp_path):
    bundle = protocol_run()
    out = tmp_path / "report.pdf"
    render_report_pdf(bundle, out, meta={"lab": "Lab A", "operator": "alice"}, identify=False)
    assert out.read_bytes()[:5] == b"%PDF-"
    pages = png_pages(out, tmp_path)
    # summary, setup, loops, time histories, per-cycle table, verdicts and events (10 s: no detail page)
    assert len(pages) == 6
    for i, page in enumerate(pages, start=1):
        assert page.shape[0] > page.shape[1]  # A4 portrait
        assert ink(page) > 0.003, f"page {i} looks blank"
    assert colour(pages[2]) > 0.01  # coloured loops
    assert colour(pages[3]) > 0.01  # time histories
    assert colour(pages[2]) > 5 * colour(pages[4])  # the table page is text, the loop page is plots


def test_report_json_names_the_failing_rule():
    good = report_json(protocol_run(), identify=False)
    assert good["acceptance"]["summary"]["passed"] is True
    assert len(good["cycles"]) == 10 and "displacement_m" not in good["cycles"][0]
    assert good["controller"]["name"] == "pid"
    assert good["limit_trips"][0]["message"] == "force above the limit"
    json.dumps(good, allow_nan=False)  # strict JSON: no NaN anywhere
    # soften the isolator in level 2, test cycle 2 (planned cycle 8): both 3rd-cycle rules fail there
    bad = report_json(protocol_run(degrade_cycle=8), identify=False)
    summary = bad["acceptance"]["summary"]
    assert summary["passed"] is False
    assert {r["rule"] for r in summary["failed_rules"]} == {"keff_vs_3rd_cycle", "edc_vs_3rd_cycle"}
    assert all(r["cycles"] == [8] for r in summary["failed_rules"])


def test_identified_parameters_beside_nominal():
    pytest.importorskip("sim.identify_bouc_wen")
    rep = report_json(protocol_run())
    ident = rep["identification"]
    assert ident["available"], ident.get("note")
    assert ident["nominal"]["kw_n"] == PRESETS["IUT_a"].kw_n
    # the simulated isolator is IUT_a itself: the fit must find its parameters
    for key in ("kd_n_per_m", "kw_n"):
        assert ident["identified"][key] == pytest.approx(ident["nominal"][key], rel=0.02)


def test_report_from_simulate_csv_uses_its_summary(tmp_path, capsys):
    from isorig.cli import main

    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 5, controller="pid", taper_cycles=1)
    result = Simulation(scenario).run()
    write_csv(tmp_path / "timeseries.csv", result.samples)
    (tmp_path / "summary.json").write_text(json.dumps(result.summary()))
    bundle = bundle_from_csv(tmp_path / "timeseries.csv")
    assert [c["cycle"] for c in bundle.cycles] == [1, 2, 3, 4, 5]  # split by the command's phase
    assert bundle.record["isolator"] == "IUT_a" and bundle.record["supply_bar"] == 100.0
    assert np.isnan(bundle.samples["model_m"]).all()  # model_m is empty for PID: NaN, not an error
    out = tmp_path / "r.pdf"
    code = main(["report", "--csv", str(tmp_path / "timeseries.csv"), "--out", str(out), "--json",
                 str(tmp_path / "r.json"), "--no-identify", "--protocol", "quick_check"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "time" in printed
    assert out.stat().st_size > 10_000
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["acceptance"]["protocol"] == "quick_check"  # judged, though this record is no protocol run
    assert rep["acceptance"]["summary"]["passed"] is False


def _store_test(url: str) -> int:
    from backend import store
    from backend.db import make_engine, session_factory, upgrade

    bundle = protocol_run()
    engine = make_engine(url)
    upgrade(engine)
    with session_factory(engine)() as session:
        test = store.create_test(session, rig_name="rig-1", label="stored", isolator="IUT_a", supply_bar=100.0,
                                 controller="pid", speed=1.0, driver="simulated",
                                 request={"profile": {"kind": "protocol", "name": "quick_check"}},
                                 scenario=bundle.record["scenario"], limits={}, duration_s=10.0, cycles_total=10)
        for i in range(0, len(bundle.samples), 1000):
            store.append_samples(session, test, bundle.samples[i:i + 1000])
        for c in bundle.cycles:
            metrics = {k: v for k, v in c.items() if k not in ("displacement_m", "force_n", "cycle")}
            store.add_cycle(session, test.id, c["cycle"], 0, c["t_start_s"], c["t_end_s"], metrics,
                            c["displacement_m"], c["force_n"])
        store.add_event(session, test.id, "limit_trip", "displacement beyond the limit", {"detector": "stroke"},
                        time_s=4.0)
        store.set_status(session, test, "completed")
        session.commit()
        test_id = test.id
    engine.dispose()
    return test_id


def test_report_of_a_stored_test_via_the_cli(tmp_path, capsys):
    pytest.importorskip("backend.store")
    from isorig.cli import main

    url = f"sqlite:///{tmp_path / 'store.db'}"
    test_id = _store_test(url)
    out = tmp_path / "stored.pdf"
    assert main(["report", str(test_id), "--out", str(out), "--database-url", url, "--json",
                 str(tmp_path / "stored.json"), "--no-identify", "--lab", "Lab B",
                 "--csv-out", str(tmp_path / "stored.csv")]) == 0
    capsys.readouterr()
    assert main(["analyze", str(tmp_path / "stored.csv"), "--json", "--frequency-hz", "1"]) == 0
    analysed = json.loads(capsys.readouterr().out)["cycles"]
    rep = json.loads((tmp_path / "stored.json").read_text())
    assert rep["lab"]["name"] == "Lab B" and rep["test"]["status"] == "completed"
    assert len(rep["cycles"]) == 10 and rep["acceptance"]["summary"]["passed"] is True
    # the exported CSV gives the same metrics as the store's (split by the same phase)
    assert [c["edc_j"] for c in analysed] == pytest.approx([c["edc_j"] for c in rep["cycles"]], rel=1e-6)
    assert rep["limit_trips"][0]["message"] == "displacement beyond the limit"
    assert out.read_bytes()[:5] == b"%PDF-"
    capsys.readouterr()
    assert main(["report", "999", "--out", str(out), "--database-url", url]) == 2
    assert "test 999 does not exist" in capsys.readouterr().err


def test_the_cli_report_of_a_stored_test_names_the_lab_the_service_was_given(tmp_path):
    """The Lab page's settings (backend.lab, in the database) head `isorig report` as the service's reports."""
    pytest.importorskip("backend.store")
    from backend import db, lab
    from isorig.cli import main

    url = f"sqlite:///{tmp_path / 'store.db'}"
    test_id = _store_test(url)
    engine = db.make_engine(url)
    with db.session_factory(engine)() as session:
        lab.update(session, "adam", "Database Lab", "Road 5", None)
        session.commit()
    engine.dispose()
    assert main(["report", str(test_id), "--out", str(tmp_path / "r.pdf"), "--database-url", url, "--json",
                 str(tmp_path / "r.json"), "--no-identify"]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["lab"]["name"] == "Database Lab"
    assert main(["report", str(test_id), "--out", str(tmp_path / "r.pdf"), "--database-url", url, "--json",
                 str(tmp_path / "r.json"), "--no-identify", "--lab", "Flag Lab"]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["lab"]["name"] == "Flag Lab"  # a flag still wins


@pytest.mark.parametrize("argv, message", [
    (["report", "--out", "x.pdf"], "exactly one of TEST_ID"),
    (["report", "3", "--csv", "a.csv", "--out", "x.pdf"], "exactly one of TEST_ID"),
    (["report", "3", "--protocol", "quick_check", "--out", "x.pdf"], "go with --csv only"),
    (["report", "--csv", "missing.csv", "--out", "x.pdf"], "cannot read"),
    (["report", "--csv", "a.csv", "--out", "/no/such/dir/x.pdf"], "does not exist"),
])
def test_report_cli_errors_are_one_line(argv, message, capsys):
    from isorig.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_report_of_a_test_that_never_ran():
    bundle = ReportBundle({"id": 3, "status": "ready", "isolator": "IUT_b",
                           "profile": {"kind": "protocol", "name": "quick_check", "protocol": None}},
                          Samples.empty(), [], [])
    rep = report_json(bundle)
    assert rep["cycles"] == [] and rep["identification"]["available"] is False
    # nothing measured: every judged cycle is "missing", so the protocol fails, it never passes by absence
    assert rep["acceptance"]["summary"]["passed"] is False
    assert {v["status"] for v in rep["acceptance"]["verdicts"]} == {"missing"}
    buf = __import__("io").BytesIO()
    render_report_pdf(bundle, buf, report=rep)
    assert buf.getvalue()[:5] == b"%PDF-"


def test_a_crowded_header_continues_on_another_page():
    """Ten levels, six rules, long notes and a long controller parameter list do not run into the footer: the
    summary continues on a page of its own, every word kept."""
    from backend.reports import data, header, plot_style

    proto = load_protocol("en15129_type_test").to_dict()
    proto["levels"] = [{"fraction": 0.1 * (i + 1), "cycles": 3} for i in range(10)]
    proto["acceptance"] += [{"name": f"r{i}", "quantity": "xi_eff", "reference": "cycle", "tolerance_fraction": 0.1}
                            for i in range(4)]
    notes = " ".join(f"note{i}" for i in range(300))
    crowded = {"id": 9, "status": "aborted", "isolator": "IUT_b", "controller": "servo", "supply_bar": 70,
               "profile": {"kind": "protocol", "protocol": proto}, "notes": notes}
    plain = {"id": 10, "status": "aborted", "isolator": "IUT_b", "controller": "pid", "supply_bar": 70}
    plt = plot_style()
    counts = []
    for record in (crowded, plain):
        bundle = ReportBundle(record, Samples.empty(), [], [])
        rep = report_json(bundle, identify=False)
        figs = header.page_header(plt, bundle, rep, data.isolator_of(record), data.protocol_of(record)[0], None)
        counts.append(len(figs))
        words = " ".join(t.get_text() for fig in figs for t in fig.texts).split()
        for fig in figs:  # every text stays above the footer line
            assert min(t.get_position()[1] for t in fig.texts if t.get_text()) >= PAGE_BOTTOM
            plt.close(fig)
        if record is crowded:
            assert all(f"note{i}" in words for i in range(300))  # wrapped, never cut
            assert "..." not in " ".join(words).replace("... and", "")
    assert counts[1] == 2 and counts[0] > counts[1]  # the summary page and the setup page; more when crowded


PDFTOTEXT = shutil.which("pdftotext")


def pdf_text(pdf, *options) -> list[str]:
    """The text of each page (pdftotext), without the line that says when the report was issued."""
    out = subprocess.run([PDFTOTEXT, *options, str(pdf), "-"], check=True, capture_output=True, text=True,
                         timeout=60).stdout
    return ["\n".join(line for line in page.splitlines() if "issued" not in line and "CreationDate" not in line)
            for page in out.split("\f")]


def comparable(rep: dict) -> dict:
    """report.json without what differs between two runs: the time it was made and how long the fit took."""
    return {**rep, "generated_at": None, "identification": {**rep["identification"], "time_s": None}}


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_a_deferred_identification_still_heads_the_report(tmp_path):
    """The fit may finish while the other pages are drawn: its header page is drawn last but comes first."""
    bundle = protocol_run()
    rep = report_json(bundle, identify=False)
    fit = {**rep["identification"], "available": True, "source": "a fit made elsewhere",
           "identified": {"rho_bw_per_m": 150.0, "sigma_bw": 0.5, "n": 1.0, "kd_n_per_m": 1.3e6, "kw_n": 1.7e4}}
    render_report_pdf(bundle, tmp_path / "now.pdf", report={**rep, "identification": fit})
    asked = []
    render_report_pdf(bundle, tmp_path / "later.pdf", report=rep, identification=lambda: asked.append(1) or fit)
    assert asked == [1] and rep["identification"] == fit  # asked once, and the report says what was drawn
    later = pdf_text(tmp_path / "later.pdf")
    assert later == pdf_text(tmp_path / "now.pdf")
    assert "a fit made elsewhere" in later[1] and "page 1 of" in later[0] and "page 2 of" in later[1]


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_table_lines_sit_where_text_objects_put_them(tmp_path):
    """The table's lines (layout.draw_lines) must land exactly where one Text per line at its baseline puts them."""
    from backend.reports import layout, plot_style

    plt = plot_style()
    lines = ["cycle  t_start", ("    1     0.00", "#c62828"), "", "    3     2.00"]
    for name, draw in (("artist", layout.draw_lines), ("text", None)):
        fig = plt.figure(figsize=layout.A4_PORTRAIT_IN)
        if draw:
            draw(fig, lines, 0.05, 0.885, 8.5, 11.0)
        else:
            step = 11.0 / 72.0 / fig.get_figheight()
            for k, item in enumerate(lines, start=1):
                text, color = item if isinstance(item, tuple) else (item, "black")
                if text:
                    fig.text(0.05, 0.885 - k * step, text, fontsize=8.5, family="monospace", color=color,
                             va="baseline")
        fig.savefig(tmp_path / f"{name}.pdf")
        plt.close(fig)
    boxes = pdf_text(tmp_path / "artist.pdf", "-bbox")
    assert boxes == pdf_text(tmp_path / "text.pdf", "-bbox")
    assert "2.00" in boxes[0]


@pytest.mark.parametrize("controller, cycles", [("mrac", 3), ("servo", 2), ("pid", 2)])
def test_report_columns_only_change_nothing_the_report_says(tmp_path, controller, cycles):
    """all_columns=False skips model_m and load_pressure_pa and reads the adaptive estimates from the last rows
    (PID has none: empty cells); report.json stays the same."""
    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, cycles, controller=controller, taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    full = bundle_from_csv(tmp_path / "timeseries.csv")
    some = bundle_from_csv(tmp_path / "timeseries.csv", all_columns=False)
    for name in SAMPLE_FIELDS:
        if name in ("model_m", "load_pressure_pa"):
            assert np.isnan(some.samples[name]).all()
        elif name in ("ar_hat", "ay_hat", "as_hat"):
            read = np.isfinite(some.samples[name])
            assert read.any() == np.isfinite(full.samples[name]).any() and read[-1] == read.any()
            np.testing.assert_array_equal(some.samples[name][read], full.samples[name][read])
        else:
            np.testing.assert_array_equal(full.samples[name], some.samples[name])
    assert comparable(report_json(full)) == comparable(report_json(some))
    assert (controller == "pid") == (not some_final(some))


def some_final(bundle) -> dict:
    from backend.reports import controller_state

    return controller_state(bundle)["final_adapted"]


@pytest.mark.parametrize("last_rows, final, from_tail", [
    ("", {"ar_hat": 3.0, "ay_hat": 0.5}, True),  # as_hat empty in the first row: never read, as the full reader does
    ("9.0,0.1,5,7,,\n", {"ar_hat": 7.0, "ay_hat": 0.5}, True),  # an empty cell: the last finite value before it
    ("9.0,0.1,5,abc,1,\n", "'abc'", False),  # not a number: the whole-column reader names it
    ("9.0,0.1,5,1_0,1,\n", {"ar_hat": 10.0, "ay_hat": 1.0}, False),  # left to the whole-column reader, which takes it
])
@pytest.mark.parametrize("tail_bytes", [200, 1 << 16])  # a tail that starts mid-file, one that reaches the start
def test_final_estimates_of_a_small_csv(tmp_path, monkeypatch, last_rows, final, from_tail, tail_bytes):
    import functools

    from backend.reports import data as reports

    rows = "".join(f"{0.01 * i:.2f},{1e-3 * i:g},{10.0 * i:g},{1 + i % 3:g},0.5,{'' if i == 0 else 2}\n"
                   for i in range(60))
    path = tmp_path / "r.csv"
    path.write_text("time_s,displacement_m,force_n,ar_hat,ay_hat,as_hat\n" + rows + last_rows)
    n_rows = 60 + bool(last_rows)
    tail = reports._final_estimates(path, n_rows, tail_bytes=tail_bytes)
    assert (tail is not None) == from_tail
    if tail is not None:  # what the tail read agrees with the whole columns wherever it has a value
        full = bundle_from_csv(path)
        assert sorted(tail) == sorted(final)
        for name, values in tail.items():
            column = full.samples[name]
            if tail_bytes >= path.stat().st_size:  # the whole file: every row
                np.testing.assert_array_equal(values, column)
            else:
                read = np.isfinite(values)
                assert not read[0] and read.any()
                np.testing.assert_array_equal(values[read], column[read])
    monkeypatch.setattr(reports, "_final_estimates", functools.partial(reports._final_estimates,
                                                                       tail_bytes=tail_bytes))
    if isinstance(final, str):
        with pytest.raises(ValueError, match=final):
            bundle_from_csv(path, all_columns=False)
        return
    assert some_final(bundle_from_csv(path, all_columns=False)) == final == some_final(bundle_from_csv(path))


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_three_processes_make_the_same_report_as_one(tmp_path, capsys):
    """`isorig report` loads, fits and draws in separate processes (2+ cores); --serial does it all in one."""
    from isorig.cli import main
    from isorig.commands.report import _parallel

    url = f"sqlite:///{tmp_path / 'store.db'}"
    test_id = _store_test(url)
    for how in ("serial", "parallel"):
        argv = ["report", str(test_id), "--database-url", url, "--out", str(tmp_path / f"{how}.pdf"),
                "--json", str(tmp_path / f"{how}.json"), "--csv-out", str(tmp_path / f"{how}.csv")]
        assert main(argv + (["--serial"] if how == "serial" else [])) == 0
        printed = capsys.readouterr().out
        assert ("1 process" in printed) == (how == "serial" or not _parallel())
    reps = [json.loads((tmp_path / f"{how}.json").read_text()) for how in ("serial", "parallel")]
    assert reps[1]["identification"]["available"], reps[1]["identification"].get("note")
    assert comparable(reps[0]) == comparable(reps[1])
    assert pdf_text(tmp_path / "serial.pdf") == pdf_text(tmp_path / "parallel.pdf")
    assert (tmp_path / "serial.csv").read_text() == (tmp_path / "parallel.csv").read_text()


def test_a_bad_csv_read_in_another_process_is_still_one_line(tmp_path, capsys):
    from isorig.cli import main

    rows = "".join(f"{i * 0.001},{1e-3 * i},{'abc' if i == 5 else 10.0 * i}\n" for i in range(200))
    (tmp_path / "bad.csv").write_text("time_s,displacement_m,force_n\n" + rows)
    for extra in ([], ["--serial"]):
        assert main(["report", "--csv", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "r.pdf")] + extra) == 2
        err = capsys.readouterr().err
        assert "line 7, column force_n: 'abc' is not a number" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r.pdf").exists()


def test_without_shared_memory_one_process_does_it(tmp_path, capsys, monkeypatch):
    import os

    from isorig.cli import main

    def refuse(*_args):
        raise OSError(38, "Function not implemented")

    monkeypatch.setattr(os, "memfd_create", refuse, raising=False)
    url = f"sqlite:///{tmp_path / 'store.db'}"
    test_id = _store_test(url)
    assert main(["report", str(test_id), "--database-url", url, "--out", str(tmp_path / "r.pdf"), "--no-identify"]) == 0
    assert "in 1 process" in capsys.readouterr().out
    assert (tmp_path / "r.pdf").read_bytes()[:5] == b"%PDF-"


def _children_of(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    import os

    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    stat = fh.read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


@pytest.mark.skipif(not shutil.os.path.isdir("/proc/self"), reason="needs /proc (Linux)")
def test_killing_the_report_process_ends_its_children_quietly(tmp_path):
    """SIGTERM to `isorig report` alone: its loader and identifier end with it, without a traceback each."""
    import os
    import signal
    import sys
    import time

    from isorig.commands.report import _parallel

    if not _parallel():
        pytest.skip("one process only here")
    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 20, controller="pid", taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    proc = subprocess.Popen([sys.executable, "-m", "isorig", "report", "--csv", str(tmp_path / "timeseries.csv"),
                             "--out", str(tmp_path / "r.pdf")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 60
        children = []
        while len(children) < 2 and time.monotonic() < deadline and proc.poll() is None:
            children = _children_of(proc.pid)
            time.sleep(0.01)
        assert len(children) == 2, "the report did not start its two children"
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=60)  # the output ends when the children have closed it too
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in err and "Error" not in err, err
    for pid in children:
        assert not os.path.exists(f"/proc/{pid}") or open(f"/proc/{pid}/stat").read().split()[2] == "Z"


def test_the_receiving_thread_is_never_cut_off_by_a_stop(tmp_path, capsys, monkeypatch):
    """A stop of the report while the test is on its way (SIGTERM raises SystemExit in the main thread): the
    children end first and the receiving thread reads to the end of its pipe before the pipe is closed; a pipe
    closed under a half-read message ended that thread with a TypeError traceback (a CI run saw it)."""
    import backend.reports as reports_module
    import isorig.commands.report as report_cmd
    from isorig.cli import main

    if not report_cmd._parallel():
        pytest.skip("one process only here")
    seen = {}
    receive = report_cmd._receive

    def watched_receive(conn, received):
        receive(conn, received)
        seen["pipe_open_at_end"] = not conn.closed

    def stopped():
        raise SystemExit(143)

    monkeypatch.setattr(report_cmd, "_receive", watched_receive)
    monkeypatch.setattr(reports_module, "plot_style", stopped)
    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3, controller="pid", taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    with pytest.raises(SystemExit):
        main(["report", "--csv", str(tmp_path / "timeseries.csv"), "--out", str(tmp_path / "r.pdf")])
    assert seen == {"pipe_open_at_end": True}
    assert "Traceback" not in capsys.readouterr().err


def test_a_report_goes_on_when_the_identifier_dies_early(tmp_path, capsys, monkeypatch):
    """An identifier killed before it reads its task (out of memory, a failed import): the loader's hand-over
    fails, and the report is made without the fit, saying why."""
    import os

    import isorig.commands.report as report_cmd
    from isorig.cli import main

    if not report_cmd._parallel():
        pytest.skip("one process only here")

    def dying(*_args):
        os._exit(137)

    monkeypatch.setattr(report_cmd, "_identifier", dying)
    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 5, controller="pid", taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    assert main(["report", "--csv", str(tmp_path / "timeseries.csv"), "--out", str(tmp_path / "r.pdf"),
                 "--json", str(tmp_path / "r.json")]) == 0
    assert "Traceback" not in capsys.readouterr().err
    ident = json.loads((tmp_path / "r.json").read_text())["identification"]
    assert ident["available"] is False
    assert ident["note"] == "identification failed: its process ended without an answer"


@pytest.mark.parametrize("how", ["killed", "raised"])
def test_a_failed_loader_is_told_in_one_line(tmp_path, capsys, monkeypatch, how):
    """A loader killed (os._exit) or failing unexpectedly: a one-line error and exit code 2, no traceback."""
    import os

    import isorig.commands.report as report_cmd
    from isorig.cli import main

    if not report_cmd._parallel():
        pytest.skip("one process only here")

    def load(_args):
        if how == "killed":
            os._exit(137)
        raise KeyError("boom")

    monkeypatch.setattr(report_cmd, "_load", load)
    assert main(["report", "--csv", str(tmp_path / "any.csv"), "--out", str(tmp_path / "r.pdf")]) == 2
    err = capsys.readouterr().err
    assert "the loading process failed" in err and len(err.strip().splitlines()) == 1, err
    assert ("KeyError: 'boom'" in err) == (how == "raised")


def test_no_pipes_or_no_shared_memory_room_means_one_process(tmp_path, capsys, monkeypatch):
    """Out of file descriptors for the pipes, or no room in the shared memory file: one process makes the report
    (and nothing is left open)."""
    import multiprocessing
    import os

    import isorig.commands.report as report_cmd
    from isorig.cli import main

    if not report_cmd._parallel():
        pytest.skip("one process only here")
    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3, controller="pid", taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    argv = ["report", "--csv", str(tmp_path / "timeseries.csv"), "--out", str(tmp_path / "r.pdf"), "--no-identify"]

    def refuse(*_args, **_kwargs):
        raise OSError(24, "Too many open files")

    fds = len(os.listdir("/proc/self/fd"))
    with monkeypatch.context() as patch:
        patch.setattr(type(multiprocessing.get_context("fork")), "Pipe", refuse)
        assert main(argv) == 0
    assert "in 1 process" in capsys.readouterr().out
    assert len(os.listdir("/proc/self/fd")) == fds

    def no_room(*_args):
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as patch:
        patch.setattr(os, "ftruncate", no_room)  # in the loader, which fills the shared memory
        assert main(argv) == 0
    captured = capsys.readouterr()
    assert "in 1 process" in captured.out and "Traceback" not in captured.err
    assert (tmp_path / "r.pdf").read_bytes()[:5] == b"%PDF-"


# --- the modules of backend/reports/ ---------------------------------------------------------------------

def test_the_reports_package_imports_without_matplotlib():
    """The loader and identifier processes of `isorig report` import backend.reports: no matplotlib until a PDF."""
    import sys

    code = "import sys, backend.reports; assert 'matplotlib' not in sys.modules, 'matplotlib imported'"
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=60)


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_fixed_pitch_lines_whatever_their_glyphs(tmp_path):
    """layout.draw_lines keeps every baseline on the pitch, whatever the glyphs' heights (a multi-line Text would
    not: it centres each line on its own glyphs)."""
    import re

    from backend.reports import layout, plot_style

    plt = plot_style()
    fig = plt.figure(figsize=layout.A4_PORTRAIT_IN)
    lines = ["1111", "____", ("((((", "#c62828"), "", "pppp", "-", "|||| ~~~~"]
    layout.draw_lines(fig, lines, 0.05, 0.885, 8.5, 11.0)
    fig.savefig(tmp_path / "lines.pdf")
    plt.close(fig)
    boxes = pdf_text(tmp_path / "lines.pdf", "-bbox")[0]
    y_min = {word: float(y) for y, word in re.findall(r'yMin="([\d.]+)"[^>]*>([^<]+)</word>', boxes)}
    top = y_min["1111"] - 11.0  # pdftotext measures down from the top of the page, in points
    for k, item in enumerate(lines, start=1):
        text = item[0] if isinstance(item, tuple) else item
        for word in text.split():
            assert y_min[word] == pytest.approx(top + 11.0 * k, abs=1e-3), (word, k)


def test_pages_moved_first_reorders_the_page_tree(tmp_path):
    """document._pages_moved_first permutes the page tree in place (same length: the byte offsets hold)."""
    from matplotlib.backends.backend_pdf import PdfPages

    from backend.reports import document, plot_style

    plt = plot_style()
    pdf = tmp_path / "three.pdf"
    with PdfPages(pdf) as pages:
        for word in ("one", "two", "three"):
            fig = plt.figure(figsize=(3, 3))
            fig.text(0.5, 0.5, word)
            pages.savefig(fig)
            plt.close(fig)
    data = pdf.read_bytes()
    moved = document._pages_moved_first(data, 1)
    assert len(moved) == len(data) and moved != data
    assert document._pages_moved_first(data, 0) == data
    assert document._pages_moved_first(data, 4) is None  # more pages than there are
    assert document._pages_moved_first(b"%PDF-1.4 not matplotlib's page tree", 1) is None
    (tmp_path / "moved.pdf").write_bytes(moved)
    if PDFTOTEXT is not None:  # the viewer's order: the last page first
        assert [p.strip() for p in pdf_text(tmp_path / "moved.pdf")][:3] == ["three", "one", "two"]


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_an_unknown_page_tree_means_drawing_again_in_order(tmp_path, monkeypatch):
    """Where the page tree cannot be reordered, the report is drawn again in order once the fit is there."""
    from backend.reports import document

    bundle = protocol_run()
    rep = report_json(bundle, identify=False)
    fit = {**rep["identification"], "available": True, "source": "a fit made elsewhere",
           "identified": {"rho_bw_per_m": 150.0, "sigma_bw": 0.5, "n": 1.0, "kd_n_per_m": 1.3e6, "kw_n": 1.7e4}}
    render_report_pdf(bundle, tmp_path / "now.pdf", report={**rep, "identification": fit})
    monkeypatch.setattr(document, "_pages_moved_first", lambda _pdf, _n: None)
    asked = []
    render_report_pdf(bundle, tmp_path / "later.pdf", report=rep, identification=lambda: asked.append(1) or fit)
    assert asked == [1]
    assert pdf_text(tmp_path / "later.pdf") == pdf_text(tmp_path / "now.pdf")


# --- issue 14: honest figures, a report a lab can sign, the bundle ------------------------------------------

def cut_short(bundle, t_end_s: float, status: str, reason: str) -> ReportBundle:
    """The bundle as if the test had ended at ``t_end_s`` (samples and whole cycles before it only)."""
    samples = bundle.samples[bundle.samples["time_s"] <= t_end_s]
    cycles = [c for c in bundle.cycles if c["t_end_s"] <= t_end_s]
    record = {**bundle.record, "status": status, "reason": reason, "time_s": float(samples["time_s"][-1]),
              "cycles_total": len(bundle.cycles), "cycles_done": len(cycles), "specimen_id": "LRB-17",
              "operator_name": "A. Rossi", "notes": "second specimen of three", "vertical_load_n": 150e3}
    events = [e for e in bundle.events if (e.get("time_s") or 0.0) <= t_end_s]
    return ReportBundle(record, samples, cycles, events)


def test_headline_figures_come_from_the_steady_cycles_only():
    """sim.metrics.headline_figures over the steady cycles: the tapers (stiffer, at a lower amplitude) are left
    out of the headline K_eff, which therefore differs from the mean over all cycles."""
    from sim.metrics import headline_figures

    bundle = protocol_run()
    rep = report_json(bundle, identify=False)
    steady = [c["k_eff_n_per_m"] for c in bundle.cycles if c["phase"] == "steady"]
    every = [c["k_eff_n_per_m"] for c in bundle.cycles]
    head = rep["headline"]
    assert head["means"]["k_eff_n_per_m"] == pytest.approx(np.mean(steady), rel=1e-12)
    assert abs(head["means"]["k_eff_n_per_m"] / np.mean(every) - 1) > 0.02  # the tapers would have moved it
    assert head["steady_cycles"] == 6 and head["excluded_cycles"] == {"taper_in": 2, "taper_out": 2}
    assert head["means"] == headline_figures(rep["cycles"])["means"]  # sim's function, not a re-implementation
    assert [lv["steady_cycles"] for lv in head["levels"]] == [3, 3]
    assert [c["phase"] for c in rep["cycles"]][:5] == ["taper_in", "steady", "steady", "steady", "taper_out"]


def test_the_k_eff_axis_is_scaled_to_the_steady_cycles():
    """The taper-out cycle's K_eff (3.33 kN/mm against 2.08-2.70 in the steady cycles) no longer stretches the axis:
    it is drawn at the edge, marked."""
    from backend.reports import figures, plot_style

    plt = plot_style()
    bundle = protocol_run()
    rep = report_json(bundle, identify=False)
    fig = figures.page_loops(plt, bundle, None, rep)
    ax = fig.axes[1]  # K_eff per cycle (the colour bar is added after the two plots)
    lo, hi = ax.get_ylim()
    steady = [c["k_eff_n_per_m"] * 1e-6 for c in bundle.cycles if c["phase"] == "steady"]
    tapers = [c["k_eff_n_per_m"] * 1e-6 for c in bundle.cycles if c["phase"] != "steady"]
    assert lo <= min(steady) and max(steady) <= hi
    assert max(tapers) > hi  # off the axis ...
    legend = " ".join(t.get_text() for t in ax.get_legend().get_texts())
    assert "taper" in legend and "off scale" in legend  # ... and said so
    plt.close(fig)


def test_taper_cycles_are_never_judged():
    """A planned test cycle that was the ramp-out of an operator's stop is not judged as a steady cycle: its check
    has no measured cycle, and the verdict of a test that ended early is INCOMPLETE."""
    bundle = protocol_run()
    stopped = cut_short(bundle, 9.0, "stopped", "operator stop; ramped out to t = 9.000 s")
    stopped.cycles[-1] = {**stopped.cycles[-1], "phase": "ramp_out"}  # cycle 9 (L2.3) became the ramp-out
    rep = report_json(stopped, identify=False)
    judged = {v["cycle"]: v for v in rep["acceptance"]["verdicts"]}
    assert judged[9 - 1]["status"] == "missing"  # cycle 8 is judged against cycle 9, the ramp-out: no reference
    assert rep["acceptance"]["verdict"] == "INCOMPLETE"
    assert rep["run"]["ended_early"] and rep["run"]["cycles_done"] == 9 and rep["run"]["cycles_planned"] == 10
    full = report_json(bundle, identify=False)
    assert full["acceptance"]["verdict"] == "PASSED" and full["run"]["banner"] is None
    level_1 = [v for v in full["acceptance"]["verdicts"] if v["level"] == 1]
    assert {(v["cycle"], v["reference_cycle"]) for v in level_1} == {(2, 4), (3, 4)}  # the cycles they came from


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_an_aborted_test_says_so_at_the_top_with_its_reason(tmp_path):
    """The banner (status and reason) heads page 1; the duration and cycles are those run, not those planned;
    events are in words; every page says "page N of M"; the approval block ends the report."""
    reason = "force limit tripped at t = 3.200 s: |force_n| = 51000 N > limit 50000 N"
    bundle = cut_short(protocol_run(), 3.5, "aborted", reason)
    out = tmp_path / "aborted.pdf"
    render_report_pdf(bundle, out, identify=False)
    pages = pdf_text(out)[:-1]  # pdftotext ends with a form feed
    first = pages[0]
    assert "TEST ABORTED" in first and reason in first
    assert first.index("TEST ABORTED") < first.index("Specimen") < first.index("Results")
    assert "Ran 3.50 s of the 10 s planned; 3 of 10 cycles completed" in first
    assert "3.50 s run of the 10 s planned" in first and "10.00 s" not in first
    assert "INCOMPLETE" in first and "LRB-17" in first and "A. Rossi" in first and "150.00 kN" in first
    for n, page in enumerate(pages, start=1):
        assert f"page {n} of {len(pages)}" in page
    last = " ".join(pages[-1].split())
    assert "Tested by" in last and "Reviewed by" in last and "Approved by" in last and "A. Rossi" in last
    # the limit trip in words, not a dict: what the rig read at that sample and the limit
    assert "force 51.00 kN" in last and "limit: |force| <= 50.00 kN" in last and "no ref." in last
    assert "{" not in "".join(pages)
    rep = report_json(bundle, identify=False)
    assert rep["run"]["banner"]["title"] == "TEST ABORTED" and rep["run"]["banner"]["reason"] == reason
    assert rep["run"]["time_run_s"] == pytest.approx(3.5) and rep["run"]["planned_duration_s"] == 10.0


@pytest.mark.parametrize("status, title", [("interrupted", "TEST INTERRUPTED"), ("failed", "TEST FAILED"),
                                           ("stopped", "TEST STOPPED BEFORE ITS END"), ("completed", None)])
def test_the_banner_of_each_status(status, title):
    bundle = cut_short(protocol_run(), 6.0, status, f"why it {status}")
    run = report_json(bundle, identify=False)["run"]
    assert (run["banner"] or {}).get("title") == title
    if title:
        assert run["banner"]["reason"] == f"why it {status}"


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_controller_options_in_full_and_adapted_parameters_by_name(tmp_path):
    """Every option of the servo controller is printed with its unit (wrapped, never cut with "..."), and what
    it adapts under the names and units sim.controllers declares."""
    from sim.controllers import ADAPTED, OPTIONS

    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 4, controller="servo", taper_cycles=1)
    result = Simulation(scenario).run()
    write_csv(tmp_path / "timeseries.csv", result.samples)
    (tmp_path / "summary.json").write_text(json.dumps(result.summary()))
    bundle = bundle_from_csv(tmp_path / "timeseries.csv")
    assert [c["phase"] for c in bundle.cycles] == ["taper_in", "steady", "steady", "taper_out"]
    render_report_pdf(bundle, tmp_path / "r.pdf", identify=False)
    setup = " ".join(pdf_text(tmp_path / "r.pdf")[1].split())  # the setup page, lines joined
    for name in OPTIONS["servo"]:
        assert f"{name} =" in setup, name
    assert "kp_per_s = 30 1/s" in setup and "..." not in setup
    for a in ADAPTED["servo"]:
        if a.column != "model_m":
            assert f"{a.name} =" in setup, a.name
    assert "ideal (sim.rig's defaults)" in setup  # the sensors


def _logo(path):
    from PIL import Image

    Image.new("RGB", (300, 100), (20, 70, 140)).save(path)
    return path


@pytest.mark.skipif(PDFTOPPM is None, reason="pdftoppm (poppler-utils) is not installed")
def test_lab_header_with_logo_and_a_logo_that_is_not_there(tmp_path, capsys, monkeypatch):
    from isorig.cli import main

    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3, controller="pid", taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    base = ["report", "--csv", str(tmp_path / "timeseries.csv"), "--no-identify", "--serial"]
    monkeypatch.delenv("ISORIG_LAB_LOGO_FILE", raising=False)
    assert main(base + ["--out", str(tmp_path / "logo.pdf"), "--json", str(tmp_path / "logo.json"),
                        "--lab-name", "Prove Lab", "--lab-address", "Via Roma 1; Milano",
                        "--lab-logo", str(_logo(tmp_path / "logo.png"))]) == 0
    assert "warning" not in capsys.readouterr().err
    lab = json.loads((tmp_path / "logo.json").read_text())["lab"]
    assert lab == {"name": "Prove Lab", "address": "Via Roma 1; Milano", "logo_file": str(tmp_path / "logo.png"),
                   "logo_shown": True, "logo_warning": None, "units": "lab"}
    top_left = png_pages(tmp_path / "logo.pdf", tmp_path)[0][:40, :90]
    assert colour(top_left) > 0.05  # the blue logo is there
    # a missing logo: one warning line, a report all the same
    assert main(base + ["--out", str(tmp_path / "none.pdf"), "--json", str(tmp_path / "none.json"),
                        "--lab-logo", str(tmp_path / "missing.png")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "warning" in err[0] and "missing.png" in err[0] and "no such file" in err[0]
    assert json.loads((tmp_path / "none.json").read_text())["lab"]["logo_shown"] is False
    assert (tmp_path / "none.pdf").read_bytes()[:5] == b"%PDF-"
    # an unreadable one, through the settings (ISORIG_LAB_*)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    monkeypatch.setenv("ISORIG_LAB_NAME", "Env Lab")
    monkeypatch.setenv("ISORIG_LAB_LOGO_FILE", str(tmp_path / "bad.png"))
    assert main(base + ["--out", str(tmp_path / "env.pdf"), "--json", str(tmp_path / "env.json")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an image" in err[0]
    assert json.loads((tmp_path / "env.json").read_text())["lab"]["name"] == "Env Lab"


def test_the_bundle_holds_record_report_samples_cycles_and_pdf(tmp_path, capsys):
    import csv
    import io
    import zipfile

    from isorig.cli import main
    from sim.samples import RECORD_FIELDS

    url = f"sqlite:///{tmp_path / 'store.db'}"
    test_id = _store_test(url)
    assert main(["report", str(test_id), "--database-url", url, "--out", str(tmp_path / "r.pdf"), "--no-identify",
                 "--bundle", str(tmp_path / "b.zip"), "--csv-out", str(tmp_path / "d.csv")]) == 0
    assert "b.zip" in capsys.readouterr().out
    with zipfile.ZipFile(tmp_path / "b.zip") as zf:
        names = zf.namelist()
        folder = f"test-{test_id}/"
        assert sorted(names) == sorted(folder + n for n in ("README.txt", "record.json", "report.json",
                                                            "samples.csv", "cycles.csv", "report.pdf"))
        record = json.loads(zf.read(folder + "record.json"))
        report = json.loads(zf.read(folder + "report.json"))
        samples = zf.read(folder + "samples.csv").decode()
        cycles = list(csv.DictReader(io.StringIO(zf.read(folder + "cycles.csv").decode())))
        pdf = zf.read(folder + "report.pdf")
        readme = zf.read(folder + "README.txt").decode()
    assert record["id"] == test_id and report["test"]["id"] == test_id
    assert samples.splitlines()[0].split(",") == list(RECORD_FIELDS)
    assert len(samples.splitlines()) == 1 + 10_000
    assert pdf[:5] == b"%PDF-" and pdf == (tmp_path / "r.pdf").read_bytes()
    assert list(cycles[0])[:6] == ["cycle", "block", "phase", "in_headline", "t_start_s", "t_end_s"]
    assert "k_eff_n_per_m" in cycles[0] and "level_cycle" in cycles[0]
    assert [c["phase"] for c in cycles][:5] == ["taper_in", "steady", "steady", "steady", "taper_out"]
    assert [c["in_headline"] for c in cycles][:5] == ["0", "1", "1", "1", "0"]
    assert float(cycles[1]["k_eff_n_per_m"]) == pytest.approx(report["cycles"][1]["k_eff_n_per_m"], rel=1e-8)
    assert "samples.csv" in readme and "sha256" not in readme.lower().replace("sha-256", "")


def test_the_decimated_time_histories_keep_every_sample():
    """The min/max envelope covers the whole record, the remainder of the last bucket too (11 610 samples of an
    aborted test lost their last 1.6 s, where the limit trip was)."""
    from backend.reports.figures import _minmax_decimate

    t = np.arange(11_610) * 1e-3
    y = np.sin(t)
    y[-3] = 7.0  # a peak in the last, shorter bucket
    td, yd = _minmax_decimate(t, y)
    assert td[-1] == t[-1] and yd.max() == 7.0 and np.all(np.diff(td) >= 0)
    assert td.size < 3 * 2500


def history_run(stop_s: float | None = None):
    """A time-history test as the service records it (its spec, the profile built, the samples), stopped by the
    operator at ``stop_s`` if given (the record then goes on for the 1 s of the fade; here the target's own)."""
    from sim.earthquake import earthquake_from_spec

    t = np.arange(0.0, 4.0, 0.01)
    d = 0.015 * np.sin(2 * np.pi * 0.7 * t) * np.sin(np.pi * t / 4.0) ** 2
    spec = {"kind": "history", "displacement": {"time_s": t.tolist(), "displacement_m": d.tolist()},
            "taper_in_s": 0.5, "taper_out_s": 0.5}
    profile = earthquake_from_spec(spec, PRESETS["IUT_a"], 125e3)
    scenario = Scenario(PRESETS["IUT_a"], 100e5, [], vertical_load_n=125e3, history=profile.target)
    samples = Simulation(scenario).run().samples
    events = [{"kind": "operator", "actor": "alice", "time_s": 0.0, "message": "test 8 started by alice",
               "values": {"action": "start"}}]
    status = "completed"
    if stop_s is not None:
        samples = samples[: int(round((stop_s + 1.0) / 1e-3))]
        events.append({"kind": "operator", "actor": "system", "time_s": stop_s, "message": f"stop at t = {stop_s}",
                       "values": {"action": "stop", "ends_at_s": stop_s + 1.0}})
        status = "stopped"
    record = {"id": 8, "label": "history", "status": status, "isolator": "IUT_a", "supply_bar": 100.0,
              "vertical_load_n": 125e3, "controller": "servo", "driver": "simulated", "profile": profile.description,
              "earthquake": spec, "earthquake_fingerprint": profile.fingerprint, "duration_s": scenario.duration_s,
              "cycles_total": 0, "scenario": scenario.describe(), "time_s": float(samples["time_s"][-1])}
    return ReportBundle(record, samples, [], events)


@pytest.mark.skipif(PDFTOTEXT is None or PDFTOPPM is None, reason="poppler-utils are not installed")
def test_a_time_history_report_has_its_criteria_and_no_cycle_pages(tmp_path):
    bundle = history_run()
    rep = report_json(bundle, identify=False)
    eq = rep["earthquake"]
    assert [v["name"] for v in eq["verdicts"]] == ["J1", "J2", "J3"] and eq["judged"]["samples"] == len(bundle.samples)
    assert all(v["target"] == t for v, t in zip(eq["verdicts"], (1.0, 1.0, 3.0), strict=True))
    assert "J criteria" in rep["acceptance"]["note"] and rep["headline"]["cycles"] == 0
    assert "arrays" not in eq and json.dumps(rep)  # plain JSON
    out = tmp_path / "history.pdf"
    render_report_pdf(bundle, out, report=rep)
    pages = pdf_text(out, "-layout")[:-1]
    text = "\n".join(pages)
    assert "Results (the J criteria of the RTHS benchmark)" in pages[0] and "|J1| <= 1 ms" in pages[0]
    assert "an inline displacement history" in pages[0] and "none: an earthquake test has no cycles" in pages[0]
    criteria_page = next(p for p in pages if "Time history: tracking criteria" in p)
    for words in ("J2 <= 1 %", "J3 <= 3 %", "Command and measured displacement", "Tracking error",
                  "Force against displacement (whole test)", "Where the command is fastest"):
        assert words in criteria_page, words
    assert "Per-cycle metrics" not in text and "Force-displacement loops" not in text
    # summary, setup, criteria and overlay, time histories, events and approval
    images = png_pages(out, tmp_path)
    assert len(images) == 5 and all(ink(page) > 0.003 for page in images)
    assert colour(images[2]) > 0.005  # the plotted command, measurement and error
    # stopped early: the criteria judge the record up to the stop; the banner says it
    stopped = history_run(stop_s=2.0)
    rep = report_json(stopped, identify=False)
    assert rep["earthquake"]["judged"]["samples"] == 2000 and "early end at t = 2.000 s" in rep["earthquake"][
        "judged"]["what"]
    out = tmp_path / "stopped.pdf"
    render_report_pdf(stopped, out, report=rep)
    first = pdf_text(out)[0]
    assert "TEST STOPPED BEFORE ITS END" in first and "no cycles (a time history)" in first


def test_a_stability_trip_and_a_hybrid_run_are_said_in_words():
    from backend.reports.data import event_text, run_text

    monitor = {"added_energy_j": 2.0834, "specimen_energy_j": 138.3, "command_energy_j": 136.2,
               "reference_energy_j": 245.0, "limit_j": 2.0, "absolute_limit_j": 2.0, "relative_limit": 0.002,
               "ratio": 0.0085, "indicator": 1.04, "tripped": True, "reason": "RTHS stability monitor: ...",
               "trip_time_s": 0.755, "at_trip": {"time_s": 0.755, "added_energy_j": 2.0151, "limit_j": 2.0,
                                                 "reference_energy_j": 238.3}}
    text = event_text({"kind": "limit_trip", "message": "hybrid simulation unstable at t = 0.760 s",
                       "values": {"detector": "rths_stability", "action": "valve_close", "time_s": 0.76, **monitor}})
    assert "at the trip (t = 0.755 s): E_err 2.015 J, limit 2 J, reference energy 238.3 J" in text
    assert "at the end of that block: E_err 2.083 J" in text and "reference energy 245 J" in text
    assert " j " not in text and "reason" not in text.split("(", 1)[1]  # units, and the reason not said twice
    run = {"time_run_s": 0.86, "planned_duration_s": 15.001, "cycles_done": 0, "cycles_planned": 0}
    assert run_text({**run, "kind": "hybrid"}).endswith("no cycles (a hybrid simulation)")
    assert run_text({**run, "kind": "history"}).endswith("no cycles (a time history)")


def test_the_controller_options_in_the_report_are_those_of_the_labs_rig():
    """A test run on a lab's rig file: the servo's rig-declared options are the rig's, not the defaults."""
    from types import SimpleNamespace

    from backend.reports import controller_state
    from sim.rig import DEFAULT_RIG
    from sim.samples import Samples

    def in_force(rig_changes):
        record = {"controller": "servo", "scenario": {"controller": "servo", "rig_changes": rig_changes}}
        rows = controller_state(SimpleNamespace(record=record, samples=Samples.empty()))["options_in_force"]
        return {row["name"]: row["value"] for row in rows}

    assert in_force({})["mass_kg"] == DEFAULT_RIG.mass_kg
    assert in_force({"mass_kg": 4000.0})["mass_kg"] == 4000.0


def test_the_report_names_the_rig_file_its_commissioning_and_whether_the_table_followed():
    bundle = protocol_run(controller="servo")
    bundle.record["rig_file"] = {"name": "Lab B rig, commissioned", "source": "/lab/rig.json", "changed": {},
                                 "commissioning": {"date": "2026-11-27T08:00:00+00:00", "rig": "udp://10.0.0.2:5555",
                                                   "supply_pa": 1e7, "specimen": "none", "flow_r2": 0.9992,
                                                   "velocity_nrmse": 0.034}}
    bundle.record["summary"] = {"tracking_verdict": {"verdict": "did_not_follow", "words": "did not follow: 2 %"}}
    bundle.record["rig_name"] = "hall-b"
    report = report_json(bundle, identify=False)
    rig_name, sensors = rig_text(report["rig"])
    assert rig_name.startswith("hall-b: ") and report["rig"]["rig_name"] == "hall-b"  # which of the lab's rigs
    assert sensors[0] == ("rig file Lab B rig, commissioned (/lab/rig.json): commissioned 2026-11-27 on "
                          "udp://10.0.0.2:5555 at 100.0 bar, no specimen (flow balance R^2 0.9992, replay 3.4 % RMS)")
    assert report["tracking_verdict"]["words"] == "did not follow: 2 %"
    bundle.record["rig_file"]["commissioning"] = None
    assert "not commissioned" in rig_text(report_json(bundle, identify=False)["rig"])[1][0]
    bundle.record.pop("summary")
    assert "not judged" in report_json(bundle, identify=False)["tracking_verdict"]["words"]


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext (poppler-utils) is not installed")
def test_every_figure_of_the_report_in_the_units_asked(tmp_path, capsys):
    """isorig report --units si prints the figures in SI (m, N, N/m, MPa) where the lab's units (the default) are
    mm, kN, kN/mm, bar: the header, the headline and per-cycle tables, the checks, the events and the plots'
    axes; report.json stays SI and names the units of the PDF."""
    import re

    from isorig.cli import main

    scenario = Scenario.sine("IUT_a", 100.0, 0.02, 1.0, 3, controller="pid", taper_cycles=1)
    write_csv(tmp_path / "timeseries.csv", Simulation(scenario).run().samples)
    base = ["report", "--csv", str(tmp_path / "timeseries.csv"), "--no-identify", "--serial", "--isolator", "IUT_a",
            "--supply-bar", "100", "--protocol", "quick_check"]
    texts = {}
    for units in ("lab", "si"):
        out = tmp_path / f"{units}.pdf"
        assert main(base + ["--out", str(out), "--json", str(tmp_path / f"{units}.json"), "--units", units]) == 0
        texts[units] = " ".join(" ".join(pdf_text(out, "-layout")).split())
        assert json.loads((tmp_path / f"{units}.json").read_text())["lab"]["units"] == units
    capsys.readouterr()
    lab, si = texts["lab"], texts["si"]
    assert "k_d = 1.25 kN/mm" in lab and "k_d = 1250000 N/m" in si
    assert "Supply pressure 100.0 bar" in lab and "Supply pressure 10.00 MPa" in si
    assert "level 1: 10.00 mm at 1 Hz" in lab and "level 1: 0.01000 m at 1 Hz" in si
    assert "force [kN]" in lab and "force [N]" in si and "K_eff [kN/mm]" in lab and "K_eff [N/m]" in si
    assert "s mm mm kN kN kN/mm J % kN kN/mm" in lab and "s m m N N N/m J % N N/m" in si  # the per-cycle table
    assert not re.search(r"\d (N/m|N|m|MPa)\b", lab), re.findall(r".{30}\d (?:N/m|N|m|MPa)\b", lab)
    assert not re.search(r"\d (kN/mm|kN|mm|bar|mm/s)\b", si), re.findall(r".{30}\d (?:kN/mm|kN|mm|bar)\b", si)
    report = json.loads((tmp_path / "si.json").read_text())
    assert report["isolator_nominal"]["kd_n_per_m"] == 1.25e6  # the JSON keeps SI
    # the raw |y - r| in three significant digits, not at the display's 0.01 mm (0.012 mm read 0.01 mm)
    rms_m = report["tracking"]["rms_y_minus_r_m"]
    from backend.units import sig_digits

    assert f"RMS {sig_digits(rms_m * 1e3, 3)} mm, peak" in lab, re.findall(r"RMS \S+ \S+, peak", lab)
    assert f"RMS {sig_digits(rms_m, 3)} m, peak" in si, re.findall(r"RMS \S+ \S+, peak", si)
