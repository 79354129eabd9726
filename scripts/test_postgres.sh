#!/usr/bin/env bash
# Start a throw-away PostgreSQL server on loopback for the test suite and print its
# SQLAlchemy URL. Installs Debian's postgresql when it is missing (as root with apt),
# like the bootstrap does for libLLVM. Idempotent: a running server is reused. When it
# starts one it says so on standard error ("test_postgres: started ..."), so that the
# caller can stop it when done:
#
#   NIRC_BENCH_TEST_PG_URL=$(bash scripts/test_postgres.sh)
#   bash scripts/test_postgres.sh stop
#
# NIRC_BENCH_TEST_PG_PORT (55432) and NIRC_BENCH_TEST_PG_DIR (/tmp/nirc-bench-pg-PORT)
# choose the port and the folder of its data.
set -euo pipefail

PORT="${NIRC_BENCH_TEST_PG_PORT:-55432}"
BASE="${NIRC_BENCH_TEST_PG_DIR:-/tmp/nirc-bench-pg-$PORT}"

bindir() { ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1; }

source "$(dirname "$0")/debian.sh"
ensure_debian_package '[ -n "$(bindir)" ]' postgresql "the PostgreSQL tests"
BIN="$(bindir)"

# initdb and postgres refuse to run as root: run them as an unprivileged user.
as_owner() {
    if [ "$(id -u)" = 0 ]; then
        id postgres >/dev/null 2>&1 || useradd --system --no-create-home postgres
        runuser -u postgres -- "$@"
    else
        "$@"
    fi
}

if [ "${1:-}" = stop ]; then
    if as_owner "$BIN/pg_ctl" -D "$BASE/data" status >/dev/null 2>&1; then
        as_owner "$BIN/pg_ctl" -D "$BASE/data" -m fast -w stop >/dev/null
        echo "test_postgres: stopped the server on port $PORT" >&2
    fi
    exit 0
fi

if ! as_owner "$BIN/pg_ctl" -D "$BASE/data" status >/dev/null 2>&1; then
    mkdir -p "$BASE"
    [ "$(id -u)" = 0 ] && chown postgres "$BASE"
    if [ ! -f "$BASE/data/PG_VERSION" ]; then
        as_owner "$BIN/initdb" -D "$BASE/data" --auth=trust -U postgres -E UTF8 >/dev/null
    fi
    as_owner "$BIN/pg_ctl" -D "$BASE/data" -l "$BASE/server.log" -w \
        -o "-p $PORT -k $BASE -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=200" \
        start >/dev/null
    echo "test_postgres: started a server on port $PORT (data in $BASE; stop it with:" \
         "bash scripts/test_postgres.sh stop)" >&2
fi
echo "postgresql+psycopg://postgres@127.0.0.1:$PORT/postgres"
