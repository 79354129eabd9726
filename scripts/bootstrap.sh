#!/usr/bin/env bash
# Bootstrap everything `make demo` / `make test` need on a fresh machine:
#   1. a system libLLVM >= 16 for Dr.Jit (installs Debian's libllvm19 as root),
#   2. the virtual environment .venv with the project and its dev dependencies.
# Idempotent: a second run only re-installs when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.installed

if ! "$PYTHON" -m renderers.llvm >/dev/null 2>&1; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
        echo "bootstrap: installing Debian's libllvm19 (Dr.Jit needs libLLVM >= 16)"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq >/dev/null
        apt-get install -y -qq libllvm19 >/dev/null
    else
        "$PYTHON" -m renderers.llvm >/dev/null || true
        echo "bootstrap: Dr.Jit needs a system libLLVM >= 16. Install it first, e.g." >&2
        echo "    sudo apt-get install libllvm19        (Debian/Ubuntu)" >&2
        echo "or set DRJIT_LIBLLVM_PATH to a libLLVM >= 16, then run make again." >&2
        exit 1
    fi
fi

if [ ! -x "$VENV/bin/python" ]; then
    echo "bootstrap: creating $VENV"
    "$PYTHON" -m venv "$VENV"
fi
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ]; then
    echo "bootstrap: installing Python dependencies into $VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q -e ".[dev]"
    touch "$STAMP"
fi
