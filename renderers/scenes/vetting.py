"""Vetting a Mitsuba XML scene that a remote user names: which files it reads, and
whether each may be read, before anything of it is loaded.

A scene given over the REST API comes either from an upload (its XML and files
sent with the request) or from a file under the service's configured scene
roots. Mitsuba would read whatever the XML names — ``<include filename>``, a
mesh's or bitmap's ``filename`` property, ``<spectrum filename>``, a ``$name``
whose ``<default>`` is a path — from anywhere on the machine, and quote a line of
it in its error. So before a render ever sees the scene:

* every reference is found here, after ``$`` substitution, in the main XML and
  (recursively) in every included XML;
* each must resolve inside the upload, or under a scene root after symlinks;
  anything else, and anything missing, is refused with one message (no oracle
  telling "exists" from "not allowed");
* the vetted bytes are returned as a *staged* scene: flat, content-named files
  and XML rewritten to name them (``$`` substituted, ``<default>``s dropped), which
  the service stores and the render loads instead of the originals. The render
  never opens an original path, so a file swapped after vetting changes nothing.

Which files a reference may name (``source``), and how a name is looked up, is
the only difference between uploads and roots: see :class:`RootSource` and
:class:`UploadSource`. Relative names are looked up, like Mitsuba does, first
next to the XML that names them, then next to the main scene file.

A file's content is a :data:`Blob`: bytes, or the path of a file that only the
service writes (an upload received to disk). XML is parsed in memory; every other
file of an upload is hashed and copied from disk in chunks, never held whole.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import stat
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Protocol
from xml.parsers import expat

from renderers.scenes.errors import SceneError

#: The staged main scene's file name.
STAGED_SCENE = "scene.xml"
#: Hex digits of a staged scene's digest (its id): 128 bits.
DIGEST_LENGTH = 32
#: Includes nested deeper than this are refused (a cycle is refused at once).
MAX_INCLUDE_DEPTH = 16

_PARAMETER = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")
# Tags that change where Mitsuba looks for files (its `<path value=...>` prepends a
# folder to the file resolver).
_RESOLVER_TAGS = frozenset({"path", "resource"})
# Attributes that name things, never files.
_NAME_ATTRIBUTES = frozenset({"name", "type", "id", "version"})
_UNSAFE_NAME_CHARACTERS = re.compile(r"[^A-Za-z0-9._-]")
#: Bytes read at a time when hashing a file on disk.
_CHUNK = 1 << 20

#: A file's content: its bytes, or a private file holding them (an upload on disk).
Blob = bytes | Path


def blob_size(blob: Blob) -> int:
    return blob.stat().st_size if isinstance(blob, Path) else len(blob)


def blob_sha256(blob: Blob) -> str:
    if not isinstance(blob, Path):
        return hashlib.sha256(blob).hexdigest()
    digest = hashlib.sha256()
    with blob.open("rb") as file:
        while chunk := file.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def blob_bytes(blob: Blob) -> bytes:
    return blob.read_bytes() if isinstance(blob, Path) else blob


class SceneRefused(SceneError):
    """The scene (or a file it names) may not be used; the message is safe to serve."""


class SceneTooLarge(SceneRefused):
    """A file of the scene, or all of them together, exceed a configured size limit."""


@dataclass(frozen=True)
class Limits:
    """Size limits of a vetted scene (bytes)."""

    max_file_bytes: int
    max_total_bytes: int
    max_files: int = 1000
    #: XML elements of a scene, its included files together: checked by a streaming
    #: parse before any tree is built (a tree costs ~1 KB per element).
    max_xml_elements: int = 100_000


#: The scene-size limits' environment variables and defaults (bytes): each file of a
#: scene (its XML, includes, meshes, textures), and all of its files together.
MAX_FILE_BYTES_VARIABLE, MAX_TOTAL_BYTES_VARIABLE = (
    "NIRC_BENCH_SCENE_MAX_FILE_BYTES", "NIRC_BENCH_SCENE_MAX_BYTES")
DEFAULT_MAX_FILE_BYTES, DEFAULT_MAX_TOTAL_BYTES = 64 << 20, 256 << 20


#: The XML elements' limit's environment variable (the default: Limits).
MAX_XML_ELEMENTS_VARIABLE = "NIRC_BENCH_SCENE_MAX_XML_ELEMENTS"


def scene_limits() -> Limits:
    """The one size limit of scenes: what a scene given by path may hold (every file
    within ``max_file_bytes``, checked by the loader before anything opens it) and what
    the service stores (an upload or a scene root's copy, also within
    ``max_total_bytes``). Read from the environment at every call, never at import, so
    a process sees its own environment."""
    values = []
    for variable, default in ((MAX_FILE_BYTES_VARIABLE, DEFAULT_MAX_FILE_BYTES),
                              (MAX_TOTAL_BYTES_VARIABLE, DEFAULT_MAX_TOTAL_BYTES),
                              (MAX_XML_ELEMENTS_VARIABLE, Limits.max_xml_elements)):
        text = os.environ.get(variable, "").strip()
        try:
            value = int(text) if text else default
        except ValueError:
            raise ValueError(f"{variable}={text!r}: a whole number is needed") from None
        if value < 1:
            raise ValueError(f"{variable}={value}: the limit must be at least 1")
        values.append(value)
    return Limits(max_file_bytes=values[0], max_total_bytes=values[1],
                  max_xml_elements=values[2])


@dataclass(frozen=True)
class StagedScene:
    """A vetted scene ready to be stored: ``files`` (staged name -> content) hold the
    rewritten main XML under :data:`STAGED_SCENE` and everything it reads."""

    digest: str
    files: dict[str, Blob]

    @property
    def total_bytes(self) -> int:
        return sum(blob_size(data) for data in self.files.values())


class Source(Protocol):
    """Where a scene's files may come from."""

    def open(self, name: str, near: Sequence[str]) -> tuple[str, Blob] | None:
        """The key and content of the file ``name`` (looked up relative to each folder
        key of ``near`` in turn when relative), or None if it is missing *or* not
        allowed — the caller must not be able to tell which."""
        ...

    def folder(self, key: str) -> str:
        """The folder key of the file ``key`` (for names relative to it)."""
        ...


def _shown(name: str) -> str:
    """A user-given name as quoted in a message (bounded, printable)."""
    return repr(name[:200])


# ---- Sources -----------------------------------------------------------------

class RootSource:
    """Files under the service's scene roots, found without looking outside them.

    A name is first normalised as text (``a/../b`` is ``b``; nothing on disk is asked
    what ``a`` is) and must then lie inside a root; only after that is the disk
    touched, one component at a time from the root (:func:`_confined`), each
    symlink followed as text and checked against the roots again. So neither a
    ``..`` after a file (``/etc/shadow/../..``) nor a symlink leading out makes
    the answer depend on what exists outside the roots. The file is then opened
    without blocking (a FIFO cannot hang the request) and its open descriptor
    checked again (``/proc/self/fd``) against the roots, so a link swapped in
    between is caught.
    """

    def __init__(self, roots: Iterable[Path], limits: Limits) -> None:
        # A root as configured (maybe through a symlink) -> the same root resolved: a
        # client may spell a path either way. Deepest first: nested roots are allowed.
        self.spellings = sorted(
            ((Path(os.path.normpath(Path(root).expanduser().absolute())), resolved)
             for root in roots if (resolved := _resolve_root(root))),
            key=lambda pair: -len(pair[0].parts))
        self.roots = [resolved for _, resolved in self.spellings]
        self.limits = limits

    def _inside(self, path: Path) -> bool:
        return any(path.is_relative_to(root) for root in self.roots)

    def open(self, name: str, near: Sequence[str]) -> tuple[str, bytes] | None:
        if not name or "\x00" in name or not self.roots:
            return None
        path = Path(name)
        candidates = [path] if path.is_absolute() else [Path(folder) / path for folder in near]
        for candidate in candidates:
            found = self._read(candidate)
            if found is not None:
                return found
        return None

    def folder(self, key: str) -> str:
        return str(Path(key).parent)

    def _read(self, path: Path) -> tuple[str, bytes] | None:
        real = _confined(str(path), self.roots, self.spellings)
        if real is None:
            return None
        try:
            fd = os.open(real, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
        except OSError:
            return None
        try:
            opened = Path(os.readlink(f"/proc/self/fd/{fd}")) if Path("/proc/self/fd").is_dir() \
                else real
            info = os.fstat(fd)
            if not self._inside(opened) or not stat.S_ISREG(info.st_mode):
                return None
            _check_file_size(str(real), info.st_size, self.limits)
            with os.fdopen(os.dup(fd), "rb") as file:
                # One byte past the size seen (or the limit) shows a file that grows.
                data = file.read(min(info.st_size, self.limits.max_file_bytes) + 1)
            _check_file_size(str(real), len(data), self.limits)
            return str(opened), data
        except OSError:
            return None
        finally:
            os.close(fd)


#: Symlinks followed on the way to one file before it is refused (Linux's own limit).
MAX_SYMLINKS = 40


def _confined(name: str, roots: Sequence[Path],
              spellings: Sequence[tuple[Path, Path]]) -> Path | None:
    """The regular file ``name`` (absolute) names, every symlink resolved, or None if
    it is missing or leads outside ``roots`` at any step (the caller cannot tell which).

    ``name`` is normalised as text before anything is looked up, and must lie inside a
    root (``spellings`` maps a root as configured to the resolved root). The disk is
    then asked only about components below the root: a symlink's target is joined as
    text to the (symlink-free) folder it sits in, normalised, and must lie inside a
    root again before the walk goes on."""
    text = os.path.normpath(name)
    for _ in range(MAX_SYMLINKS + 1):
        path = Path(text)
        root = next((root for root in roots if path.is_relative_to(root)), None)
        if root is None:
            spelled = next(((given, real) for given, real in spellings
                            if path.is_relative_to(given)), None)
            if spelled is None:
                return None
            root, path = spelled[1], spelled[1] / path.relative_to(spelled[0])
        walked = root
        parts = path.relative_to(root).parts
        for index, part in enumerate(parts):
            step = walked / part
            try:
                info = os.lstat(step)
            except (OSError, ValueError):
                return None
            if stat.S_ISLNK(info.st_mode):
                try:
                    target = os.readlink(step)
                except OSError:
                    return None
                text = os.path.normpath(os.path.join(walked, target, *parts[index + 1:]))
                break
            if index < len(parts) - 1 and not stat.S_ISDIR(info.st_mode):
                return None
            walked = step
        else:
            return walked if walked != root and walked.is_file() else None
    return None


def _resolve_root(root: Path) -> Path | None:
    try:
        resolved = Path(root).expanduser().resolve(strict=True)
    except (OSError, RuntimeError):
        return None  # a root that does not exist allows nothing
    return resolved if resolved.is_dir() else None


def upload_name(name: str) -> str | None:
    """``name`` as a normalized relative POSIX path inside an upload, or None if it
    is absolute, empty, or climbs out (``..``)."""
    if not name or "\x00" in name or "\\" in name:
        return None
    path = PurePosixPath(name)
    if path.is_absolute() or any(part in ("..", "") for part in path.parts):
        return None
    parts = [part for part in path.parts if part != "."]
    return "/".join(parts) if parts else None


class UploadSource:
    """The files of an upload (relative name -> content); nothing else exists."""

    def __init__(self, files: Mapping[str, Blob]) -> None:
        self.files = dict(files)

    def open(self, name: str, near: Sequence[str]) -> tuple[str, Blob] | None:
        if upload_name(name) is None:
            return None
        for folder in near:
            key = upload_name(str(PurePosixPath(folder) / name)) if folder else upload_name(name)
            if key is not None and key in self.files:
                return key, self.files[key]
        return None

    def folder(self, key: str) -> str:
        parent = str(PurePosixPath(key).parent)
        return "" if parent == "." else parent


def _check_file_size(name: str, size: int, limits: Limits) -> None:
    if size > limits.max_file_bytes:
        raise SceneTooLarge(f"file {_shown(name)} is {size} bytes; the limit is "
                            f"{limits.max_file_bytes} bytes per file")


# ---- The XML walk --------------------------------------------------------------

#: Elements nested deeper than this are refused before any tree is built: Mitsuba
#: scenes nest a handful of levels (scene, shape, bsdf, texture, ...), and the tree's
#: serializer recurses once per level.
MAX_XML_DEPTH = 64


class _Unacceptable(Exception):
    """Raised by the streaming check's handlers: what the XML may not hold."""


class _TooManyElements(_Unacceptable):
    pass


def _refuse_document_type(*_: object) -> None:
    raise _Unacceptable("a document type declaration (<!DOCTYPE>) is not allowed in a scene")


def _check_structure(data: bytes, max_elements: int) -> None:
    """Stream through ``data`` without keeping anything, refusing DTDs (entities could
    expand without bound or name files of their own), elements nested deeper than
    :data:`MAX_XML_DEPTH` and more than ``max_elements`` elements: it stops at the first
    element too many. A parser of its own finds a DTD in any encoding the XML may
    declare."""
    checker = expat.ParserCreate()
    checker.StartDoctypeDeclHandler = _refuse_document_type
    checker.EntityDeclHandler = _refuse_document_type
    depth = elements = 0

    def start(*_: object) -> None:
        nonlocal depth, elements
        depth, elements = depth + 1, elements + 1
        if elements > max_elements:
            raise _TooManyElements
        if depth > MAX_XML_DEPTH:
            raise _Unacceptable(f"elements nested more than {MAX_XML_DEPTH} deep (the limit)")

    def end(_: str) -> None:
        nonlocal depth
        depth -= 1

    checker.StartElementHandler, checker.EndElementHandler = start, end
    checker.Parse(data, True)


def _parse(data: bytes, shown: str, budget: int, limits: Limits) -> ET.Element:
    """The tree of ``data``, which may hold ``budget`` more elements of the scene."""
    try:
        _check_structure(data, budget)
        root = ET.fromstring(data)
    except _TooManyElements:
        raise SceneRefused(f"{shown}: the scene's XML holds more than "
                           f"{limits.max_xml_elements} elements (the limit, "
                           f"{MAX_XML_ELEMENTS_VARIABLE})") from None
    except _Unacceptable as err:
        raise SceneRefused(f"{shown}: {err}") from None
    except (ET.ParseError, expat.ExpatError) as err:
        line, column = (err.position if isinstance(err, ET.ParseError)
                        else (err.lineno, err.offset))
        raise SceneRefused(f"{shown}: malformed XML at line {line}, column {column + 1}") \
            from None
    if root.tag != "scene":
        raise SceneRefused(f"{shown}: not a Mitsuba scene (the root element is not <scene>)")
    return root


def _is_reference(element: ET.Element, attribute: str, value: str) -> bool:
    """Whether Mitsuba could open ``value`` as a file: a ``filename`` attribute
    (``<include>``, ``<spectrum>``), the value of a property named ``filename``,
    or any value that looks like a path."""
    if attribute == "filename":
        return True
    if attribute in _NAME_ATTRIBUTES:
        return False
    if attribute == "value" and element.get("name") == "filename":
        return True
    return "/" in value or "\\" in value or value.startswith("~")


def _staged_name(key: str, sha256: str) -> str:
    """A flat, content-addressed name that keeps the original's extension (Mitsuba
    picks some readers by it)."""
    base = _UNSAFE_NAME_CHARACTERS.sub("_", PurePosixPath(key.replace("\\", "/")).name)[-80:]
    return f"{sha256[:16]}-{base or 'file'}"


@dataclass
class _Walk:
    source: Source
    limits: Limits
    scene: str  # the scene's name as the user gave it, for messages
    main_folder: str
    defaults: dict[str, str] = field(default_factory=dict)
    files: dict[str, Blob] = field(default_factory=dict)
    hashes: dict[str, str] = field(default_factory=dict)  # staged name -> sha256
    staged: dict[str, str] = field(default_factory=dict)  # source key -> staged name
    including: list[str] = field(default_factory=list)  # the chain of XML being walked
    elements: int = 0  # XML elements of the files parsed so far

    def unavailable(self, name: str) -> SceneRefused:
        return SceneRefused(f"scene {_shown(self.scene)}: the file {_shown(name)} it "
                            "references is not available (a scene's files must be in its "
                            "upload, or under the service's scene roots)")

    def substitute(self, value: str) -> str:
        substituted = _PARAMETER.sub(lambda m: self.defaults.get(m.group(1), m.group(0)), value)
        if "$" in substituted:
            raise SceneRefused(f"scene {_shown(self.scene)}: {_shown(value)} uses a parameter "
                               "without a <default> (over the API a scene cannot be given "
                               "parameters)")
        return substituted

    def add(self, key: str, data: Blob, name: str) -> str:
        if key not in self.staged:
            _check_file_size(name, blob_size(data), self.limits)
            sha256 = blob_sha256(data)
            staged = _staged_name(key, sha256)
            self.files[staged], self.hashes[staged] = data, sha256
            self.staged[key] = staged
            total = sum(blob_size(d) for d in self.files.values())
            if total > self.limits.max_total_bytes:
                raise SceneTooLarge(f"scene {_shown(self.scene)} is more than "
                                    f"{self.limits.max_total_bytes} bytes in all (the limit)")
            if len(self.files) > self.limits.max_files:
                raise SceneTooLarge(f"scene {_shown(self.scene)} reads more than "
                                    f"{self.limits.max_files} files (the limit)")
        return self.staged[key]

    def xml(self, key: str, data: bytes, shown: str) -> bytes:
        """``data`` (the XML at ``key``) with every reference vetted, staged and
        renamed, ``$`` parameters substituted and ``<default>``s dropped."""
        if key in self.including:
            raise SceneRefused(f"scene {_shown(self.scene)}: {shown} includes itself")
        if len(self.including) >= MAX_INCLUDE_DEPTH:
            raise SceneRefused(f"scene {_shown(self.scene)}: includes are nested more than "
                               f"{MAX_INCLUDE_DEPTH} deep")
        root = _parse(data, shown, self.limits.max_xml_elements - self.elements, self.limits)
        self.elements += sum(1 for _ in root.iter())
        # Mitsuba keeps a parameter's first definition; includes see the scene's.
        for default in root.iter("default"):
            if default.get("name"):
                self.defaults.setdefault(default.get("name", ""), default.get("value", ""))
        near = [self.source.folder(key), self.main_folder]
        self.including.append(key)
        for parent in list(root.iter()):
            for element in list(parent):
                if element.tag == "default":
                    parent.remove(element)
                elif element.tag in _RESOLVER_TAGS:
                    raise SceneRefused(f"scene {_shown(self.scene)}: <{element.tag}> (extra "
                                       "file search folders) is not allowed")
        for element in root.iter():
            # Substitute every attribute first: `name="$n"` may turn out to be "filename".
            for attribute, value in list(element.attrib.items()):
                element.set(attribute, self.substitute(value))
            for attribute, value in list(element.attrib.items()):
                if _is_reference(element, attribute, value):
                    element.set(attribute, self.reference(element, value, near))
        self.including.pop()
        return ET.tostring(root, encoding="utf-8", xml_declaration=False)

    def reference(self, element: ET.Element, name: str, near: list[str]) -> str:
        found = self.source.open(name, near)
        if found is None:
            raise self.unavailable(name)
        key, data = found
        if element.tag == "include" and key not in self.staged:
            data = self.xml(key, blob_bytes(data), f"included file {_shown(name)}")
        return self.add(key, data, name)


def _digest(hashes: Mapping[str, str]) -> str:
    """The id of a staged scene: the hash of its files' names and hashes."""
    text = json.dumps(dict(sorted(hashes.items())), separators=(",", ":"), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:DIGEST_LENGTH]


def _stage(source: Source, key: str, data: bytes, shown: str, limits: Limits) -> StagedScene:
    """The staged scene of the main XML ``data`` (at ``key`` of ``source``)."""
    walk = _Walk(source, limits, shown, source.folder(key))
    main = walk.xml(key, data, f"scene {_shown(shown)}")
    _check_file_size(shown, len(main), limits)
    files = {STAGED_SCENE: main, **walk.files}
    if sum(blob_size(d) for d in files.values()) > limits.max_total_bytes:
        raise SceneTooLarge(f"scene {_shown(shown)} is more than {limits.max_total_bytes} "
                            "bytes in all (the limit)")
    return StagedScene(_digest({STAGED_SCENE: blob_sha256(main), **walk.hashes}), files)


def vet_root_scene(path: str, roots: Sequence[Path], limits: Limits,
                   missing: str | None = None) -> StagedScene:
    """Vet the scene file ``path`` (absolute, or relative to each root in turn) and
    everything it reads. ``missing`` is the message when the file itself is not
    available — the same whether it does not exist or lies outside the roots.
    Raises :class:`SceneRefused` (:class:`SceneTooLarge` for a size limit)."""
    source = RootSource(roots, limits)
    if "\x00" not in path:
        candidates = [path] if Path(path).is_absolute() else [
            str(root / path) for root in source.roots]
        for candidate in candidates:
            found = source.open(candidate, [])
            if found is not None:
                return _stage(source, *found, path, limits)
    raise SceneRefused(missing or f"scene {_shown(path)} is not available")


#: The key of an upload's main XML: no uploaded file can have it (NUL).
_UPLOAD_MAIN = "\x00scene.xml"


def vet_upload(xml: bytes, files: Mapping[str, Blob], limits: Limits) -> StagedScene:
    """Vet an uploaded scene: its main ``xml`` and ``files`` (relative name -> content),
    the only files it may read. Raises :class:`SceneRefused` (or
    :class:`SceneTooLarge`), naming the first bad name or limit."""
    for name, data in files.items():
        if upload_name(name) != name:
            raise SceneRefused(f"file name {_shown(name)} of the upload must be relative, "
                               "without '..', '.' or backslashes")
        _check_file_size(name, blob_size(data), limits)
    total = len(xml) + sum(blob_size(data) for data in files.values())
    if total > limits.max_total_bytes:
        raise SceneTooLarge(f"the upload is {total} bytes; the limit is "
                            f"{limits.max_total_bytes} bytes in all")
    _check_file_size("the scene XML", len(xml), limits)
    return _stage(UploadSource(files), _UPLOAD_MAIN, xml, "the uploaded scene", limits)
