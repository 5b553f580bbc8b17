"""Tests that ran are archived (who, when, why), never erased through the API.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-24
"""

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("tests") as batch:
        batch.add_column(sa.Column("archived_at", sa.DateTime(timezone=True), nullable=True))
        batch.add_column(sa.Column("archived_by", sa.String(64), nullable=True))
        batch.add_column(sa.Column("archive_reason", sa.Text(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("tests") as batch:
        batch.drop_column("archive_reason")
        batch.drop_column("archived_by")
        batch.drop_column("archived_at")
