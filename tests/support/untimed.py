"""Frame hooks for the renders of tests that read no frame time.

Without kernel frames (``kernel_every=0``) the frame loop's warm-up settles the frozen
calls under one kernel-history state instead of two (renderers.timing.history_states):
about a quarter less CPU for a small render, and more where every warm-up call renders
many samples. The history changes no value: every method's fingerprint image
(tests/renderers/test_fingerprints.py) is bit-equal under these hooks and the default
ones.
"""

from __future__ import annotations

from renderers.methods.base import FrameHooks

UNTIMED = FrameHooks(kernel_every=0)
