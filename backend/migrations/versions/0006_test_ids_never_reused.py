"""A test's id is never given again: SQLite's tests table gets AUTOINCREMENT, its sequence seeded with the
largest id ever used (a deleted test's id survives in the audit log, whose events keep it).

Without it SQLite hands out max(id) + 1, so after the newest test is deleted (a test that never ran), its id
went to the next test and the audit log of that id mixed two tests. PostgreSQL's sequences never go back:
nothing to do there.

The table is recreated (SQLite cannot alter a primary key); backend.db.upgrade runs migrations with SQLite's
foreign-key enforcement off, so dropping the old table does not cascade to the samples and cycles.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-27
"""

from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    if op.get_bind().dialect.name != "sqlite":
        return
    with op.batch_alter_table("tests", recreate="always", table_kwargs={"sqlite_autoincrement": True}):
        pass
    op.execute("DELETE FROM sqlite_sequence WHERE name = 'tests'")
    op.execute("INSERT INTO sqlite_sequence (name, seq) SELECT 'tests', max(coalesce((SELECT max(id) FROM tests), "
               "0), coalesce((SELECT max(test_id) FROM events), 0))")


def downgrade() -> None:
    if op.get_bind().dialect.name != "sqlite":
        return
    with op.batch_alter_table("tests", recreate="always", table_kwargs={"sqlite_autoincrement": False}):
        pass
