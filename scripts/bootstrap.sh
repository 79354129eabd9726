#!/usr/bin/env bash
# Bootstrap everything `make demo` / `make test` need on a fresh machine:
#   1. a system libLLVM >= 16 and libatomic for Dr.Jit (installs Debian's libllvm19,
#      libatomic1 as root),
#   2. the virtual environment .venv with the project and its dev dependencies.
# Idempotent: a second run only re-installs when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.installed

# Dr.Jit's native libraries: libLLVM >= 16 (checked by renderers.llvm) and libatomic.
missing=()
"$PYTHON" -m renderers.llvm >/dev/null 2>&1 || missing+=(libllvm19)
"$PYTHON" -c "import ctypes; ctypes.CDLL('libatomic.so.1')" 2>/dev/null || missing+=(libatomic1)
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
        echo "bootstrap: installing Debian's ${missing[*]} (Dr.Jit needs libLLVM >= 16 and libatomic)"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq >/dev/null
        apt-get install -y -qq "${missing[@]}" >/dev/null
    else
        "$PYTHON" -m renderers.llvm >/dev/null || true
        echo "bootstrap: Dr.Jit needs a system libLLVM >= 16 and libatomic. Install them, e.g." >&2
        echo "    sudo apt-get install ${missing[*]}        (Debian/Ubuntu)" >&2
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
