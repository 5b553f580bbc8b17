"""Who and what: the specimen's id, the operator's name and notes on every test.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-24
"""

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("tests") as batch:
        batch.add_column(sa.Column("specimen_id", sa.String(64), nullable=False, server_default=""))
        batch.add_column(sa.Column("operator_name", sa.String(64), nullable=False, server_default=""))
        batch.add_column(sa.Column("notes", sa.Text(), nullable=False, server_default=""))


def downgrade() -> None:
    with op.batch_alter_table("tests") as batch:
        batch.drop_column("notes")
        batch.drop_column("operator_name")
        batch.drop_column("specimen_id")
