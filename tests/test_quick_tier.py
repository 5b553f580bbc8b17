"""`scripts/test.sh --quick` selects what it says, and the full `scripts/test.sh` still runs every test (issue 33,
item 7).

The script runs in a copy of itself whose `.venv/bin/python` only writes down the arguments it was given (and
whose setup, ruff and apt-get do nothing), so the pytest commands checked are the script's own, word for word.
Their selection (`-m`, `--ignore`) is then applied to one real collection of the whole suite, with each test's
markers, by pytest's own marker-expression evaluator; an argument that selects in a way this test does not know
fails it, so that a change of the script's selection is checked, never passed over. The collection is the
session's own when it collected the whole suite (the script's runs: tests/conftest.py keeps it), else one made
here, which takes seconds, so these two checks are marked slow: the full run (CI) makes them, the quick tier not."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from _pytest.mark.expression import Expression

ROOT = Path(__file__).resolve().parent.parent
E2E = "tests/e2e/"

# writes every collected test's node id and marker names, as JSON, to $QUICK_TIER_DUMP
DUMP_PLUGIN = """
import json, os

def pytest_collection_finish(session):
    with open(os.environ["QUICK_TIER_DUMP"], "w") as f:
        json.dump({item.nodeid: sorted({m.name for m in item.iter_markers()}) for item in session.items}, f)
"""

# arguments that do not change which tests run, with the number of values each takes
NEUTRAL = {"-q": 0, "--durations": 1, "--junitxml": 1, "-n": 1, "--dist": 1}


def commands(tmp_path: Path, *args: str) -> list[list[str]]:
    """The pytest commands (arguments after `-m pytest`) that `scripts/test.sh ARGS` runs, in order."""
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "test.sh", root / "scripts" / "test.sh")
    (root / "scripts" / "setup.sh").write_text("exit 0\n")
    bin_dir = root / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    log = tmp_path / "commands.jsonl"
    stubs = {"python": f'exec {sys.executable} -c \'import json, sys; open("{log}", "a").write('
                       'json.dumps(sys.argv[1:]) + "\\n")\' "$@"\n',
             "ruff": "exit 0\n"}
    for name, body in stubs.items():
        (bin_dir / name).write_text("#!/bin/sh\n" + body)
        (bin_dir / name).chmod(0o755)
    path_dir = tmp_path / "path"  # apt-get and sudo, should the script want a Debian package here: nothing
    path_dir.mkdir()
    for name in ("apt-get", "sudo"):
        (path_dir / name).write_text("#!/bin/sh\nexit 0\n")
        (path_dir / name).chmod(0o755)
    env = {**os.environ, "PATH": f"{path_dir}:{os.environ['PATH']}", "ISORIG_TEST_WORKERS": "2"}
    done = subprocess.run(["bash", str(root / "scripts" / "test.sh"), *args], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    runs = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    for run in runs:
        assert run[:2] == ["-m", "pytest"], run
    return [run[2:] for run in runs]


def selected(argv: list[str], tests: dict[str, list[str]]) -> set[str]:
    """The tests of ``tests`` (node id: marker names) that pytest run with ``argv`` would run."""
    expression, ignored, i = None, [], 0
    while i < len(argv):
        arg = argv[i]
        name, eq, value = arg.partition("=")
        if name in NEUTRAL:
            i += 1 if eq else 1 + NEUTRAL[name]
            continue
        if name in ("-m", "--ignore"):
            if not eq:
                i, value = i + 1, argv[i + 1]
            if name == "-m":
                expression = value
            else:
                ignored.append(value.rstrip("/") + "/")
            i += 1
            continue
        pytest.fail(f"scripts/test.sh gives pytest {arg!r}, which this test does not know how to apply: teach it")
    compiled = Expression.compile(expression) if expression else None
    return {nodeid for nodeid, markers in tests.items()
            if not any(nodeid.startswith(prefix) for prefix in ignored)
            and (compiled is None or compiled.evaluate(lambda mark, /, **_kw: mark in markers))}  # noqa: B023


@pytest.fixture(scope="module")
def every_test(tmp_path_factory, whole_suite) -> dict[str, list[str]]:
    """Every test of the suite (the testpaths of pyproject.toml, as the script's commands collect), its markers:
    this session's own collection where it was the whole suite (the script's runs), else one made here."""
    if whole_suite is not None:
        return whole_suite
    tmp = tmp_path_factory.mktemp("collect")
    (tmp / "quick_tier_dump.py").write_text(DUMP_PLUGIN)
    dump = tmp / "tests.json"
    env = {**os.environ, "QUICK_TIER_DUMP": str(dump),
           "PYTHONPATH": os.pathsep.join(p for p in (str(tmp), os.environ.get("PYTHONPATH")) if p)}
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                           "-p", "no:xdist", "-p", "quick_tier_dump"], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads(dump.read_text())


@pytest.mark.slow  # a collection of the whole suite: scripts/test.sh --quick leaves it out
def test_the_quick_tier_runs_every_test_but_the_real_time_browser_and_slow_ones(tmp_path, every_test):
    runs = commands(tmp_path, "--quick")
    assert len(runs) == 1, runs
    quick = selected(runs[0], every_test)
    expected = {t for t, marks in every_test.items()
                if not t.startswith(E2E) and "realtime" not in marks and "slow" not in marks}
    assert sorted(quick - expected) == [], "in the quick tier, but real-time, browser or slow"
    assert sorted(expected - quick) == [], "left out of the quick tier, though neither real-time, browser nor slow"
    # the tiers the quick one leaves out are in use, and it is most of the suite
    assert any(t.startswith(E2E) for t in every_test)
    assert any("realtime" in m for m in every_test.values()) and any("slow" in m for m in every_test.values())
    assert len(quick) > len(every_test) / 2
    # it runs in parallel workers, one test file to a worker (module fixtures start once)
    assert "-n" in runs[0] and runs[0][runs[0].index("--dist") + 1] == "loadfile"


def test_the_quick_tier_passes_extra_arguments_to_pytest(tmp_path):
    runs = commands(tmp_path, "--quick", "-k", "store", "-x")
    assert runs[0][-3:] == ["-k", "store", "-x"]


@pytest.mark.slow  # a collection of the whole suite: scripts/test.sh --quick leaves it out
def test_the_full_run_runs_every_test_once_slow_ones_included(tmp_path, every_test):
    runs = commands(tmp_path)
    # in parallel, then the real-time ones two at a time, then those that judge tight timing one at a time
    assert len(runs) == 3, runs
    parallel, realtime, strict = (selected(run, every_test) for run in runs)
    assert parallel | realtime | strict == set(every_test)
    assert parallel & realtime == set() and parallel & strict == set() and realtime & strict == set()
    assert realtime | strict == {t for t, marks in every_test.items() if "realtime" in marks}
    assert strict == {t for t, marks in every_test.items() if "strict_timing" in marks}  # each one real-time too
    assert strict and "-n" not in runs[2]  # one at a time
    assert {t for t, marks in every_test.items() if "slow" in marks} <= parallel
