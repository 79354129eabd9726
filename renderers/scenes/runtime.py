"""Access to the ``mitsuba`` module for the scene library, imported lazily.

Listing or describing the built-in scenes must work without libLLVM, so no
module here imports Mitsuba at import time; they call :func:`mitsuba` when
they build or load a scene.
"""

from __future__ import annotations

import sys
from typing import Any

from renderers.backend import init_backend


def mitsuba() -> Any:
    """The ``mitsuba`` module with a variant set, keeping the caller's choice.

    If the process already chose a variant (through ``init_backend``), keep
    it: calling ``init_backend()`` without one could switch a CPU run on a GPU
    machine over to CUDA behind the caller's back.
    """
    loaded = sys.modules.get("mitsuba")
    current = loaded.variant() if loaded is not None else None
    return init_backend(current)
