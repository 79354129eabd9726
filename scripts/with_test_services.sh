#!/usr/bin/env bash
# Run a command (the test suite) with the services its tests need, then stop what this
# script started:
#   - a throw-away PostgreSQL server on loopback (scripts/test_postgres.sh; Debian's
#     postgresql is installed first when missing), stopped at the end if it was not
#     running before;
#   - a headless Chromium for the dashboard tests (scripts/test_browser.sh; Debian's
#     chromium is installed when missing).
#   bash scripts/with_test_services.sh .venv/bin/python -m pytest -q
set -euo pipefail
here="$(dirname "$0")"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
NIRC_BENCH_TEST_PG_URL="$(bash "$here/test_postgres.sh" 2>"$log")" || { cat "$log" >&2; exit 1; }
cat "$log" >&2
if grep -q "test_postgres: started" "$log"; then
    trap 'bash "$here/test_postgres.sh" stop; rm -f "$log"' EXIT
fi
NIRC_BENCH_TEST_CHROMIUM="$(bash "$here/test_browser.sh")"
export NIRC_BENCH_TEST_PG_URL NIRC_BENCH_TEST_CHROMIUM
"$@"
