"""The one exception type of the scene library.

Everything a user can get wrong when naming or loading a scene (an unknown
name, a missing or malformed XML file, a resolution out of range, a scene that
Mitsuba refuses) surfaces as :class:`SceneError` with a one-line message in the
user's terms, so the CLI and the service can show it as is.
"""

from __future__ import annotations


class SceneError(ValueError):
    """A scene cannot be found, parsed or loaded; the message says which and why."""


class SceneNotFinite(SceneError):
    """A loaded scene with a NaN or infinite transform, vertex or emitter parameter.

    ``reason`` says what, without the file's path or the ids it gives its objects,
    so a service can show it for a stored scene (jobs.protocol.scene_store)."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason
