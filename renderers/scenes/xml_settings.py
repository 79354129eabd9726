"""What a Mitsuba XML scene file sets that a run replaces: its film size, its
integrator (and the integrator's max_depth) and its sampler's samples per pixel.

A run renders at the spec's resolution, with its method's integrator and max_depth
and the spec's spp, whatever the file says; these are read so that the run can say
which of the file's settings it did not use. ``$name`` values take the file's
``<default>`` (unresolved ones are reported as written). Files brought in by a
top-level ``<include>`` are read too, where Mitsuba finds them (beside the including
file, then the working folder), as Mitsuba merges their elements into the scene; a
setting the including file makes itself is the one reported.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from renderers.scenes.fingerprint import resolve_referenced


def _resolved(text: str | None, defaults: dict[str, str]) -> str | None:
    """An attribute's text with every ``$name`` replaced by the file's ``<default>`` of
    that name, as Mitsuba's loader does (an unresolved one is kept as written)."""
    if text is None:
        return None
    return re.sub(r"\$(\w+)", lambda match: defaults.get(match[1], match[0]), text)


def _value(element: ET.Element | None, defaults: dict[str, str]) -> str | None:
    return None if element is None else _resolved(element.get("value"), defaults)


def _number(text: str | None) -> int | str | None:
    if text is None:
        return None
    try:
        return int(text)
    except ValueError:
        return text


def xml_settings(root: ET.Element, folder: Path | None = None,
                 seen: frozenset[Path] = frozenset()) -> dict[str, Any]:
    """The settings of the scene ``root`` (the parsed <scene>) a run replaces, those it
    has: ``film`` [width, height], ``integrator`` (type), ``max_depth``, ``spp``.
    ``folder``: where the file lies, to read its top-level includes (None: not read);
    ``seen``: the files already being read (an include cycle stops there)."""
    found = _own_settings(root)
    if folder is None:
        return found
    for include in root.findall("include"):
        path = resolve_referenced(include.get("filename", ""), folder)
        if path is None or path.resolve() in seen:
            continue        # missing: Mitsuba's load says so; a cycle: read once
        try:
            included = ET.fromstring(path.read_bytes())
        except (OSError, ET.ParseError):
            continue        # Mitsuba's load reports the file
        for key, value in xml_settings(included, path.parent,
                                       seen | {path.resolve()}).items():
            found.setdefault(key, value)
    return found


def _own_settings(root: ET.Element) -> dict[str, Any]:
    """The settings ``root`` makes itself (xml_settings)."""
    defaults = {d.get("name", ""): d.get("value", "") for d in root.findall("default")}
    found: dict[str, Any] = {}
    film = root.find("sensor/film")
    if film is not None:
        size = [_number(_value(film.find(f"integer[@name='{name}']"), defaults))
                for name in ("width", "height")]
        if any(v is not None for v in size):
            found["film"] = size
    integrator = root.find("integrator")
    if integrator is not None:
        found["integrator"] = _resolved(integrator.get("type"), defaults)
        depth = _number(_value(integrator.find("integer[@name='max_depth']"), defaults))
        if depth is not None:
            found["max_depth"] = depth
    spp = _number(_value(root.find("sensor/sampler/integer[@name='sample_count']"), defaults))
    if spp is not None:
        found["spp"] = spp
    return found
