"""The methods' Mitsuba integrator plugins.

Each plugin is a class in a module of this package that declares its Mitsuba plugin
name (``plugin_name``) and registers itself with ``@register`` (renderers/registry.py).
The modules import Mitsuba, so importing this package imports none of them (the
method and policy registries, read without Mitsuba, import
``renderers.integrators.termination``): a render registers every plugin for the
current Mitsuba variant with :func:`register_plugins` when it starts. Adding an
integrator is adding a module; a method loads it by its plugin name.
"""

from __future__ import annotations

from renderers.registry import Registry, discover

#: Integrator classes by Mitsuba plugin name.
PLUGINS: Registry[type] = Registry("integrator plugins", lambda cls: cls.plugin_name)
register = PLUGINS.register


def register_plugins() -> None:
    """Import every module of this package and register every plugin class with
    Mitsuba for the current variant (idempotent; call it when a render starts)."""
    discover(__name__, __path__)
    from renderers.integrators import path

    for name, cls in PLUGINS.items():
        path.register(name, cls)
