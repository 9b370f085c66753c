"""Alembic's entry point for the store's schema revisions.

ncmeasure runs the revisions itself (:func:`ncmeasure.store.database.connect`), on a
connection it has opened, inside its transaction; there is no alembic.ini.
"""

from __future__ import annotations

from alembic import context

from ncmeasure.store.schema import metadata

connection = context.config.attributes.get("connection")
if connection is None:  # pragma: no cover - only ncmeasure runs these revisions
    raise RuntimeError("the store's migrations run through ncmeasure.store, with a connection")

context.configure(
    connection=connection,
    target_metadata=metadata,
    render_as_batch=connection.dialect.name == "sqlite",  # ALTER TABLE on SQLite
    compare_type=True,
)
with context.begin_transaction():
    context.run_migrations()
