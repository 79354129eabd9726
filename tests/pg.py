"""A fresh database on the PostgreSQL test server, for one test.

A test's database is a copy of one that ``open_store`` migrated to the newest schema
once per test session (``CREATE DATABASE ... TEMPLATE``): migrating each database
anew took 0.4-0.6 s of the test's time, copying the migrated one takes none of it (the
store finds the schema current). The tests of migrating itself ask for an empty
database (``migrated=False``).
"""

from __future__ import annotations

import atexit
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from tempfile import TemporaryDirectory

from sqlalchemy import Engine, create_engine, text
from sqlalchemy.engine import make_url

from tests.setup_services import postgres_server_url

#: The session's migrated database, once made (a name of its own: sessions may share
#: the server).
_template: list[str] = []


def _database_url(server: str, name: str) -> str:
    return make_url(server).set(database=name).render_as_string(hide_password=False)


def _drop(server: str, name: str) -> None:
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()


def _migrated_template(server: str, admin: Engine) -> str:
    """The name of the session's database migrated by ``open_store`` (made on first
    use, dropped when the session's process exits)."""
    if not _template:
        from jobs.record.config import Settings
        from jobs.record.db import open_store

        name = f"nirc_template_{uuid.uuid4().hex[:12]}"
        with admin.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
        atexit.register(_drop, server, name)
        with TemporaryDirectory() as folder:
            store = open_store(Settings(data_dir=Path(folder),
                                        database_url=_database_url(server, name)))
            store.close()       # a template must have no connection when it is copied
        _template.append(name)
    return _template[0]


@contextmanager
def postgres_database(migrated: bool = True) -> Iterator[str]:
    """Create a uniquely named database, yield its URL, drop it afterwards: a copy of
    the session's migrated database, or empty with ``migrated=False``."""
    server = postgres_server_url()
    name = f"nirc_test_{uuid.uuid4().hex[:12]}"
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    template = f' TEMPLATE "{_migrated_template(server, admin)}"' if migrated else ""
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"{template}'))
    try:
        yield _database_url(server, name)
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()
