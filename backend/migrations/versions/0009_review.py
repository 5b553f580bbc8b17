"""Review and approval of a test record: its state (unreviewed, approved, rejected), who reviewed it and when,
the note or reason, and for an approved record the SHA-256 it was approved with (backend.review).

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-27
"""

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # plain ADD COLUMN (no batch recreate, which would drop SQLite's AUTOINCREMENT of migration 0006)
    op.add_column("tests", sa.Column("review_state", sa.String(16), nullable=False, server_default="unreviewed"))
    op.add_column("tests", sa.Column("reviewed_by", sa.String(64)))
    op.add_column("tests", sa.Column("reviewed_at", sa.DateTime(timezone=True)))
    op.add_column("tests", sa.Column("review_note", sa.Text()))
    op.add_column("tests", sa.Column("record_sha256", sa.String(64)))
    op.add_column("tests", sa.Column("review_events_upto", sa.Integer()))
    op.create_index("ix_tests_review_state", "tests", ["review_state"])


def downgrade() -> None:
    op.drop_index("ix_tests_review_state", "tests")
    with op.batch_alter_table("tests", table_kwargs={"sqlite_autoincrement": True}) as batch:
        for name in ("review_events_upto", "record_sha256", "review_note", "reviewed_at", "reviewed_by",
                     "review_state"):
            batch.drop_column(name)
