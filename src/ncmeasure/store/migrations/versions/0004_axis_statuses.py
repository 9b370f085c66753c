"""Per machine and axis, its status without the fleet: the lists judge only the fleet

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-28 20:00:00.000000

Empty at first: the statuses are judged where missing by the first reader (kept by
a store open for writing; ``ncmeasure store refresh`` judges every machine).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "axis_statuses",
        sa.Column("machine_id", sa.Integer(), nullable=False),
        sa.Column("axis", sa.String(length=32), nullable=False),
        sa.Column("latest_id", sa.Integer(), nullable=False),
        sa.Column("baseline_id", sa.Integer(), nullable=False),
        sa.Column("diagnosis_version", sa.Integer(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.ForeignKeyConstraint(
            ["machine_id"],
            ["machines.id"],
            name=op.f("fk_axis_statuses_machine_id_machines"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("machine_id", "axis", name=op.f("pk_axis_statuses")),
    )


def downgrade() -> None:
    op.drop_table("axis_statuses")
