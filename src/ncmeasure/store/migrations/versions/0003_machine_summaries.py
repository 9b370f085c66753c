"""A summary row per machine: what the lists show, read a page at a time

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-28 17:00:00.000000

Filled here from the measurements; kept current as measurements are added, and
rebuilt by ``ncmeasure store refresh``. The status column starts empty (it is
judged against the whole fleet: ``store refresh`` or the first fleet overview of
a store open for writing fills it).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_FILL = """
INSERT INTO machine_summaries (machine_id, serial, machine_type, config_hash, site,
    measurements, latest_id, latest_utc, latest_label, baseline_id, baseline_utc,
    baseline_label)
SELECT m.id, m.serial, t.name, t.config_hash, m.site,
    (SELECT COUNT(*) FROM measurements x WHERE x.machine_id = m.id),
    m.latest_measurement_id, l.measured_utc, l.label, b.id, b.measured_utc, b.label
FROM machines m
JOIN machine_types t ON t.id = m.type_id
LEFT JOIN measurements l ON l.id = m.latest_measurement_id
LEFT JOIN measurements b ON b.id = (
    SELECT x.id FROM measurements x WHERE x.machine_id = m.id
    ORDER BY CASE WHEN x.label = 'delivery' THEN 0 ELSE 1 END, x.measured_utc, x.id
    LIMIT 1)
"""


def upgrade() -> None:
    op.create_table(
        "machine_summaries",
        sa.Column("machine_id", sa.Integer(), nullable=False),
        sa.Column("serial", sa.String(length=64), nullable=False),
        sa.Column("machine_type", sa.String(length=200), nullable=False),
        sa.Column("config_hash", sa.String(length=64), nullable=False),
        sa.Column("site", sa.String(length=200), nullable=True),
        sa.Column("measurements", sa.Integer(), nullable=False),
        sa.Column("latest_id", sa.Integer(), nullable=True),
        sa.Column("latest_utc", sa.String(length=32), nullable=True),
        sa.Column("latest_label", sa.String(length=64), nullable=True),
        sa.Column("baseline_id", sa.Integer(), nullable=True),
        sa.Column("baseline_utc", sa.String(length=32), nullable=True),
        sa.Column("baseline_label", sa.String(length=64), nullable=True),
        sa.Column("status", sa.String(length=16), nullable=True),
        sa.Column("fleet_version", sa.String(length=64), nullable=True),
        sa.ForeignKeyConstraint(
            ["machine_id"],
            ["machines.id"],
            name=op.f("fk_machine_summaries_machine_id_machines"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("machine_id", name=op.f("pk_machine_summaries")),
        sa.UniqueConstraint("serial", name=op.f("uq_machine_summaries_serial")),
    )
    with op.batch_alter_table("machine_summaries", schema=None) as batch_op:
        batch_op.create_index(
            "ix_machine_summaries_status_serial", ["status", "serial"], unique=False
        )
        batch_op.create_index(
            "ix_machine_summaries_type_serial", ["machine_type", "serial"], unique=False
        )
    op.execute(_FILL)


def downgrade() -> None:
    with op.batch_alter_table("machine_summaries", schema=None) as batch_op:
        batch_op.drop_index("ix_machine_summaries_type_serial")
        batch_op.drop_index("ix_machine_summaries_status_serial")
    op.drop_table("machine_summaries")
