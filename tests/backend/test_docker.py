"""docker-compose.yml and the Dockerfile run the README's run command; the compose file runs two rigs' services
(each its own --rig-name as ISORIG_RIG_NAME, port and data volume) on one PostgreSQL database."""

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


def test_compose_runs_two_rigs_on_one_postgresql_with_the_readme_command():
    from sqlalchemy.engine import make_url

    from backend.service import SHUTDOWN_GRACE_S
    from backend.settings import check_rig_name

    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    rigs = {name: s for name, s in services.items() if name != "postgres"}
    assert sorted(rigs) == ["rig-a", "rig-b"] and set(services) == {"rig-a", "rig-b", "postgres"}
    assert readme_run_command() == ["bash", "scripts/run.sh"]
    postgres = services["postgres"]
    assert "profiles" not in postgres  # not optional: the rigs' common database
    assert "ports" not in postgres  # reached by the services only, never published
    pg_env = postgres["environment"]
    names, ports, volumes, urls = set(), set(), set(), set()
    for name, service in rigs.items():
        command = service["command"]
        command = shlex.split(command) if isinstance(command, str) else command
        assert command == readme_run_command(), name
        env = service["environment"]
        assert env["ISORIG_RIG_NAME"] == name and check_rig_name(env["ISORIG_RIG_NAME"]) == name
        assert env["ISORIG_HOST"] == "0.0.0.0" and env["ISORIG_DATA_DIR"] == "/data"
        port = int(env["ISORIG_PORT"])
        assert service["ports"] == [f"127.0.0.1:{port}:{port}"], name  # each its own port, on the host's loopback
        volume, mount = service["volumes"][0].split(":")
        assert mount == "/data" and volume in compose["volumes"] and len(service["volumes"]) == 1
        url = make_url(env["ISORIG_DATABASE_URL"].replace("${ISORIG_POSTGRES_PASSWORD:-isorig}", "pw"))
        assert url.drivername == "postgresql+psycopg" and url.host == "postgres" and url.port == 5432
        assert url.username == pg_env["POSTGRES_USER"] and url.database == pg_env["POSTGRES_DB"]
        assert "${ISORIG_POSTGRES_PASSWORD:-isorig}" in env["ISORIG_DATABASE_URL"]
        assert pg_env["POSTGRES_PASSWORD"] == "${ISORIG_POSTGRES_PASSWORD:-isorig}"  # the same password
        assert service["depends_on"]["postgres"]["condition"] == "service_healthy"
        assert service["depends_on"]["postgres"].get("required", True) is True
        # docker stop: the controlled shutdown (up to backend.service.SHUTDOWN_GRACE_S) fits the grace period
        grace = re.fullmatch(r"(\d+)s", str(service["stop_grace_period"]))
        assert grace is not None and int(grace.group(1)) >= SHUTDOWN_GRACE_S + 5
        names.add(name), ports.add(port), volumes.add(volume), urls.add(env["ISORIG_DATABASE_URL"])
    assert len(ports) == len(volumes) == 2 and len(urls) == 1  # own port and data, one database
    assert "pg_isready -U isorig -d isorig" in " ".join(postgres["healthcheck"]["test"])


def test_dockerfile_runs_the_readme_command():
    text = (ROOT / "Dockerfile").read_text()
    cmd = re.search(r"^CMD (\[.*\])$", text, re.M)
    assert cmd and json.loads(cmd.group(1)) == readme_run_command()
    assert "scripts/setup.sh" in text
