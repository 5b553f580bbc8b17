"""docker-compose.yml and the Dockerfile run the README's run command; the PostgreSQL profile is optional."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parents[2]


def readme_run_command() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## The two commands", 1)[1]
    first = next(line.strip() for line in section.splitlines() if line.startswith("    ") and line.strip())
    return shlex.split(first)


def test_compose_runs_the_readme_command():
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    service = compose["services"]["isorig"]
    command = service["command"]
    command = shlex.split(command) if isinstance(command, str) else command
    assert readme_run_command() == ["bash", "scripts/run.sh"]
    assert command == readme_run_command()
    env = service["environment"]
    assert env["ISORIG_HOST"] == "0.0.0.0" and env["ISORIG_DATA_DIR"] == "/data"
    postgres = compose["services"]["postgres"]
    assert postgres["profiles"] == ["postgres"]  # optional: only with --profile postgres
    assert service["depends_on"]["postgres"]["required"] is False
    # docker stop: the service's controlled shutdown (up to backend.service.SHUTDOWN_GRACE_S) fits the grace period
    from backend.service import SHUTDOWN_GRACE_S

    grace = re.fullmatch(r"(\d+)s", str(service["stop_grace_period"]))
    assert grace is not None and int(grace.group(1)) >= SHUTDOWN_GRACE_S + 5


def test_dockerfile_runs_the_readme_command():
    text = (ROOT / "Dockerfile").read_text()
    cmd = re.search(r"^CMD (\[.*\])$", text, re.M)
    assert cmd and json.loads(cmd.group(1)) == readme_run_command()
    assert "scripts/setup.sh" in text
