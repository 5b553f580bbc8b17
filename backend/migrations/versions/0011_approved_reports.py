"""The report of an approved record kept as rendered at the approval (its PDF and SHA-256), and the lab's
tolerances per protocol for the check against the specimen's design values.

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-29
"""

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # plain ADD COLUMN (no batch recreate, which would drop SQLite's AUTOINCREMENT of migration 0006)
    op.add_column("tests", sa.Column("report_sha256", sa.String(64)))
    op.create_table(
        "approved_reports",
        sa.Column("test_id", sa.Integer, sa.ForeignKey("tests.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("pdf", sa.LargeBinary(), nullable=False),
        sa.Column("sha256", sa.String(64), nullable=False),
        sa.Column("lab_name", sa.String(200), nullable=False),
        sa.Column("units", sa.String(8), nullable=False),
    )
    op.create_table(
        "acceptance_tolerances",
        sa.Column("protocol", sa.String(64), primary_key=True),
        sa.Column("k_eff_fraction", sa.Float(), nullable=False),
        sa.Column("edc_fraction", sa.Float(), nullable=False),
        sa.Column("xi_eff_fraction", sa.Float(), nullable=False),
        sa.Column("mean_fraction", sa.Float(), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True)),
        sa.Column("updated_by", sa.String(64)),
    )


def downgrade() -> None:
    op.drop_table("acceptance_tolerances")
    op.drop_table("approved_reports")
    with op.batch_alter_table("tests", table_kwargs={"sqlite_autoincrement": True}) as batch:
        batch.drop_column("report_sha256")
