"""Store: migrations match the models, sample codec precision and size, bundle contract, on SQLite and on a real
PostgreSQL server (the ``postgres`` fixture, tests/backend/conftest.py)."""

from __future__ import annotations

import numpy as np
import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import text

from backend import store
from backend.codec import decode_samples, encode_samples
from backend.db import make_engine, session_factory, upgrade
from backend.models import Base
from sim.engine import Scenario, Simulation
from sim.samples import N_FIELDS


def test_migrations_match_the_models(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'm.db'}")
    upgrade(engine)
    upgrade(engine)  # idempotent
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
        assert diff == []
        assert conn.execute(text("PRAGMA journal_mode")).scalar() == "wal"


def test_sample_codec_keeps_7_digits_and_compresses():
    rows = Simulation(Scenario.sine("IUT_b", 70, 0.03, 1.0, 3, controller="pid")).run().samples[:1000].array
    data = encode_samples(rows)
    back = decode_samples(data, *rows.shape)
    assert np.array_equal(back[:, 0], rows[:, 0])  # time exact
    finite = np.isfinite(rows)
    assert np.array_equal(np.isfinite(back), finite)
    scale = np.nanmax(np.abs(rows), axis=0) + 1e-30
    assert np.nanmax(np.abs(back - rows) / scale) < 1e-6
    assert len(data) < 0.5 * rows.size * 4  # well under raw float32


def test_samples_of_older_and_newer_chunks_load_as_one_array(tmp_path):
    """A record whose first chunk was stored with fewer fields (an older version) reads those fields as NaN; every
    chunk lands in one array, as the codec decoded it, in the stored order."""
    engine = make_engine(f"sqlite:///{tmp_path / 's.db'}")
    upgrade(engine)
    rng = np.random.default_rng(7)
    old, new = rng.normal(size=(300, 9)), rng.normal(size=(200, N_FIELDS))
    old[:, 0], new[:, 0] = np.arange(300) * 1e-3, 0.3 + np.arange(200) * 1e-3
    with session_factory(engine)() as s:
        t = store.create_test(s, rig_name="rig-1", isolator="IUT_a", supply_bar=100.0, controller="pid",
                              speed=1.0, driver="simulated", request={}, scenario={}, limits={}, duration_s=0.5,
                              cycles_total=0, label="")
        store.append_samples(s, t, old)
        store.append_samples(s, t, new)
        s.commit()
        loaded = store.load_samples(s, t.id).array
        assert store.load_samples(s, t.id + 1).array.shape == (0, N_FIELDS)  # no chunk: an empty record
    assert loaded.shape == (500, N_FIELDS)
    assert np.array_equal(loaded[:300, :9], decode_samples(encode_samples(old), 300, 9))
    assert np.isnan(loaded[:300, 9:]).all()
    assert np.array_equal(loaded[300:], decode_samples(encode_samples(new), 200, N_FIELDS))
    assert np.array_equal(loaded[:, 0], np.concatenate([old[:, 0], new[:, 0]]))  # time exact


def test_samples_stored_by_a_newer_version_are_refused_with_their_width(tmp_path):
    """Rows wider than the fields this version knows are refused by name, whole or chunk by chunk."""
    engine = make_engine(f"sqlite:///{tmp_path / 'w.db'}")
    upgrade(engine)
    wide = np.zeros((10, N_FIELDS + 2))
    with session_factory(engine)() as s:
        t = store.create_test(s, rig_name="rig-1", isolator="IUT_a", supply_bar=100.0, controller="pid",
                              speed=1.0, driver="simulated", request={}, scenario={}, limits={}, duration_s=0.5,
                              cycles_total=0, label="")
        store.append_samples(s, t, wide)
        s.commit()
        expected = f"stored rows have {N_FIELDS + 2} columns, more than the {N_FIELDS} known fields"
        with pytest.raises(ValueError, match=expected):
            store.load_samples(s, t.id)
        with pytest.raises(ValueError, match=expected):
            list(store.iter_sample_blocks(s, t.id))


def make_bundle(url: str) -> store.TestBundle:
    engine = make_engine(url)
    upgrade(engine)
    sessions = session_factory(engine)
    rows = np.random.default_rng(1).normal(size=(2500, N_FIELDS))
    rows[:, 0] = np.arange(2500) * 1e-3
    with sessions() as s:
        t = store.create_test(s, rig_name="rig-1", isolator="IUT_a", supply_bar=100.0, controller="pid",
                              speed=1.0, driver="simulated", request={"profile": {"kind": "sine"}}, scenario={},
                              limits={}, duration_s=2.5, cycles_total=2, label="")
        for i in range(0, 2500, 1000):
            store.append_samples(s, t, rows[i:i + 1000])
        store.add_cycle(s, t.id, 1, 0, 0.0, 1.0, {"k_eff_n_per_m": 1.5e6, "xi_eff": float("nan")},
                        rows[:1000, 3], rows[:1000, 5])
        store.add_event(s, t.id, "limit_trip", "x", {"force_n": 1.0})
        s.commit()
        bundle = store.load_test_bundle(s, t.id)
        with pytest.raises(KeyError):
            store.load_test_bundle(s, t.id + 1)
    engine.dispose()
    assert bundle.samples.shape == rows.shape
    assert np.allclose(bundle.samples.array, rows, rtol=1e-6, atol=1e-6)
    return bundle


def test_bundle_contract_sqlite(tmp_path):
    bundle = make_bundle(f"sqlite:///{tmp_path / 'b.db'}")
    assert bundle.record["samples_stored"] == 2500 and bundle.record["cycles_done"] == 1
    c = bundle.cycles[0]
    assert c["cycle"] == 1 and c["k_eff_n_per_m"] == 1.5e6 and c["xi_eff"] is None
    assert len(c["displacement_m"]) == len(c["force_n"]) == 1000
    assert bundle.events[0]["kind"] == "limit_trip" and bundle.events[0]["values"] == {"force_n": 1.0}


def test_bundle_contract_postgresql(postgres):
    """On a real PostgreSQL server (started by the ``postgres`` fixture, or ISORIG_TEST_POSTGRES_URL's)."""
    bundle = make_bundle(postgres.database())
    assert bundle.record["samples_stored"] == 2500 and bundle.cycles[0]["xi_eff"] is None
    assert bundle.record["rig_name"] == "rig-1" and bundle.events[0]["rig_name"] == "rig-1"


def test_service_runs_a_test_on_postgresql(tmp_path, postgres):
    from conftest import create_and_start, make_settings, wait_for
    from fastapi.testclient import TestClient

    from backend.app import create_app

    url = postgres.database()
    with TestClient(create_app(make_settings(tmp_path, database_url=url))) as client:
        assert client.get("/api/health").json()["database"] == "postgresql"
        rec = wait_for(client, create_and_start(client))
        assert rec["status"] == "completed" and rec["samples_stored"] == 1500 and rec["cycles_done"] == 3
        assert len(client.get(f"/api/tests/{rec['id']}/data.csv").text.splitlines()) == 1501


def test_cycles_keep_their_phase_and_older_cycles_get_the_planned_one(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'p.db'}")
    upgrade(engine)
    sessions = session_factory(engine)
    profile = [{"kind": "sine", "amplitude_m": 0.01, "frequency_hz": 1.0, "cycles": 3, "taper_cycles": 1,
                "offset_m": 0.0}]
    loop = np.zeros(10)
    with sessions() as s:
        t = store.create_test(s, rig_name="rig-1", isolator="IUT_a", supply_bar=100.0, controller="pid", speed=1.0,
                              driver="simulated", request={"profile": profile[0]}, scenario={"profile": profile},
                              limits={}, duration_s=3.0, cycles_total=3, label="")
        for n in (1, 2, 3):  # stored before phases existed: no phase
            store.add_cycle(s, t.id, n, 0, n - 1.0, float(n), {"k_eff_n_per_m": 1e6 * n}, loop, loop)
        t2 = store.create_test(s, rig_name="rig-1", isolator="IUT_a", supply_bar=100.0, controller="pid", speed=1.0,
                               driver="simulated", request={}, scenario={"profile": profile}, limits={},
                               duration_s=3.0, cycles_total=3, label="")
        store.add_cycle(s, t2.id, 1, 0, 0.0, 1.0, {}, loop, loop, phase="ramp_out")
        s.commit()
        assert [c["phase"] for c in store.load_cycles(s, t.id)] == ["taper_in", "steady", "taper_out"]
        assert store.load_cycles(s, t2.id, arrays=False)[0]["phase"] == "ramp_out"
