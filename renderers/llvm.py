"""Find a system libLLVM that Dr.Jit's LLVM backend can use (major version >= 16).

Dr.Jit loads libLLVM at run time. With LLVM 15 the process *aborts* inside code
generation ("Cannot select: fminimum"), which no Python ``try`` can catch, so
we look for a usable library before Mitsuba is imported and point Dr.Jit at it
with ``DRJIT_LIBLLVM_PATH``.

This module uses only the standard library: the bootstrap (``make``) runs it
with the system Python before the virtual environment exists::

    python3 -m renderers.llvm          # prints the path, exit 1 if none
"""

from __future__ import annotations

import glob
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

MIN_LLVM_MAJOR = 16

#: Where Debian/Ubuntu/Fedora/Homebrew put libLLVM. ``NIRC_BENCH_LLVM_SEARCH``
#: (os.pathsep-separated directories) replaces this list, e.g. in tests.
DEFAULT_SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/usr/lib/llvm-*/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
)

INSTALL_HINT = (
    "install Debian's 'libllvm19' (apt-get install libllvm19) or another libLLVM >= "
    f"{MIN_LLVM_MAJOR}, or set DRJIT_LIBLLVM_PATH to such a library"
)

# libLLVM-19.so, libLLVM-19.so.1, libLLVM.so.19.1, libLLVM-16.0.6.so, libLLVM.19.dylib
_VERSION_PATTERNS = (
    re.compile(r"libLLVM-(\d+)(?:\.\d+)*\.so"),
    re.compile(r"libLLVM\.so\.(\d+)"),
    re.compile(r"libLLVM\.(\d+)(?:\.\d+)*\.dylib"),
    re.compile(r"/llvm-(\d+)/lib/libLLVM\.(?:so|dylib)$"),
)


class LLVMNotFoundError(RuntimeError):
    """No libLLVM >= 16 is available; the message says what to install."""


@dataclass(frozen=True)
class LibLLVM:
    path: str
    major: int


def llvm_major(path: str) -> int | None:
    """Major LLVM version encoded in a library file name, or None if unknown."""
    for pattern in _VERSION_PATTERNS:
        match = pattern.search(path)
        if match:
            return int(match.group(1))
    return None


def _search_dirs() -> list[str]:
    override = os.environ.get("NIRC_BENCH_LLVM_SEARCH")
    patterns = override.split(os.pathsep) if override is not None else DEFAULT_SEARCH_DIRS
    dirs: list[str] = []
    for pattern in patterns:
        dirs.extend(sorted(glob.glob(pattern)) if pattern else [])
    return dirs


def candidates() -> list[LibLLVM]:
    """Every libLLVM with a recognisable version in the search directories."""
    found: dict[str, LibLLVM] = {}
    for directory in _search_dirs():
        for name in glob.glob(os.path.join(directory, "libLLVM*")):
            major = llvm_major(name)
            if major is not None and os.path.isfile(name):
                found.setdefault(os.path.realpath(name), LibLLVM(name, major))
    return sorted(found.values(), key=lambda lib: (-lib.major, len(lib.path)))


def find_libllvm() -> LibLLVM:
    """Return the newest usable libLLVM, honouring an explicit DRJIT_LIBLLVM_PATH.

    Raises LLVMNotFoundError with an actionable message when there is none.
    """
    explicit = os.environ.get("DRJIT_LIBLLVM_PATH")
    if explicit:
        if not Path(explicit).is_file():
            raise LLVMNotFoundError(
                f"DRJIT_LIBLLVM_PATH={explicit} does not exist; {INSTALL_HINT}"
            )
        major = llvm_major(os.path.realpath(explicit)) or llvm_major(explicit)
        if major is not None and major < MIN_LLVM_MAJOR:
            raise LLVMNotFoundError(
                f"DRJIT_LIBLLVM_PATH={explicit} is LLVM {major}, but Dr.Jit needs "
                f">= {MIN_LLVM_MAJOR} (LLVM {major} aborts the process); {INSTALL_HINT}"
            )
        return LibLLVM(explicit, major or 0)

    found = candidates()
    usable = [lib for lib in found if lib.major >= MIN_LLVM_MAJOR]
    if usable:
        return usable[0]
    seen = ", ".join(f"LLVM {lib.major}" for lib in found) or "none"
    raise LLVMNotFoundError(
        f"no libLLVM >= {MIN_LLVM_MAJOR} found (found: {seen}); {INSTALL_HINT}"
    )


def main() -> int:
    try:
        lib = find_libllvm()
    except LLVMNotFoundError as err:
        print(f"nirc-bench: {err}", file=sys.stderr)
        return 1
    print(lib.path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
