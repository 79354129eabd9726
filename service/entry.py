"""The ``nirc-bench`` entry point: load the CLI, or say in one line why it cannot load.

The CLI imports Dr.Jit, whose native extension needs system libraries (libatomic;
libLLVM is checked later, by renderers.backend, before Dr.Jit loads it). Without
them the import fails before the CLI's own error handling exists (Dr.Jit turns
the ImportError into a NameError), so it is caught here: one line and exit
status 2, not a traceback.
"""

from __future__ import annotations

import os
import sys


def native_library_error(err: BaseException) -> str | None:
    """The loader's message if ``err`` (or what it was raised while handling) is a
    shared library that could not be loaded, else None."""
    seen: BaseException | None = err
    while seen is not None:
        if isinstance(seen, ImportError) and "shared object file" in str(seen):
            return str(seen)
        seen = seen.__cause__ or seen.__context__
    return None


def main() -> None:
    try:
        from service.cli import main as cli_main
    except Exception as err:
        message = native_library_error(err)
        if message is None or os.environ.get("NIRC_BENCH_DEBUG"):
            raise
        print(f"nirc-bench: error: cannot load the renderer's native libraries ({message}); "
              "on Debian/Ubuntu: sudo apt-get install libatomic1 libllvm19, or run "
              "scripts/bootstrap.sh", file=sys.stderr)
        sys.exit(2)
    cli_main()
