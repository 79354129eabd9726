"""Scene fingerprints: a short hash of a scene's *content*, not of its film size.

References and results are keyed by fingerprint, so it must be

* stable: the same scene gives the same fingerprint in every process (no
  ``id()``s, no float noise below float32 precision);
* sensitive: any change to geometry, materials, lights, camera or to a file
  the scene reads changes it;
* resolution-free: the film's width and height are left out, because the
  resolution is a separate key of every reference and result.

Built-in scenes hash a canonical JSON of their ``mi.load_dict`` dictionary
(transforms as rounded matrices, bitmaps and arrays by content hash) together
with the library version. XML scenes hash their canonical XML (comments and
formatting dropped, film width/height removed, ``$`` defaults substituted) with
every file they reference replaced by its content hash, so that renaming the files
(as a service does when it stages an upload) keeps the fingerprint.
"""

from __future__ import annotations

import hashlib
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from renderers.scenes.runtime import mitsuba

#: Hex digits kept: 64 bits make accidental collisions between the scenes of
#: one installation practically impossible while keeping keys readable.
FINGERPRINT_LENGTH = 16

#: Significant digits kept of floats that come out of float32 arithmetic
#: (transform matrices): enough to tell any two real scenes apart, few enough
#: to ignore last-bit differences between builds.
_FLOAT_DIGITS = 7

_FILM_SIZE_NAMES = ("width", "height")
_PARAMETER = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def _digest(payload: bytes) -> str:
    return hashlib.sha256(payload).hexdigest()[:FINGERPRINT_LENGTH]


def _round(x: float) -> float:
    # `+ 0.0` folds -0.0 into 0.0 so both print the same.
    return float(f"{x:.{_FLOAT_DIGITS}g}") + 0.0


def _array_summary(kind: str, array: np.ndarray, **extra: Any) -> dict[str, Any]:
    """Large numeric content is represented by its hash, shape and dtype."""
    data = np.ascontiguousarray(array)
    return {
        kind: hashlib.sha256(data.tobytes()).hexdigest(),
        "shape": list(data.shape),
        "dtype": str(data.dtype),
        **extra,
    }


def canonical(value: Any) -> Any:
    """A JSON-ready, deterministic representation of a ``load_dict`` value.

    Raises TypeError for a value it does not know how to describe: silently
    skipping it would let two different scenes share a fingerprint.
    """
    mi = mitsuba()
    if isinstance(value, dict):
        return {str(key): canonical(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [canonical(item) for item in value]
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return _round(value)
    if isinstance(value, np.ndarray):
        return _array_summary("array", value)
    if isinstance(value, mi.ScalarTransform4f):
        return {"transform": [_round(x) for x in np.asarray(value.matrix).ravel()]}
    if isinstance(value, mi.Bitmap):
        return _array_summary(
            "bitmap",
            np.asarray(value),
            pixel_format=str(value.pixel_format()),
            srgb_gamma=bool(value.srgb_gamma()),
        )
    if isinstance(value, np.generic):
        return canonical(value.item())
    import drjit as dr  # loaded with mitsuba above; not at import (see runtime.py)

    if dr.is_array_v(value):
        # Dr.Jit scalar vectors/colours (ScalarPoint3f, ScalarColor3f, ...).
        return [_round(float(x)) for x in np.asarray(value).ravel()]
    raise TypeError(f"cannot fingerprint a scene value of type {type(value).__name__}")


def builtin_fingerprint(definition: dict[str, Any], library_version: int) -> str:
    """Fingerprint of a built-in scene's resolution-free dictionary."""
    document = {"kind": "builtin", "library": library_version, "scene": canonical(definition)}
    # Key order is kept, not sorted: it is the order of shapes and emitters in
    # the loaded scene (light indices, random sequences), i.e. part of the scene.
    text = json.dumps(document, separators=(",", ":"), allow_nan=False)
    return _digest(text.encode())


# ---- XML scenes --------------------------------------------------------------

def _strip_film_size(root: ET.Element) -> None:
    """Remove the film width/height of every sensor, and defaults only they used."""
    used_by_size: set[str] = set()
    for sensor in root.iter("sensor"):
        for film in sensor.iter("film"):
            for element in list(film):
                if element.tag == "integer" and element.get("name") in _FILM_SIZE_NAMES:
                    used_by_size.update(_PARAMETER.findall(element.get("value", "")))
                    film.remove(element)
    if not used_by_size:
        return
    # A `$res` default that nothing else uses is a resolution too.
    remaining = ET.tostring(root, encoding="unicode")
    still_used = set(_PARAMETER.findall(remaining))
    for default in list(root.findall("default")):
        if default.get("name") in used_by_size - still_used:
            root.remove(default)


def _defaults(root: ET.Element) -> dict[str, str]:
    return {
        d.get("name", ""): d.get("value", "") for d in root.findall("default") if d.get("name")
    }


def _substitute(value: str, defaults: dict[str, str]) -> str:
    return _PARAMETER.sub(lambda m: defaults.get(m.group(1), m.group(0)), value)


def _referenced_names(root: ET.Element) -> list[str]:
    """File names a scene reads: ``filename`` properties and ``<include>`` files.

    Mitsuba plugins (meshes, bitmaps, env maps, spectra, volumes) all take
    their input file through a property named ``filename``.
    """
    defaults = _defaults(root)
    names: list[str] = []
    for element in root.iter():
        if element.tag == "include" and element.get("filename"):
            names.append(element.get("filename", ""))
        elif element.get("name") == "filename" and element.get("value"):
            names.append(element.get("value", ""))
    return [_substitute(name, defaults) for name in names]


def resolve_referenced(name: str, folder: Path) -> Path | None:
    path = Path(name)
    for candidate in (path,) if path.is_absolute() else (folder / path, Path.cwd() / path):
        if candidate.is_file():
            return candidate
    return None


def _content_form(root: ET.Element, folder: Path, seen: set[Path]) -> str:
    """The scene's canonical XML independent of how its files are named: film size
    removed, ``$name`` parameters replaced by their defaults (and the defaults dropped),
    and every file the scene reads replaced by its content: the SHA-256 of its bytes, or
    for an included XML file the digest of its own content form. A scene and a copy of
    it whose files were renamed (the upload a service stages) give the same form."""
    copy = ET.fromstring(ET.tostring(root))     # a deep copy we may edit
    _strip_film_size(copy)
    defaults = _defaults(copy)
    for default in list(copy.findall("default")):
        copy.remove(default)
    for element in copy.iter():
        for key, value in element.attrib.items():
            element.set(key, _substitute(value, defaults))
        attribute = ("filename" if element.tag == "include" and element.get("filename")
                     else "value" if element.get("name") == "filename" and element.get("value")
                     else None)
        if attribute is not None:
            element.set(attribute, _file_content(element.get(attribute, ""), folder, seen))
    return ET.canonicalize(ET.tostring(copy, encoding="unicode"), strip_text=True)


def _file_content(name: str, folder: Path, seen: set[Path]) -> str:
    """What stands for the file ``name`` in :func:`_content_form`."""
    path = resolve_referenced(name, folder)
    if path is None:
        # Mitsuba found it elsewhere or never needed it; the name still counts.
        return f"missing:{name}"
    data = path.read_bytes()
    resolved = path.resolve()
    if path.suffix.lower() == ".xml" and resolved not in seen:
        seen.add(resolved)
        try:
            included = ET.fromstring(data)
        except ET.ParseError:
            pass    # its bytes count; Mitsuba reports the error itself
        else:
            return "xml:" + _digest(_content_form(included, path.parent, seen).encode())
    return "sha256:" + hashlib.sha256(data).hexdigest()


def xml_fingerprint(root: ET.Element, xml_path: Path) -> str:
    """Fingerprint of a parsed XML scene (``root`` is not modified): the digest of its
    :func:`_content_form`, so the same scene with its files under other names (a copy
    uploaded to a service) has the same fingerprint."""
    text = _content_form(root, xml_path.parent, {xml_path.resolve()})
    document = {"kind": "xml", "form": 2, "scene": text}
    return _digest(json.dumps(document, separators=(",", ":")).encode())
