"""Loading Mitsuba 3 XML scenes given by path, with the film resolution overridden.

The resolution override edits the XML *text* of each sensor's film (it
replaces the values of ``<integer name="width|height">``, or inserts them,
or inserts a film) without adding or removing lines, so that the line numbers
in Mitsuba's error messages still point into the user's file. Positions come
from an expat pass over the original bytes. Relative file names in the scene
are resolved from the XML file's folder, as ``mitsuba`` on the command line
would.

Every failure a user can cause (missing file, malformed XML, a scene Mitsuba
refuses) becomes a one-line :class:`SceneError` naming the file. So does a
scene Mitsuba loads without complaint but cannot render meaningfully (see
:func:`check_finite_scene`): a shape whose transform or vertices are NaN or
infinite (Mitsuba drops it silently: it is never hit), or an emitter whose
radiance is NaN or infinite (every estimate it touches is NaN or infinite).
"""

from __future__ import annotations

import math
import re
import threading
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.parsers import expat

import numpy as np

from renderers.scenes.errors import SceneError, SceneNotFinite
from renderers.scenes.fingerprint import xml_fingerprint
from renderers.scenes.resolution import Resolution
from renderers.scenes.runtime import mitsuba
from renderers.scenes.xml_settings import xml_settings

# A start tag from its '<' to its '>', skipping '>' inside quoted attributes.
_START_TAG = re.compile(rb"<[^\s/>]+(?:[^\"'>]|\"[^\"]*\"|'[^']*')*>")
_VALUE_ATTRIBUTE = re.compile(rb"value\s*=\s*(\"[^\"]*\"|'[^']*')")
_SIZE_NAMES = ("width", "height")


@dataclass
class _Tag:
    """Byte span of an element's start tag in the original file."""

    start: int
    end: int

    def self_closing(self, data: bytes) -> bool:
        return data[self.end - 2 : self.end] == b"/>"


@dataclass
class _Film:
    tag: _Tag
    sizes: dict[str, _Tag] = field(default_factory=dict)  # 'width'/'height' -> integer tag


@dataclass
class _Sensor:
    tag: _Tag
    films: list[_Film] = field(default_factory=list)


@dataclass
class XmlScene:
    """A loaded XML scene with what the loader needs to report about it."""

    path: Path
    scene: Any  # mi.Scene
    resolution: Resolution
    fingerprint: str
    settings: dict[str, Any] = field(default_factory=dict)  # renderers.scenes.xml_settings


def _scan_sensors(data: bytes) -> list[_Sensor]:
    """Start-tag positions of each sensor, its films and their width/height."""
    parser = expat.ParserCreate()
    stack: list[str] = []
    sensors: list[_Sensor] = []

    def start(tag: str, attributes: dict[str, str]) -> None:
        begin = parser.CurrentByteIndex
        match = _START_TAG.match(data, begin)
        span = _Tag(begin, match.end() if match else begin)
        parent = stack[-1] if stack else None
        if tag == "sensor":
            sensors.append(_Sensor(span))
        elif tag == "film" and parent == "sensor":
            sensors[-1].films.append(_Film(span))
        elif (
            tag == "integer"
            and parent == "film"
            and stack[-2:-1] == ["sensor"]
            and attributes.get("name") in _SIZE_NAMES
        ):
            sensors[-1].films[-1].sizes[attributes["name"]] = span
        stack.append(tag)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    parser.Parse(data, True)
    return sensors


def _insert_child(data: bytes, tag: _Tag, name: bytes, content: bytes) -> tuple[int, int, bytes]:
    """An edit putting ``content`` first inside the element whose start tag is ``tag``."""
    if tag.self_closing(data):
        # <film type="hdrfilm"/>  ->  <film type="hdrfilm">content</film>
        opening = data[tag.start : tag.end - 2].rstrip() + b">"
        return tag.start, tag.end, opening + content + b"</" + name + b">"
    return tag.end, tag.end, content


def override_film_size(data: bytes, width: int, height: int, path: Path) -> bytes:
    """The XML bytes with every sensor's film set to ``width`` x ``height``."""
    sensors = _scan_sensors(data)
    if not sensors:
        raise SceneError(f"{path}: the scene has no <sensor> whose resolution could be set")
    size = {"width": width, "height": height}

    def integer(name: str) -> bytes:
        return f'<integer name="{name}" value="{size[name]}"/>'.encode()

    edits: list[tuple[int, int, bytes]] = []
    for sensor in sensors:
        if not sensor.films:
            film = b'<film type="hdrfilm">' + integer("width") + integer("height") + b"</film>"
            edits.append(_insert_child(data, sensor.tag, b"sensor", film))
        for film_ in sensor.films:
            for name, tag in film_.sizes.items():
                new_value = f'value="{size[name]}"'.encode()
                new_tag = _VALUE_ATTRIBUTE.sub(new_value, data[tag.start : tag.end], count=1)
                edits.append((tag.start, tag.end, new_tag))
            missing = b"".join(integer(n) for n in _SIZE_NAMES if n not in film_.sizes)
            if missing:
                edits.append(_insert_child(data, film_.tag, b"film", missing))
    # Apply back to front so that earlier offsets stay valid.
    for start, end, replacement in sorted(edits, key=lambda edit: edit[0], reverse=True):
        data = data[:start] + replacement + data[end:]
    return data


# Mitsuba's file resolver is process-wide: two threads loading scenes from
# different folders must not interleave their prepend/restore.
_RESOLVER_LOCK = threading.Lock()


@contextmanager
def _resolving_from(folder: Path) -> Iterator[None]:
    """Let Mitsuba find the scene's relative file names in ``folder`` (then restore)."""
    mi = mitsuba()
    with _RESOLVER_LOCK:
        saved = mi.FileResolver(mi.file_resolver())
        resolver = mi.FileResolver(saved)
        resolver.prepend(str(folder))
        mi.set_file_resolver(resolver)
        try:
            yield
        finally:
            mi.set_file_resolver(saved)


def _mitsuba_message(error: Exception) -> str:
    """Mitsuba's error on one line, without its C++ source location."""
    message = " ".join(str(error).split())
    message = re.sub(r"^\[[\w.]+:\d+\]\s*", "", message)
    # The text came from load_string: say "line L, column C" of the user's file.
    return re.sub(r"At string \(line (\d+), col (\d+)\)", r"line \1, column \2", message)


def _parse(path: Path, data: bytes) -> ET.Element:
    try:
        root = ET.fromstring(data)
    except ET.ParseError as err:
        line, column = err.position
        reason = re.sub(r":\s*line \d+, column \d+$", "", str(err))
        raise SceneError(
            f"{path}: malformed XML at line {line}, column {column + 1}: {reason}"
        ) from None
    if root.tag != "scene":
        raise SceneError(
            f"{path}: not a Mitsuba scene (the root element is <{root.tag}>, expected <scene>)"
        )
    return root


def is_scene_file(name: str) -> bool:
    """True when ``name`` is the path of an existing file (False, not an error, for a
    name no file can have: too long, with a NUL character, or in the home folder of an
    unknown user, ``~user/...``, which ``expanduser`` reports as a RuntimeError)."""
    try:
        return Path(name).expanduser().is_file()
    except (OSError, ValueError, RuntimeError):
        return False


def _label(kind: str, index: int, obj: Any) -> str:
    """How the user's file names a shape or emitter: its id, else its type and position."""
    ident = obj.id()
    if ident and not ident.startswith("_unnamed"):
        return f"{kind} id={ident!r} ({obj.class_name()})"
    return f"{kind} #{index + 1} ({obj.class_name()}, no id)"


def _nonfinite_values(value: Any) -> bool:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False            # not numeric (a string, a nested object)
    return bool(array.size) and not bool(np.isfinite(array).all())


def check_finite_scene(scene: Any, path: Path) -> None:
    """Refuse (SceneError) a loaded scene with non-finite geometry or emission.

    A shape's bounding box is non-finite when its ``to_world`` (a ``scale``,
    ``translate``, ``rotate`` or ``matrix`` with NaN or inf) or its vertex
    positions are: Mitsuba renders such a shape as absent, so the run would
    measure a different scene than the file describes. An emitter parameter
    (radiance, intensity, scale, ...) that is NaN or infinite makes every pixel
    it lights non-finite. Both are named the way the file names them.
    """
    for index, shape in enumerate(scene.shapes()):
        box = shape.bbox()
        corners = [float(v) for v in (*box.min, *box.max)]
        if not all(math.isfinite(v) for v in corners):
            reason = ("has a NaN or infinite transform or vertex position (its bounding box "
                      "is not finite), so it would vanish from the render; fix its "
                      "<transform name=\"to_world\"> or its mesh")
            raise SceneNotFinite(f"{path}: {_label('shape', index, shape)} {reason}",
                                 f"shape #{index + 1} ({shape.class_name()}) {reason}")
    mi = mitsuba()
    for index, emitter in enumerate(scene.emitters()):
        for key, value in mi.traverse(emitter).items():
            if _nonfinite_values(value):
                shape = emitter.get_shape()
                where = (f" on {_label('shape', scene.shapes().index(shape), shape)}"
                         if shape is not None and shape in scene.shapes() else "")
                reason = (f"has a NaN or infinite {key.split('.')[0]!r}; every pixel it "
                          "lights would be NaN or infinite")
                raise SceneNotFinite(
                    f"{path}: {_label('emitter', index, emitter)}{where} {reason}",
                    f"emitter #{index + 1} ({emitter.class_name()}) {reason}")


def load_xml_scene(name: str, resolution: Resolution | None) -> XmlScene:
    """Load the XML scene at ``name``, optionally at ``resolution`` (width, height)."""
    if not is_scene_file(name):
        try:
            what = "is a directory, not a scene file" if Path(name).is_dir() else "not found"
        except (OSError, ValueError) as err:  # e.g. a name too long for any file
            what = f"not a usable path ({err})"
        raise SceneError(f"scene file {name[:200]!r}: {what}")
    path = Path(name).expanduser().resolve()
    try:
        data = path.read_bytes()
    except OSError as err:
        raise SceneError(f"scene file {path}: cannot be read ({err.strerror})") from None
    root = _parse(path, data)

    if resolution is not None:
        data = override_film_size(data, resolution[0], resolution[1], path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SceneError(f"{path}: not UTF-8 text (byte {err.start})") from None

    mi = mitsuba()
    try:
        with _resolving_from(path.parent):
            # optimize=False keeps emitter order and bounding box deterministic
            # (see loader.py).
            scene = mi.load_string(text, optimize=False)
    except Exception as err:  # noqa: BLE001 - every Mitsuba failure is the scene's fault
        message = _mitsuba_message(err)
        raise SceneError(f"{path}: Mitsuba could not load the scene: {message}") from None
    if not scene.sensors():
        raise SceneError(f"{path}: the scene has no <sensor> (camera) to render from")
    check_finite_scene(scene, path)

    width, height = (int(x) for x in scene.sensors()[0].film().size())
    return XmlScene(path, scene, (width, height), xml_fingerprint(root, path),
                    xml_settings(root, path.parent, frozenset({path.resolve()})))
