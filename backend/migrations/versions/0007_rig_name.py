"""Several rigs on one database: every test and its events carry the name of the rig they ran on.

A lab with two or three rigs runs one service per rig (``isorig serve --rig-name``) on one database. The
records made before, by the lab's one service, get the default name "rig-1" (backend.settings.DEFAULT_RIG_NAME),
as do the events of a test; events that concern no test (a user isolator added) keep no rig.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-27
"""

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None

DEFAULT_RIG_NAME = "rig-1"  # as backend.settings.DEFAULT_RIG_NAME when this was written (a migration never changes)


def upgrade() -> None:
    sqlite = op.get_bind().dialect.name == "sqlite"
    # SQLite recreates the table: keep the AUTOINCREMENT of migration 0006 (ids never given again)
    with op.batch_alter_table("tests", table_kwargs={"sqlite_autoincrement": True} if sqlite else {}) as batch:
        batch.add_column(sa.Column("rig_name", sa.String(64), nullable=True))
    op.execute(sa.text("UPDATE tests SET rig_name = :name").bindparams(name=DEFAULT_RIG_NAME))
    with op.batch_alter_table("tests", table_kwargs={"sqlite_autoincrement": True} if sqlite else {}) as batch:
        batch.alter_column("rig_name", existing_type=sa.String(64), nullable=False)
        batch.create_index("ix_tests_rig_name", ["rig_name"])
    if sqlite:
        _reseed_test_ids()
    with op.batch_alter_table("events") as batch:
        batch.add_column(sa.Column("rig_name", sa.String(64), nullable=True))
        batch.create_index("ix_events_rig_name", ["rig_name"])
    op.execute(sa.text("UPDATE events SET rig_name = :name WHERE test_id IS NOT NULL").bindparams(
        name=DEFAULT_RIG_NAME))


def _reseed_test_ids() -> None:
    """SQLite's recreated tests table counts its ids from its largest one: as migration 0006, from the largest
    id ever used (a deleted test's id lives on in the events), so that no id is given again."""
    op.execute("DELETE FROM sqlite_sequence WHERE name = 'tests'")
    op.execute("INSERT INTO sqlite_sequence (name, seq) SELECT 'tests', max(coalesce((SELECT max(id) FROM tests), "
               "0), coalesce((SELECT max(test_id) FROM events), 0))")


def downgrade() -> None:
    sqlite = op.get_bind().dialect.name == "sqlite"
    with op.batch_alter_table("events") as batch:
        batch.drop_index("ix_events_rig_name")
        batch.drop_column("rig_name")
    with op.batch_alter_table("tests", table_kwargs={"sqlite_autoincrement": True} if sqlite else {}) as batch:
        batch.drop_index("ix_tests_rig_name")
        batch.drop_column("rig_name")
    if sqlite:
        _reseed_test_ids()
