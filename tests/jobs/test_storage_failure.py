"""Which storage failures the service answers 507 (full) or 503 (unavailable)
(jobs/record/storage.py), on the errors the drivers really raise; the services' own
fault tests (tests/service/test_storage_faults.py) drive them end to end."""

from __future__ import annotations

import errno
import sqlite3

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.exc import DBAPIError

from jobs.record.storage import StorageFull, describe, storage_failure


@pytest.mark.parametrize("code, kind", [(errno.ENOSPC, "full"), (errno.EDQUOT, "full"),
                                        (errno.EFBIG, "full"), (errno.EIO, "full"),
                                        (errno.ENOENT, None), (errno.EACCES, None)])
def test_os_errors_are_full_only_for_lack_of_room(code, kind):
    err = OSError(code, "what the OS said", "/data/run.exr")
    assert storage_failure(err) == kind
    assert describe(err) == (
        "storage full: the service could not write its data (/data/run.exr): what the OS said"
        if kind else f"{type(err).__name__}: what the OS said")
    assert storage_failure(StorageFull("read back 3 of 8 bytes")) == "full"


def test_a_locked_sqlite_database_is_unavailable_and_says_so(tmp_path):
    path = tmp_path / "jobs.db"
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("create table t (x int)")
    holder.execute("begin exclusive")
    engine = create_engine(f"sqlite:///{path}", connect_args={"timeout": 0})
    with pytest.raises(DBAPIError) as raised, engine.connect() as connection:
        connection.execute(text("insert into t values (1)"))
    holder.close()
    assert storage_failure(raised.value) == "unavailable"
    assert describe(raised.value) == "database unavailable: database is locked"


class _PostgresError(Exception):
    def __init__(self, sqlstate: str) -> None:
        super().__init__(f"server said {sqlstate}")
        self.sqlstate = sqlstate


@pytest.mark.parametrize("sqlstate, kind", [("53100", "full"), ("53200", "full"),
                                            ("55P03", "unavailable"), ("57014", "unavailable"),
                                            ("08006", "unavailable"), ("57P01", "unavailable"),
                                            ("23505", None), ("42P01", None)])
def test_postgresql_states_by_class(sqlstate, kind):
    err = DBAPIError("insert", {}, _PostgresError(sqlstate))
    assert storage_failure(err) == kind
    assert storage_failure(ValueError("not storage")) is None
