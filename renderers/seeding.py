"""Seeds derived from what a render *is*, so that every render is reproducible.

A render is identified by (scene fingerprint, method, method parameters, seed
index, frame); hashing them gives the 32-bit seed Mitsuba's sampler receives.
Two renders that differ in any part get independent sample streams; the same
parts always give the same image on the same device and library versions.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal values give equal text."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def digest(*parts: Any, length: int = 64) -> str:
    """Hex sha256 of the canonical JSON of ``parts`` (truncated to ``length``)."""
    return hashlib.sha256(canonical_json(list(parts)).encode()).hexdigest()[:length]


def derive_seed(*parts: Any) -> int:
    """A 32-bit sampler seed determined by ``parts`` (see module docstring)."""
    return int(digest(*parts)[:8], 16)
