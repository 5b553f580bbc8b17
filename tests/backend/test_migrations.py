"""Migrations from the first schema to the newest, on SQLite and on a real PostgreSQL server: a lab's records
written under revision 0001 survive every step (0001 -> 0002 -> ... -> head), the newest schema is the models'
(alembic's autogenerate diff is empty), and revision 0007 names the rig of the old records "rig-1"."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import select, text

from backend import store
from backend.codec import ARRAYS_CODEC, SAMPLES_CODEC, encode_arrays, encode_samples
from backend.db import alembic_config, make_engine, session_factory, upgrade
from backend.models import Base
from backend.settings import DEFAULT_RIG_NAME
from sim.samples import N_FIELDS

DELETED_TEST_ID = 7  # a test deleted before the upgrade: its id lives on in its events, and is never given again


def revisions(url: str) -> list[str]:
    """Every revision, oldest first."""
    script = ScriptDirectory.from_config(alembic_config(url))
    return [r.revision for r in reversed(list(script.walk_revisions()))]


@pytest.fixture(params=["sqlite", "postgresql"])
def url(request, tmp_path):
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'migrate.db'}"
    return request.getfixturevalue("postgres").database()


def samples_rows(n: int) -> np.ndarray:
    rows = np.random.default_rng(3).normal(size=(n, N_FIELDS))
    rows[:, 0] = np.arange(n) * 1e-3
    return rows


def insert_at_0001(conn, rows: np.ndarray) -> None:
    """A lab's records as the first schema held them: a test with two sample chunks and a cycle, its events, an
    event of a test deleted since, an event of no test, a user isolator."""
    now = datetime(2026, 11, 22, 9, 30, tzinfo=UTC)
    conn.execute(text(
        "INSERT INTO tests (id, created_at, started_at, ended_at, status, reason, label, isolator, supply_bar, "
        "controller, speed, driver, request, scenario, limits, duration_s, cycles_total, samples_stored, time_s, "
        "summary) VALUES (3, :now, :now, :now, 'completed', NULL, 'old test', 'IUT_a', 100.0, 'pid', 1.0, "
        "'simulated', :request, '{}', '{}', 2.0, 1, :n, :t, :summary)"),
        {"now": now, "request": '{"profile": {"kind": "sine"}}', "n": len(rows), "t": float(rows[-1, 0]),
         "summary": f'{{"samples": {len(rows)}}}'})
    half = len(rows) // 2
    for seq, block in enumerate((rows[:half], rows[half:])):
        conn.execute(text("INSERT INTO sample_chunks (test_id, seq, t0_s, n_rows, n_columns, codec, data) "
                          "VALUES (3, :seq, :t0, :n, :c, :codec, :data)"),
                     {"seq": seq, "t0": float(block[0, 0]), "n": block.shape[0], "c": block.shape[1],
                      "codec": SAMPLES_CODEC, "data": encode_samples(block)})
    loop = np.linspace(-0.01, 0.01, 50)
    conn.execute(text("INSERT INTO cycles (test_id, cycle, block, t_start_s, t_end_s, metrics, n_points, codec, "
                      "loop_data) VALUES (3, 1, 0, 0.0, 1.0, :metrics, 50, :codec, :data)"),
                 {"metrics": '{"k_eff_n_per_m": 1500000.0}', "codec": ARRAYS_CODEC,
                  "data": encode_arrays(loop, loop * 1e6)})
    for test_id, message in ((3, "test 3 completed"), (DELETED_TEST_ID, "test 7 deleted by operator"),
                             (None, "user isolator 'X' added by operator")):
        conn.execute(text("INSERT INTO events (test_id, created_at, time_s, kind, actor, message, \"values\") "
                          "VALUES (:test_id, :now, NULL, 'operator', 'operator', :message, '{}')"),
                     {"test_id": test_id, "now": now, "message": message})
    conn.execute(text("INSERT INTO user_isolators (name, created_at, definition) VALUES ('X', :now, :d)"),
                 {"now": now, "d": '{"name": "X"}'})
    if conn.dialect.name == "postgresql":  # the ids were the sequence's: it had handed out 1 .. 7
        conn.execute(text("SELECT setval(pg_get_serial_sequence('tests', 'id'), :last)"), {"last": DELETED_TEST_ID})


def records_survive(conn, rows: np.ndarray, revision: str) -> None:
    test = conn.execute(text("SELECT label, status, samples_stored, isolator FROM tests WHERE id = 3")).one()
    assert tuple(test) == ("old test", "completed", len(rows), "IUT_a"), revision
    chunks = conn.execute(text("SELECT count(*), sum(n_rows) FROM sample_chunks WHERE test_id = 3")).one()
    assert tuple(chunks) == (2, len(rows)), revision
    assert conn.execute(text("SELECT count(*) FROM cycles WHERE test_id = 3")).scalar() == 1, revision
    assert conn.execute(text("SELECT count(*) FROM events")).scalar() == 3, revision
    assert conn.execute(text("SELECT count(*) FROM user_isolators")).scalar() == 1, revision


def test_every_migration_keeps_the_records_and_ends_at_the_models(url):
    all_revisions = revisions(url)
    assert all_revisions[0] == "0001" and "0007" in all_revisions  # later revisions are stepped through too
    engine = make_engine(url)
    rows = samples_rows(1500)
    upgrade(engine, "0001")
    with engine.begin() as conn:
        insert_at_0001(conn, rows)
    for revision in all_revisions[1:]:  # one step at a time, the records checked after each
        upgrade(engine, revision)
        with engine.connect() as conn:
            assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar() == revision
            records_survive(conn, rows, revision)
    upgrade(engine)  # at head already: nothing to do
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
        assert diff == [], diff
    sessions = session_factory(engine)
    with sessions() as session:
        bundle = store.load_test_bundle(session, 3)
        assert bundle.record["rig_name"] == DEFAULT_RIG_NAME  # 0007: the old records are the one rig's
        assert np.allclose(bundle.samples.array, rows, rtol=1e-6, atol=1e-6)
        assert bundle.cycles[0]["k_eff_n_per_m"] == 1.5e6 and len(bundle.cycles[0]["displacement_m"]) == 50
        events = {e["message"]: e["rig_name"] for e in store.load_events(session, None)}
        assert events == {"test 3 completed": DEFAULT_RIG_NAME, "test 7 deleted by operator": DEFAULT_RIG_NAME,
                          "user isolator 'X' added by operator": None}
        new = store.create_test(session, rig_name="rig-b", isolator="IUT_a", supply_bar=100.0, controller="pid",
                                speed=1.0, driver="simulated", request={}, scenario={}, limits={}, duration_s=1.0,
                                cycles_total=1, label="after the upgrade")
        session.commit()
        assert new.id > DELETED_TEST_ID  # SQLite: 0007 recreated the table and kept 0006's sequence going
        assert store.rig_names(session) == [DEFAULT_RIG_NAME, "rig-b"]
    engine.dispose()


def test_0007_downgrades_and_upgrades_again_keeping_the_records(url):
    engine = make_engine(url)
    rows = samples_rows(400)
    upgrade(engine, "0001")
    with engine.begin() as conn:
        insert_at_0001(conn, rows)
    upgrade(engine)
    cfg = alembic_config(url)
    with engine.connect() as conn:
        sqlite = engine.dialect.name == "sqlite"
        if sqlite:  # as backend.db.upgrade: a recreated table must not cascade its drop to the samples
            conn.exec_driver_sql("PRAGMA foreign_keys=OFF")
            conn.commit()
        with conn.begin():
            cfg.attributes["connection"] = conn
            command.downgrade(cfg, "0006")  # and any revision after 0007 first
        records_survive(conn, rows, "0006 (down)")
        columns = {r[1] for r in conn.exec_driver_sql("PRAGMA table_info(tests)")} if sqlite else set(
            conn.execute(text("SELECT column_name FROM information_schema.columns WHERE table_name = 'tests'"))
            .scalars())
        assert "rig_name" not in columns and "label" in columns
    upgrade(engine)
    with engine.connect() as conn:
        records_survive(conn, rows, "0007 (again)")
        assert conn.execute(text("SELECT rig_name FROM tests WHERE id = 3")).scalar() == DEFAULT_RIG_NAME
    engine.dispose()


def test_services_starting_together_on_postgresql_migrate_once(postgres):
    """Several rigs' services start at once on a new database: one migrates, the others wait for it (an advisory
    lock) and find the schema at head, instead of failing on tables the first has just created."""
    import threading

    url = postgres.database()
    errors: list[BaseException] = []
    go = threading.Barrier(4)

    def start_service() -> None:
        engine = make_engine(url)
        try:
            go.wait()
            upgrade(engine)
        except BaseException as exc:  # noqa: BLE001 (collected and asserted below)
            errors.append(exc)
        finally:
            engine.dispose()

    threads = [threading.Thread(target=start_service) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert errors == []
    engine = make_engine(url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalars().all() == [revisions(url)[-1]]
        assert compare_metadata(MigrationContext.configure(conn), Base.metadata) == []
    engine.dispose()


@pytest.mark.parametrize("dialect", ["sqlite", "postgresql"])
def test_services_starting_together_create_the_first_accounts_once(dialect, tmp_path, request):
    """The start-up writes of several rigs' services starting together (the service account, the first admin) are
    done one at a time: each service starts, one admin is created and announced once."""
    import threading

    from backend.app import bootstrap_accounts
    from backend.models import UserAccount

    url = (f"sqlite:///{tmp_path / 'start.db'}" if dialect == "sqlite"
           else request.getfixturevalue("postgres").database())
    engine = make_engine(url)
    upgrade(engine)
    sessions = session_factory(engine)
    results: list = []
    go = threading.Barrier(3)

    def start_service() -> None:
        try:
            go.wait()
            results.append(bootstrap_accounts(sessions, True))
        except BaseException as exc:  # noqa: BLE001 (asserted below)
            results.append(exc)

    threads = [threading.Thread(target=start_service) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not [r for r in results if isinstance(r, BaseException)], results
    assert len([r for r in results if r is not None]) == 1  # the admin's password told by one service only
    with sessions() as s:
        names = sorted(s.scalars(select(UserAccount.name)))
    assert names == ["admin", "automation"]
    engine.dispose()
