"""The fleet's latest figures read from indexes alone: a machine type's latest measurements
and their axes' figures

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-28 23:00:00.000000

``store check`` and the lists' statuses read every latest figure of a type; with
these two indexes neither the machines' nor the axis results' table rows are read.
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_index("ix_machines_type_latest", "machines", ["type_id", "latest_measurement_id"])
    op.create_index(
        "ix_axis_results_figures",
        "axis_results",
        ["measurement_id", "axis", "unit", "coulomb", "viscous_per_m_min", "spread_percent"],
    )


def downgrade() -> None:
    op.drop_index("ix_axis_results_figures", table_name="axis_results")
    op.drop_index("ix_machines_type_latest", table_name="machines")
