"""How methods, termination policies and integrator plugins are registered: one way.

Each kind has a :class:`Registry` (a dict from name to what is registered) in its
package's ``__init__``. A plugin registers itself in its own module, with the
registry's :meth:`Registry.register` (a class decorator, or called on an instance:
``METHOD = register(Method(...))``), and the package imports its modules by
:func:`discover`, so adding one is adding one file. Entries keep the order in which
their modules registered them (discovery imports modules sorted by name; a module
that imports another registers after it). Discovery imports nothing else, so a
registry that must be readable without Mitsuba (methods, policies) stays so as long
as its modules import Mitsuba only where they evaluate.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Iterable
from typing import TypeVar

T = TypeVar("T")


class Registry(dict[str, T]):
    """Plugins of one kind by name; ``name_of`` reads the name an entry declares."""

    def __init__(self, kind: str, name_of: Callable[[T], str]) -> None:
        super().__init__()
        self.kind = kind
        self.name_of = name_of

    def register(self, entry: T) -> T:
        """Add ``entry`` under its declared name and return it (usable as a decorator);
        a second, different entry of the same name is refused."""
        name = self.name_of(entry)
        if name in self and self[name] is not entry:
            raise ValueError(f"two {self.kind} are named {name!r}")
        self[name] = entry
        return entry


def discover(package: str, path: Iterable[str], skip: Iterable[str] = ()) -> None:
    """Import every module of ``package`` (its ``__path__``), sorted by name, but those
    whose name starts with an underscore and those named in ``skip`` (helpers that
    register nothing and must not be imported with the registry): each registers its
    plugins as it is imported."""
    skipped = set(skip)
    for module in sorted(pkgutil.iter_modules(path), key=lambda info: info.name):
        if not module.name.startswith("_") and module.name not in skipped:
            importlib.import_module(f"{package}.{module.name}")
