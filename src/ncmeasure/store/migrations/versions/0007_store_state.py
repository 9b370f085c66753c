"""The store's revision, counted as adding transactions commit

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-29 04:40:00.000000

The version a reader caches by (the dashboard, the statuses' fleet version) was the
highest measurement id. On PostgreSQL two stations adding at once may commit in the
other order than they took their ids: the one holding the lower id commits last, the
highest id does not move, and a running dashboard kept the page without its machine.
The revision starts at the highest measurement id, so statuses kept before stay current.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    state = op.create_table(
        "store_state",
        sa.Column("id", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("revision", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_store_state")),
    )
    measurements = sa.table("measurements", sa.column("id", sa.Integer))
    highest = op.get_bind().execute(sa.select(sa.func.max(measurements.c.id))).scalar_one()
    op.bulk_insert(state, [{"id": 1, "revision": int(highest or 0)}])


def downgrade() -> None:
    op.drop_table("store_state")
