#!/usr/bin/env bash
# Print the path of a Chromium for the dashboard's browser tests, installing Debian's
# `chromium` when it is missing (as root with apt), like the bootstrap does for libLLVM.
#   NIRC_BENCH_TEST_CHROMIUM=$(bash scripts/test_browser.sh)
set -euo pipefail
if ! command -v chromium >/dev/null; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "installing chromium (Debian) for the dashboard tests..." >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >&2 \
            || { apt-get update -q >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >&2; }
    else
        echo "Chromium is not installed: sudo apt-get install chromium" >&2
        exit 1
    fi
fi
command -v chromium
