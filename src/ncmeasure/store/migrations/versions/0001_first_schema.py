"""The first schema: machine types, machines, axes, measurements, results

Revision ID: 0001
Revises: (none: from an empty database)
Create Date: 2026-11-25 15:03:06.123097
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


# One function, as long as the schema: a migration is a frozen record of the schema at
# its revision, applied once and never edited, so it stays whole rather than split.
def upgrade() -> None:
    op.create_table(
        "machine_types",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("config_hash", sa.String(length=64), nullable=False),
        sa.Column("created_utc", sa.String(length=32), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_machine_types")),
        sa.UniqueConstraint("name", "config_hash", name=op.f("uq_machine_types_name")),
    )
    op.create_table(
        "machines",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("serial", sa.String(length=64), nullable=False),
        sa.Column("type_id", sa.Integer(), nullable=False),
        sa.Column("site", sa.String(length=200), nullable=True),
        sa.Column("created_utc", sa.String(length=32), nullable=False),
        sa.Column("latest_measurement_id", sa.Integer(), nullable=True),
        sa.ForeignKeyConstraint(
            ["type_id"], ["machine_types.id"], name=op.f("fk_machines_type_id_machine_types")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_machines")),
        sa.UniqueConstraint("serial", name=op.f("uq_machines_serial")),
    )
    with op.batch_alter_table("machines", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_machines_type_id"), ["type_id"], unique=False)

    op.create_table(
        "axes",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=32), nullable=False),
        sa.ForeignKeyConstraint(
            ["machine_id"],
            ["machines.id"],
            name=op.f("fk_axes_machine_id_machines"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_axes")),
        sa.UniqueConstraint("machine_id", "name", name=op.f("uq_axes_machine_id")),
    )
    op.create_table(
        "measurements",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("machine_id", sa.Integer(), nullable=False),
        sa.Column("type_id", sa.Integer(), nullable=False),
        sa.Column("measured_utc", sa.String(length=32), nullable=False),
        sa.Column("added_utc", sa.String(length=32), nullable=False),
        sa.Column("label", sa.String(length=64), nullable=True),
        sa.Column("operator", sa.String(length=200), nullable=True),
        sa.Column("temperature_c", sa.Float(), nullable=True),
        sa.Column("operating_hours", sa.Float(), nullable=True),
        sa.Column("link", sa.String(length=64), nullable=True),
        sa.Column("config_hash", sa.String(length=64), nullable=False),
        sa.Column("ncmeasure_version", sa.String(length=32), nullable=False),
        sa.Column("results_format_version", sa.Integer(), nullable=False),
        sa.Column("recording_location", sa.Text(), nullable=True),
        sa.Column("results_sha256", sa.String(length=64), nullable=False),
        sa.Column("results_json", sa.LargeBinary(), nullable=False),
        sa.ForeignKeyConstraint(
            ["machine_id"],
            ["machines.id"],
            name=op.f("fk_measurements_machine_id_machines"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["type_id"], ["machine_types.id"], name=op.f("fk_measurements_type_id_machine_types")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_measurements")),
        sa.UniqueConstraint("results_sha256", name=op.f("uq_measurements_results_sha256")),
    )
    with op.batch_alter_table("measurements", schema=None) as batch_op:
        batch_op.create_index(
            "ix_measurements_machine_time", ["machine_id", "measured_utc"], unique=False
        )

    op.create_table(
        "axis_results",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("measurement_id", sa.Integer(), nullable=False),
        sa.Column("axis_id", sa.Integer(), nullable=False),
        sa.Column("axis", sa.String(length=32), nullable=False),
        sa.Column("verdict", sa.String(length=16), nullable=False),
        sa.Column("verdict_reason", sa.Text(), nullable=False),
        sa.Column("verdict_action", sa.Text(), nullable=False),
        sa.Column("quantity", sa.String(length=16), nullable=False),
        sa.Column("unit", sa.String(length=8), nullable=False),
        sa.Column("windows", sa.Integer(), nullable=False),
        sa.Column("samples_used", sa.Integer(), nullable=False),
        sa.Column("coulomb", sa.Float(), nullable=True),
        sa.Column("coulomb_positive", sa.Float(), nullable=True),
        sa.Column("coulomb_negative", sa.Float(), nullable=True),
        sa.Column("viscous_per_m_min", sa.Float(), nullable=True),
        sa.Column("spread_percent", sa.Float(), nullable=True),
        sa.Column("signature", sa.String(length=32), nullable=True),
        sa.Column("offset", sa.Float(), nullable=True),
        sa.Column("offset_stderr", sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(
            ["axis_id"], ["axes.id"], name=op.f("fk_axis_results_axis_id_axes"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["measurement_id"],
            ["measurements.id"],
            name=op.f("fk_axis_results_measurement_id_measurements"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_axis_results")),
        sa.UniqueConstraint("measurement_id", "axis", name=op.f("uq_axis_results_measurement_id")),
    )
    with op.batch_alter_table("axis_results", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_axis_results_axis_id"), ["axis_id"], unique=False)
        batch_op.create_index(
            batch_op.f("ix_axis_results_measurement_id"), ["measurement_id"], unique=False
        )

    op.create_table(
        "causes",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("axis_result_id", sa.Integer(), nullable=False),
        sa.Column("rank", sa.Integer(), nullable=False),
        sa.Column("cause", sa.String(length=32), nullable=False),
        sa.Column("score", sa.Float(), nullable=False),
        sa.Column("evidence", sa.Text(), nullable=False),
        sa.ForeignKeyConstraint(
            ["axis_result_id"],
            ["axis_results.id"],
            name=op.f("fk_causes_axis_result_id_axis_results"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_causes")),
    )
    with op.batch_alter_table("causes", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_causes_axis_result_id"), ["axis_result_id"], unique=False
        )

    op.create_table(
        "fits",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("axis_result_id", sa.Integer(), nullable=False),
        sa.Column("position_index", sa.Integer(), nullable=False),
        sa.Column("position_mm", sa.Float(), nullable=False),
        sa.Column("direction", sa.String(length=8), nullable=False),
        sa.Column("model", sa.String(length=16), nullable=False),
        sa.Column("chosen", sa.Boolean(), nullable=False),
        sa.Column("accepted", sa.Boolean(), nullable=False),
        sa.Column("chi2_reduced", sa.Float(), nullable=True),
        sa.Column("reason", sa.Text(), nullable=True),
        sa.ForeignKeyConstraint(
            ["axis_result_id"],
            ["axis_results.id"],
            name=op.f("fk_fits_axis_result_id_axis_results"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_fits")),
    )
    with op.batch_alter_table("fits", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_fits_axis_result_id"), ["axis_result_id"], unique=False
        )

    op.create_table(
        "points",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("axis_result_id", sa.Integer(), nullable=False),
        sa.Column("position_index", sa.Integer(), nullable=False),
        sa.Column("position_mm", sa.Float(), nullable=False),
        sa.Column("direction", sa.String(length=8), nullable=False),
        sa.Column("velocity_mm_min", sa.Float(), nullable=False),
        sa.Column("median", sa.Float(), nullable=False),
        sa.Column("stderr", sa.Float(), nullable=True),
        sa.Column("mean", sa.Float(), nullable=False),
        sa.Column("std", sa.Float(), nullable=False),
        sa.Column("n", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["axis_result_id"],
            ["axis_results.id"],
            name=op.f("fk_points_axis_result_id_axis_results"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_points")),
    )
    with op.batch_alter_table("points", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_points_axis_result_id"), ["axis_result_id"], unique=False
        )

    op.create_table(
        "fit_parameters",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("fit_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=32), nullable=False),
        sa.Column("value", sa.Float(), nullable=True),
        sa.Column("stderr", sa.Float(), nullable=True),
        sa.Column("ci95_low", sa.Float(), nullable=True),
        sa.Column("ci95_high", sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(
            ["fit_id"], ["fits.id"], name=op.f("fk_fit_parameters_fit_id_fits"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_fit_parameters")),
    )
    with op.batch_alter_table("fit_parameters", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_fit_parameters_fit_id"), ["fit_id"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("fit_parameters", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_fit_parameters_fit_id"))

    op.drop_table("fit_parameters")
    with op.batch_alter_table("points", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_points_axis_result_id"))

    op.drop_table("points")
    with op.batch_alter_table("fits", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_fits_axis_result_id"))

    op.drop_table("fits")
    with op.batch_alter_table("causes", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_causes_axis_result_id"))

    op.drop_table("causes")
    with op.batch_alter_table("axis_results", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_axis_results_measurement_id"))
        batch_op.drop_index(batch_op.f("ix_axis_results_axis_id"))

    op.drop_table("axis_results")
    with op.batch_alter_table("measurements", schema=None) as batch_op:
        batch_op.drop_index("ix_measurements_machine_time")

    op.drop_table("measurements")
    op.drop_table("axes")
    with op.batch_alter_table("machines", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_machines_type_id"))

    op.drop_table("machines")
    op.drop_table("machine_types")
