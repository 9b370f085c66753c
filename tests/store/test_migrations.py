"""The store's schema revisions: from an empty database and from every earlier revision
they build exactly the tables of :mod:`ncmeasure.store.schema`; a newer schema is refused."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import create_engine, text

from ncmeasure.errors import StoreError
from ncmeasure.store import open_store
from ncmeasure.store.database import HEAD_REVISION, _alembic_config, _parse, head_revision
from ncmeasure.store.schema import metadata


def _engine(url: str):  # type: ignore[no-untyped-def]
    return create_engine(_parse(url))


def _revisions() -> list[str]:
    script = ScriptDirectory.from_config(_alembic_config())
    return [rev.revision for rev in reversed(list(script.walk_revisions()))]


def test_empty_database_gets_the_whole_schema(store_url: str) -> None:
    with open_store(store_url, write=True):
        pass
    engine = _engine(store_url)
    with engine.connect() as connection:
        context = MigrationContext.configure(connection, opts={"compare_type": True})
        assert context.get_current_revision() == head_revision()
        assert compare_metadata(context, metadata) == []
    engine.dispose()


@pytest.mark.parametrize("start", _revisions())
def test_every_earlier_revision_upgrades_to_the_schema(store_url: str, start: str) -> None:
    engine = _engine(store_url)
    with engine.begin() as connection:
        command.upgrade(_alembic_config(connection), start)
    engine.dispose()
    with open_store(store_url, write=True):  # upgrades to head on opening
        pass
    engine = _engine(store_url)
    with engine.connect() as connection:
        context = MigrationContext.configure(connection, opts={"compare_type": True})
        assert context.get_current_revision() == head_revision()
        assert compare_metadata(context, metadata) == []
    engine.dispose()


def test_a_newer_schema_is_refused(store_url: str) -> None:
    with open_store(store_url, write=True):
        pass
    engine = _engine(store_url)
    with engine.begin() as connection:
        connection.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    engine.dispose()
    for write in (False, True):
        with (
            pytest.raises(StoreError, match="schema revision 9999 is newer than this ncmeasure"),
            open_store(store_url, write=write),
        ):
            pass


def test_a_foreign_database_is_not_taken_over(store_url: str) -> None:
    engine = _engine(store_url)
    with engine.begin() as connection:
        connection.execute(text("CREATE TABLE machines (serial TEXT)"))
    engine.dispose()
    with (
        pytest.raises(StoreError, match="not an ncmeasure store"),
        open_store(store_url, write=True),
    ):
        pass


def test_the_head_revision_named_in_the_code_is_alembics() -> None:
    assert head_revision() == HEAD_REVISION


def test_a_current_store_opens_without_alembic(store_url: str) -> None:
    with open_store(store_url, write=True):
        pass
    probe = (
        "import sys\n"
        "from ncmeasure.store import open_store\n"
        f"with open_store({store_url!r}) as store:\n"
        "    store.machine_page(limit=1)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'alembic'))\n"
    )
    src = Path(__file__).resolve().parents[2] / "src"
    done = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        env={"PYTHONPATH": str(src), "PATH": "/usr/bin:/bin"},
    )
    assert done.stdout.strip() == "[]"
