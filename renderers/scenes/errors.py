"""The one exception type of the scene library.

Everything a user can get wrong when naming or loading a scene (an unknown
name, a missing or malformed XML file, a resolution out of range, a scene that
Mitsuba refuses) surfaces as :class:`SceneError` with a one-line message in the
user's terms, so the CLI and the service can show it as is.
"""

from __future__ import annotations


class SceneError(ValueError):
    """A scene cannot be found, parsed or loaded; the message says which and why."""
