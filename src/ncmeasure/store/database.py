"""Opening a store: the URL, the engine, the schema version, and errors in words.

A store is named by a URL: ``sqlite:///fleet.db`` (a file, nothing to install),
``postgresql://user@host/db`` (a shared server, through psycopg 3), or a plain
file path, which means SQLite. :func:`store_url` adds ``--store`` /
``NCMEASURE_STORE`` / the default. :func:`connect` brings the schema to the
newest Alembic revision this ncmeasure knows (creating the tables in an empty
database) and refuses a database of a newer schema. A store already at that
revision is recognised by one plain query of its ``alembic_version`` table:
Alembic itself is imported only when there is something to create or upgrade.

On SQLite every write transaction starts with ``BEGIN IMMEDIATE`` (a second
writer waits for the first instead of failing half-way) and the schema's DDL
is transactional, as on PostgreSQL, where concurrent first-time openings
queue on an advisory lock.
"""

from __future__ import annotations

import gc
import os
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, Engine, Select, create_engine, event, inspect, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, NoSuchModuleError, SQLAlchemyError

from ncmeasure.errors import ConfigError, StoreError

__all__ = [
    "HEAD_REVISION",
    "STORE_ENV",
    "connect",
    "default_store",
    "display_url",
    "plain_columns",
    "plain_rows",
    "store_url",
    "write_begin",
]

STORE_ENV = "NCMEASURE_STORE"
"""The environment variable that names the store when ``--store`` is not given."""

HEAD_REVISION = "0007"
"""The newest schema revision (the last file in ``migrations/versions``): a store at it is
opened without Alembic. A test holds it equal to Alembic's head."""

_MIGRATIONS = Path(__file__).parent / "migrations"
_PG_LOCK_KEY = 0x6E636D73  # "ncms": serialises schema upgrades of one PostgreSQL database
_WRITE = "ncmeasure_write"
_BUSY_TIMEOUT_S = 60.0


def default_store() -> Path:
    """The SQLite file used when neither ``--store`` nor ``NCMEASURE_STORE`` names a store:
    ``$XDG_DATA_HOME/ncmeasure/fleet.db`` (``~/.local/share/ncmeasure/fleet.db``)."""
    data = os.environ.get("XDG_DATA_HOME") or "~/.local/share"
    return Path(data).expanduser() / "ncmeasure" / "fleet.db"


def store_url(given: str | None) -> str:
    """The store's URL: ``given``, else ``$NCMEASURE_STORE``, else :func:`default_store`.

    A value without ``://`` is a path to an SQLite file.
    """
    value = given if given is not None else os.environ.get(STORE_ENV)
    if value is None or not value.strip():
        value = str(default_store())
    if "://" not in value:
        return "sqlite:///" + str(Path(value).expanduser().absolute())
    return value


def _parse(url: str) -> URL:
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise ConfigError(f"store {url!r}: not a database URL ({exc})") from exc
    backend = parsed.get_backend_name()
    if backend == "sqlite":
        if parsed.drivername != "sqlite":
            raise ConfigError(f"store {url!r}: use sqlite:///FILE (no driver name)")
        if not parsed.database or parsed.database == ":memory:":
            raise ConfigError(f"store {url!r}: name a file, sqlite:///fleet.db")
        return parsed
    if backend == "postgresql":
        if parsed.drivername not in ("postgresql", "postgresql+psycopg"):
            raise ConfigError(
                f"store {display_url(url)}: ncmeasure talks to PostgreSQL through psycopg 3; "
                "write postgresql://USER@HOST/DATABASE"
            )
        return parsed.set(drivername="postgresql+psycopg")
    raise ConfigError(
        f"store {display_url(url)}: {backend} is not a store ncmeasure knows; use "
        "sqlite:///FILE or postgresql://USER@HOST/DATABASE"
    )


def display_url(url: str) -> str:
    """The URL without its password, for messages."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except ArgumentError:
        return "(not a URL)"


def _sqlite_engine(parsed: URL, write: bool) -> Engine:
    path = Path(str(parsed.database))
    where = display_url(parsed.render_as_string(hide_password=False))
    if not path.exists():
        if not write:
            raise StoreError(f"store {where}: no such file (ncmeasure store add creates the store)")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"store {where}: cannot create its folder: {exc.strerror}") from exc
    elif path.is_dir():
        raise StoreError(f"store {where}: is a folder, not an SQLite file")
    elif write and not os.access(path, os.W_OK):
        raise StoreError(f"store {where}: the file is read-only; nothing was written")
    engine = create_engine(parsed, connect_args={"timeout": _BUSY_TIMEOUT_S})

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: sqlite3.Connection, _record: Any) -> None:
        dbapi_connection.isolation_level = None  # SQLAlchemy emits BEGIN itself (below)
        dbapi_connection.execute("PRAGMA foreign_keys = ON")

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Connection) -> None:
        write_tx = connection.get_execution_options().get(_WRITE, False)
        connection.exec_driver_sql("BEGIN IMMEDIATE" if write_tx else "BEGIN")

    return engine


def _engine(url: str, write: bool) -> Engine:
    parsed = _parse(url)
    if parsed.get_backend_name() == "sqlite":
        return _sqlite_engine(parsed, write)
    try:
        return create_engine(
            parsed, pool_pre_ping=True, connect_args={"connect_timeout": 10}, pool_size=2
        )
    except NoSuchModuleError as exc:  # pragma: no cover - psycopg is a dependency of the extra
        raise StoreError(f"store {display_url(url)}: {exc}") from exc


def _first_line(error: BaseException) -> str:
    original = getattr(error, "orig", None) or error
    lines = [line.strip() for line in str(original).splitlines() if line.strip()]
    return lines[0] if lines else type(original).__name__


def translate(error: SQLAlchemyError, url: str, doing: str) -> StoreError:
    """A database error as one line that says what failed where."""
    where = display_url(url)
    line = _first_line(error)
    low = line.lower()
    if "readonly" in low or "read-only" in low:
        return StoreError(f"store {where}: read-only, cannot {doing}; nothing was written")
    if "database or disk is full" in low or "no space left" in low:
        return StoreError(f"store {where}: disk full while trying to {doing}; nothing was written")
    if (isinstance(error, DBAPIError) and error.connection_invalidated) or (
        "connection" in low and ("refused" in low or "failed" in low or "timeout" in low)
    ):
        return StoreError(f"store {where}: cannot reach the database: {line}")
    if "file is not a database" in low:
        return StoreError(f"store {where}: not an SQLite database")
    return StoreError(f"store {where}: cannot {doing}: {line}")


def write_begin(engine: Engine) -> Any:
    """``engine.begin()`` for a write transaction (``BEGIN IMMEDIATE`` on SQLite)."""
    return engine.execution_options(**{_WRITE: True}).begin()


def _alembic_config(connection: Connection | None = None) -> Any:
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(_MIGRATIONS))
    if connection is not None:
        config.attributes["connection"] = connection
    return config


def head_revision() -> str:
    """The newest schema revision this ncmeasure knows."""
    from alembic.script import ScriptDirectory

    head = ScriptDirectory.from_config(_alembic_config()).get_current_head()
    assert head is not None, "the store has no migrations"
    return head


def _known_revisions() -> set[str]:
    from alembic.script import ScriptDirectory

    script = ScriptDirectory.from_config(_alembic_config())
    return {rev.revision for rev in script.walk_revisions()}


def _current(connection: Connection) -> str | None:
    from alembic.runtime.migration import MigrationContext

    return MigrationContext.configure(connection).get_current_revision()


def _stored_revision(connection: Connection) -> str | None:
    """The store's schema revision by a plain query (None: no ``alembic_version`` table, no
    row, or more than one row, which Alembic itself then reads)."""
    if not inspect(connection).has_table("alembic_version"):
        return None
    rows = connection.execute(text("SELECT version_num FROM alembic_version")).all()
    return str(rows[0][0]) if len(rows) == 1 else None


def _migrate(connection: Connection, url: str, write: bool) -> None:
    from alembic import command

    if connection.dialect.name == "postgresql":
        connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _PG_LOCK_KEY})
    current = _current(connection)
    head = head_revision()
    where = display_url(url)
    if current == head:
        return
    if current is not None and current not in _known_revisions():
        from ncmeasure._version import __version__

        raise StoreError(
            f"store {where}: schema revision {current} is newer than this ncmeasure "
            f"{__version__} knows (up to {head}); update ncmeasure to use this store"
        )
    if current is None:
        foreign = {"machines", "measurements"} & set(inspect(connection).get_table_names())
        if foreign:
            raise StoreError(
                f"store {where}: has tables {sorted(foreign)} but no ncmeasure schema version; "
                "not an ncmeasure store"
            )
        if not write:
            raise StoreError(f"store {where}: empty; ncmeasure store add fills it")
    command.upgrade(_alembic_config(connection), "head")


@contextmanager
def connect(url: str, *, write: bool) -> Iterator[Engine]:
    """An engine on the store at ``url``, its schema at the newest revision.

    Args:
        url: A store URL (:func:`store_url`).
        write: The caller writes: an SQLite file may be created, and a read-only
            one is refused before anything happens.

    Raises:
        ConfigError: Not a URL ncmeasure knows.
        StoreError: The database cannot be reached, opened or written, is not an
            ncmeasure store, or has a newer schema.
    """
    engine = _engine(url, write)
    try:
        try:
            with engine.connect() as connection:
                current = _stored_revision(connection)
            if current != HEAD_REVISION:  # create, upgrade or refuse, under a write lock
                with write_begin(engine) as connection:
                    _migrate(connection, url, write)
        except SQLAlchemyError as exc:
            raise translate(exc, url, "open the store") from exc
        yield engine
    finally:
        engine.dispose()


@contextmanager
def _collector_paused() -> Iterator[None]:
    """The cyclic garbage collector paused: tens of thousands of new tuples would start
    several full collections, each walking every object of the process (at 10,000
    machines, as long as the read itself). Tuples of numbers and strings make no cycle."""
    paused = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if paused:
            gc.enable()


def plain_rows(db: Connection, query: Select[Any]) -> list[tuple[Any, ...]]:
    """The rows of ``query`` as the database driver's tuples, without a row object each
    (the fleet's latest figures are many; their columns need no conversion), read with the
    garbage collector paused."""
    with _collector_paused():
        result = db.execute(query)
        try:
            return list(result.cursor.fetchall())
        finally:
            result.close()


def plain_columns(db: Connection, query: Select[Any]) -> list[tuple[Any, ...]]:
    """The columns of ``query``'s rows (:func:`plain_rows`), each a tuple; no row, no
    column."""
    with _collector_paused():
        rows = plain_rows(db, query)
        return list(zip(*rows, strict=True))
