"""The machines' search text: serial, type and site case-folded as Python folds them

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-29 04:30:00.000000

A search of the lists (``store list --search``, the REST API's machine list) finds
``WÜRZBURG`` for ``würzburg`` on SQLite and on PostgreSQL of any locale, as the
dashboard's grid does; before, SQLite's ``LIKE`` and a C-locale PostgreSQL's
``ILIKE`` folded ASCII letters only. The column is filled here for every machine.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_APART = "\x1f"  # ncmeasure.store.summaries.SEARCH_APART, as it was at this revision


def upgrade() -> None:
    with op.batch_alter_table("machine_summaries", schema=None) as batch_op:
        batch_op.add_column(sa.Column("search_text", sa.Text(), server_default="", nullable=False))
    summaries = sa.table(
        "machine_summaries",
        sa.column("machine_id", sa.Integer),
        sa.column("serial", sa.String),
        sa.column("machine_type", sa.String),
        sa.column("site", sa.String),
        sa.column("search_text", sa.Text),
    )
    db = op.get_bind()
    rows = db.execute(
        sa.select(summaries.c.machine_id, summaries.c.serial, summaries.c.machine_type,
                  summaries.c.site)
    ).all()  # fmt: skip
    texts = [
        {
            "id": r[0],
            "text": _APART.join((r[1].casefold(), r[2].casefold(), (r[3] or "").casefold())),
        }
        for r in rows
    ]
    if texts:
        db.execute(
            summaries.update()
            .where(summaries.c.machine_id == sa.bindparam("id"))
            .values(search_text=sa.bindparam("text")),
            texts,
        )


def downgrade() -> None:
    with op.batch_alter_table("machine_summaries", schema=None) as batch_op:
        batch_op.drop_column("search_text")
