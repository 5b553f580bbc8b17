"""The vertical load of a test; room for a rig's URL in tests.driver.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-24
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("tests") as batch:
        batch.add_column(sa.Column("vertical_load_n", sa.Float(), nullable=True))
        batch.alter_column("driver", existing_type=sa.String(32), type_=sa.String(200), existing_nullable=False)


def downgrade() -> None:
    with op.batch_alter_table("tests") as batch:
        batch.alter_column("driver", existing_type=sa.String(200), type_=sa.String(32), existing_nullable=False)
        batch.drop_column("vertical_load_n")
