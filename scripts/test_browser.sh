#!/usr/bin/env bash
# Print the path of a Chromium for the dashboard's browser tests, installing Debian's
# `chromium` when it is missing (as root with apt), like the bootstrap does for libLLVM.
#   NIRC_BENCH_TEST_CHROMIUM=$(bash scripts/test_browser.sh)
set -euo pipefail
source "$(dirname "$0")/debian.sh"
ensure_debian_package "command -v chromium >/dev/null" chromium "the dashboard tests"
command -v chromium
