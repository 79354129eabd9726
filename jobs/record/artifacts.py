"""Content-addressed storage of result files (EXR images, error maps, PNG previews).

Files live outside the database, named by the SHA-256 of their bytes:
``root/ab/cdef….exr`` for hash ``abcdef…``. The database keeps only the relative
path and the hash (``jobs.record.models.Artifact``), so equal files written by many
runs or seeds are stored once, and a path never changes meaning.

Writes are atomic: content goes to a temporary file in the destination folder
(same filesystem) and is renamed into place with ``os.replace``, so a reader, a
crash or a concurrent writer of the same content never sees a partial file.

Files are owner-only (0600) in owner-only folders (0700): results, specs and
errors are the service's to serve, under its own access rules (docs/security.md),
not readable by every account on the machine.
"""

import hashlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path, PurePosixPath
from typing import Any, BinaryIO, NamedTuple

import numpy as np

from jobs.record.storage import StorageFull

_CHUNK = 1 << 20            # bytes read at a time when hashing or copying files
_TEMP_PREFIX = ".tmp-"      # temporary files; never a valid content-addressed name
PRIVATE_DIR_MODE = 0o700
PRIVATE_FILE_MODE = 0o600
#: Kinds of a run's per-pixel maps over its seeds (metrics.pixel_maps), one EXR each.
RELATIVE_BIAS_MAP = "rel_bias_map"
RELATIVE_VARIANCE_MAP = "rel_variance_map"


def make_private_dir(path: Path) -> Path:
    """``mkdir -p path``, each folder it creates owner-only (existing ones untouched)."""
    missing = []
    folder = Path(path)
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for folder in reversed(missing):
        try:
            folder.mkdir(mode=PRIVATE_DIR_MODE)
        except FileExistsError:     # created by another process meanwhile
            pass
    return Path(path)


class StoredBlob(NamedTuple):
    """Where stored content lives: its hash and its path relative to the root."""

    sha256: str
    relpath: str


class ArtifactStore:
    """Content-addressed files under ``root`` (``Settings.artifacts_dir``)."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)

    def put_bytes(self, data: bytes, suffix: str = "") -> StoredBlob:
        """Store ``data`` (once per distinct content and suffix) and return where."""
        sha256 = hashlib.sha256(data).hexdigest()
        return self._install(sha256, suffix, len(data), lambda out: out.write(data))

    def put_file(self, path: Path | str, suffix: str | None = None) -> StoredBlob:
        """Store a copy of the file at ``path``; ``suffix`` defaults to its own."""
        path = Path(path)
        suffix = path.suffix if suffix is None else suffix
        digest = hashlib.sha256()
        with path.open("rb") as source:
            while chunk := source.read(_CHUNK):
                digest.update(chunk)
        sha256 = digest.hexdigest()

        def copy(out: BinaryIO) -> None:
            # Hash the bytes actually copied: a file rewritten between the two
            # reads must not be stored under the old content's name.
            check = hashlib.sha256()
            with path.open("rb") as source:
                while chunk := source.read(_CHUNK):
                    check.update(chunk)
                    out.write(chunk)
            if check.hexdigest() != sha256:
                raise RuntimeError(f"{path} changed while it was being stored; store it again")

        return self._install(sha256, suffix, path.stat().st_size, copy)

    def path_of(self, relpath: str) -> Path:
        """The absolute location of a stored relative path.

        Refuses paths that would leave the root, since relative paths may come
        from a request (artifact downloads).
        """
        pure = PurePosixPath(relpath)
        if pure.is_absolute() or ".." in pure.parts or not pure.parts:
            raise ValueError(f"{relpath!r} is not a path inside the artifact store")
        return self.root.joinpath(*pure.parts)

    def _install(
        self, sha256: str, suffix: str, size: int, write: Callable[[BinaryIO], object]
    ) -> StoredBlob:
        suffix = _normalize_suffix(suffix)
        relpath = f"{sha256[:2]}/{sha256[2:]}{suffix}"
        destination = self.root / sha256[:2] / f"{sha256[2:]}{suffix}"
        # Same name means same content, so an existing file of the right size is
        # this content already (the size check catches a truncated file left by
        # something other than this class, which only ever renames complete files).
        if destination.is_file() and destination.stat().st_size == size:
            return StoredBlob(sha256, relpath)
        make_private_dir(destination.parent)
        fd, temp_name = tempfile.mkstemp(prefix=_TEMP_PREFIX, dir=destination.parent)
        try:
            with os.fdopen(fd, "wb") as out:
                write(out)
                out.flush()
                # Durable before the rename makes it visible: a crash must not
                # leave a complete-looking name over incomplete data.
                os.fsync(out.fileno())
                written = os.fstat(out.fileno()).st_size
            if written != size:
                raise StorageFull(f"stored {written} of {size} bytes of {relpath}")
            # mkstemp creates 0600 already; say so, whatever the platform does.
            os.chmod(temp_name, PRIVATE_FILE_MODE)
            os.replace(temp_name, destination)
        except BaseException:
            try:
                os.unlink(temp_name)
            except FileNotFoundError:
                pass
            raise
        return StoredBlob(sha256, relpath)


def _normalize_suffix(suffix: str) -> str:
    """'.exr' or 'exr' -> '.exr'; '' stays ''. Suffixes are names, not paths."""
    if suffix and not suffix.startswith("."):
        suffix = "." + suffix
    if "/" in suffix or "\\" in suffix or suffix in (".", ".."):
        raise ValueError(f"{suffix!r} is not a file suffix (e.g. '.exr')")
    return suffix


def artifact_record(store: ArtifactStore, data: bytes, kind: str, suffix: str, media_type: str,
                    seed: int | None = None) -> dict[str, Any]:
    """Store ``data`` and return the ``Artifact`` columns that reference it."""
    sha256, relpath = store.put_bytes(data, suffix)
    return {"kind": kind, "media_type": media_type, "sha256": sha256, "path": relpath,
            "bytes": len(data), "seed": seed}


def encode_image(writer: Callable[[Path, np.ndarray], None], image: np.ndarray,
                 scratch: Path) -> bytes:
    """Bytes of ``image`` encoded by ``writer`` (e.g. EXR or PNG) through a scratch file.

    The file is a unique temporary next to ``scratch`` (with its suffix): several
    processes encode into one data folder at once.
    """
    fd, name = tempfile.mkstemp(prefix=_TEMP_PREFIX, suffix=scratch.suffix, dir=scratch.parent)
    os.close(fd)
    path = Path(name)
    try:
        writer(path, image)
        data = path.read_bytes()
    finally:
        path.unlink(missing_ok=True)
    if not data:    # never store an image as the hash of nothing
        raise StorageFull(f"the encoded image {scratch.name} is empty")
    return data
