"""The change since the baseline, stored per (latest, baseline) pair and axis

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-28 10:00:00.000000

The tables start empty: a store filled before them gets its rows as measurements
are added, or all at once with ``ncmeasure store refresh``; until then the fleet
overview compares a machine's pair when it reads it (ncmeasure.store.changes).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "baseline_changes",
        sa.Column("measurement_id", sa.Integer(), nullable=False),
        sa.Column("baseline_id", sa.Integer(), nullable=False),
        sa.Column("outcome", sa.String(length=16), nullable=False),
        sa.Column("diagnosis_version", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["baseline_id"],
            ["measurements.id"],
            name=op.f("fk_baseline_changes_baseline_id_measurements"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["measurement_id"],
            ["measurements.id"],
            name=op.f("fk_baseline_changes_measurement_id_measurements"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("measurement_id", "baseline_id", name=op.f("pk_baseline_changes")),
    )
    with op.batch_alter_table("baseline_changes", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_baseline_changes_baseline_id"), ["baseline_id"], unique=False
        )

    op.create_table(
        "axis_changes",
        sa.Column("measurement_id", sa.Integer(), nullable=False),
        sa.Column("baseline_id", sa.Integer(), nullable=False),
        sa.Column("axis", sa.String(length=32), nullable=False),
        sa.Column("signature", sa.String(length=32), nullable=False),
        sa.Column("cause", sa.String(length=32), nullable=False),
        sa.Column("spread_percent", sa.Float(), nullable=True),
        sa.Column("mean_percent", sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(
            ["measurement_id", "baseline_id"],
            ["baseline_changes.measurement_id", "baseline_changes.baseline_id"],
            name=op.f("fk_axis_changes_measurement_id_baseline_changes"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint(
            "measurement_id", "baseline_id", "axis", name=op.f("pk_axis_changes")
        ),
    )


def downgrade() -> None:
    op.drop_table("axis_changes")
    with op.batch_alter_table("baseline_changes", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_baseline_changes_baseline_id"))

    op.drop_table("baseline_changes")
