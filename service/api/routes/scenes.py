"""Uploading a Mitsuba XML scene with the files it reads (docs/service.md).

Over REST a scene is a built-in name, an uploaded scene's id, or a file under the
service's scene roots. An upload is one body, in either of two forms:

* ``application/x-tar``: a tar archive (uncompressed) holding ``scene.xml`` and
  every file it reads at the relative name the XML uses. The body is streamed to a
  private folder on disk as it arrives and counted against its cap (413 beyond,
  before anything more is read); the files are then unpacked one at a time in
  chunks, so the service never holds an upload in memory, only the XML it parses.
* ``application/json`` for small scenes: the XML as text and the files base64-encoded,
  ``{"xml": ..., "files": {name: base64}}``, within the service's body limit
  (``max_body_bytes``).

The scene is vetted — it may read only its own files — and stored
content-addressed; the answer's ``id`` (``upload:<digest>``) is then the ``scene``
of a job or sweep. The same upload twice gives the same id. A new scene that would
take the data folder past ``max_data_bytes`` is refused with 507, as is any upload
while the disk is under its free-space floor or one of the uploading key's size past
its quota (service/api/quota.py; counted as received, before the scene is vetted, so
a scene already stored is refused too); a stored upload counts in its key's quota.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import json
import shutil
import tarfile
import tempfile
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from functools import partial
from pathlib import Path

from fastapi import APIRouter, HTTPException, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from jobs.execution.work import data_bytes
from jobs.protocol.scene_store import NoRoom, save_upload
from jobs.record.artifacts import make_private_dir
from jobs.record.usage import mark_scene_owner
from renderers.scenes.vetting import (
    STAGED_SCENE,
    Blob,
    Limits,
    SceneRefused,
    SceneTooLarge,
    scene_limits,
    upload_name,
)
from service.api.deps import CallerDep, SettingsDep, StoreDep
from service.api.limits import MAX_DEPTH, is_unicode
from service.api.nesting import nested_deeper_than, too_deep_message
from service.api.quota import check_room
from service.api.schemas import SceneUploadOut
from service.api.unprocessable import unprocessable

router = APIRouter(prefix="/api/v1", tags=["scenes"])

#: The upload route; it reads its body under its own cap, not the service-wide one.
UPLOAD_PATH = "/api/v1/scenes"
TAR_TYPES = ("application/x-tar", "application/tar")
#: Tar headers and padding around the content: up to 4 KiB per file (long names).
_TAR_OVERHEAD_PER_FILE = 4096
_CHUNK = 1 << 20
#: Seconds a client is asked to wait while every upload slot is vetting a scene.
PARSE_RETRY_AFTER_S = 5


class SceneUpload(BaseModel):
    """The JSON body of ``POST /api/v1/scenes``."""

    model_config = ConfigDict(extra="forbid", strict=True)

    xml: str = Field(min_length=1, description="the scene's Mitsuba XML (text)")
    files: dict[str, str] = Field(
        default_factory=dict,
        description="the files the XML reads: relative name as the XML writes it -> "
                    "base64 of the file's bytes")


def _too_large(message: str) -> HTTPException:
    return HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, message)


def _unprocessable(loc: list[str], message: str) -> RequestValidationError:
    return unprocessable(message, ("body", *loc))


def _declared_over(request: Request, limit: int) -> bool:
    declared = request.headers.get("content-length", "")
    return declared.isdigit() and int(declared) > limit


async def _receive(request: Request, limit: int, message: str, out=None) -> bytes:
    """The request body, into ``out`` (a file) or returned; 413 as soon as it is longer
    than ``limit``."""
    if _declared_over(request, limit):
        raise _too_large(message)
    received, body = 0, bytearray()
    async for chunk in request.stream():
        received += len(chunk)
        if received > limit:
            raise _too_large(message)
        if out is None:
            body += chunk
        else:
            out.write(chunk)
    return bytes(body)


def _unpack(archive: Path, folder: Path, limits: Limits) -> tuple[bytes, dict[str, Blob]]:
    """The main XML and the files of an uploaded tar archive, each file copied to
    ``folder`` in chunks (never whole in memory). Only regular files under relative
    names without '..' are accepted; sizes are checked before anything is copied."""
    xml: bytes | None = None
    files: dict[str, Blob] = {}
    total = 0
    try:
        with tarfile.open(archive, mode="r:") as tar:
            for member in tar:
                if member.isdir():
                    continue
                name = upload_name(member.name)
                if name != member.name.removeprefix("./") or name is None:
                    raise SceneRefused(f"file name {member.name[:200]!r} of the archive must "
                                       "be relative, without '..' or backslashes")
                if not member.isfile():
                    raise SceneRefused(f"{name[:200]!r} in the archive is not a regular file "
                                       "(links and devices are not accepted)")
                if name in files or (name == STAGED_SCENE and xml is not None):
                    raise SceneRefused(f"{name[:200]!r} is in the archive twice")
                total += member.size
                if member.size > limits.max_file_bytes:
                    raise SceneTooLarge(f"file {name[:200]!r} is {member.size} bytes; the "
                                        f"limit is {limits.max_file_bytes} bytes per file")
                if total > limits.max_total_bytes or len(files) >= limits.max_files:
                    raise SceneTooLarge(f"the upload is more than {limits.max_total_bytes} "
                                        f"bytes or {limits.max_files} files (the limits)")
                source = tar.extractfile(member)
                if name == STAGED_SCENE:
                    xml = source.read()
                    continue
                path = folder / str(len(files))
                with path.open("wb") as out:
                    shutil.copyfileobj(source, out, _CHUNK)
                files[name] = path
    except tarfile.TarError as err:
        raise SceneRefused(f"the body is not a readable tar archive ({err})") from None
    if not xml:
        raise SceneRefused(f"the archive holds no {STAGED_SCENE} (the scene's XML, at the "
                           "top of the archive)")
    return xml, files


@asynccontextmanager
async def _parse_slot(request: Request, slots: int) -> AsyncIterator[None]:
    """One of the ``slots`` scene uploads vetted at once, or 503 with Retry-After."""
    parses: asyncio.Semaphore = request.app.state.scene_parses
    if parses.locked():
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                            f"{slots} scene uploads are being vetted, this service's limit "
                            "(NIRC_BENCH_MAX_SCENE_PARSES); send it again shortly",
                            headers={"Retry-After": str(PARSE_RETRY_AFTER_S)})
    async with parses:
        yield


def _decode(upload: SceneUpload) -> tuple[bytes, dict[str, Blob]]:
    files: dict[str, Blob] = {}
    for name, text in upload.files.items():
        try:
            files[name] = base64.b64decode(text, validate=True)
        except (binascii.Error, ValueError):
            raise _unprocessable(["files", name[:200]], "not valid base64") from None
    return upload.xml.encode("utf-8"), files


async def _json_upload(request: Request, limit: int) -> SceneUpload:
    body = await _receive(request, limit, (
        f"a JSON upload may be at most {limit} bytes (max_body_bytes); send a larger scene "
        "as a tar archive (Content-Type: application/x-tar)"))
    if nested_deeper_than(body, MAX_DEPTH):
        raise _unprocessable([], too_deep_message())
    try:
        parsed = json.loads(body)
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise _unprocessable([], "the body must be JSON: {\"xml\": ..., \"files\": "
                                 "{name: base64}}, or a tar archive") from None
    try:
        upload = SceneUpload.model_validate(parsed)
    except ValidationError as err:
        raise RequestValidationError([{"loc": ["body", *map(str, e["loc"])], "msg": e["msg"],
                                       "type": e["type"]} for e in err.errors()]) from None
    # JSON may spell a lone surrogate, which no file can hold (service/api/limits.py).
    if not is_unicode(upload.xml) or not all(map(is_unicode, upload.files)):
        raise _unprocessable([], "the XML or a file name holds a lone UTF-16 surrogate "
                                 "(such as \\ud800), which is not Unicode text")
    return upload


def _upload_bytes(xml: bytes, files: dict[str, Blob]) -> int:
    """The bytes an upload may store: its XML and its files as received."""
    return len(xml) + sum(len(blob) if isinstance(blob, bytes) else blob.stat().st_size
                          for blob in files.values())


@router.post(UPLOAD_PATH.removeprefix(router.prefix), status_code=status.HTTP_201_CREATED,
             response_model=SceneUploadOut,
             responses={200: {"model": SceneUploadOut, "description": "already stored"},
                        413: {"description": "a file or the whole scene is over the limit"},
                        415: {"description": "neither a tar archive nor JSON"},
                        503: {"description": "every upload slot is vetting a scene: send it "
                                             "again after Retry-After"},
                        507: {"description": "no room: the data folder's cap or "
                                             "free-space floor, or the API key's quota"}},
             openapi_extra={"requestBody": {"required": True, "content": {
                 "application/x-tar": {"schema": {"type": "string", "format": "binary"}},
                 "application/json": {"schema": SceneUpload.model_json_schema()}}}})
async def upload_scene(request: Request, response: Response, settings: SettingsDep,
                       store: StoreDep, caller: CallerDep) -> SceneUploadOut:
    """Upload a Mitsuba XML scene and the files it reads; answers its id
    (``upload:<digest>``), to use as the ``scene`` of jobs and sweeps."""
    limits = scene_limits()
    kind = request.headers.get("content-type", "application/json").split(";")[0].strip()
    folder = make_private_dir(settings.data_dir / "tmp")
    scratch = Path(tempfile.mkdtemp(prefix="upload-", dir=folder))
    try:
        if kind.lower() in TAR_TYPES:
            cap = limits.max_total_bytes + _TAR_OVERHEAD_PER_FILE * (limits.max_files + 1)
            with (scratch / "upload.tar").open("wb") as out:
                await _receive(request, cap, (
                    f"the request body is more than {cap} bytes; a scene and its files may "
                    f"be at most {limits.max_total_bytes} bytes in all"), out)
            read = partial(_unpack, scratch / "upload.tar", scratch, limits)
        elif kind.lower() == "application/json":
            read = partial(_decode, await _json_upload(request, settings.max_body_bytes))
        else:
            raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                                "send the scene as application/x-tar (scene.xml and its "
                                "files) or application/json")
        # The XML is held and parsed from here on: a bounded number at once.
        async with _parse_slot(request, settings.max_scene_parses):
            xml, files = await run_in_threadpool(read)
            await run_in_threadpool(check_room, store, settings, caller.id,
                                    _upload_bytes(xml, files), "scene upload")
            room = None
            if settings.max_data_bytes is not None:
                room = settings.max_data_bytes - await run_in_threadpool(data_bytes, store,
                                                                         settings)
            scene_id, staged, created = await run_in_threadpool(save_upload, xml, files,
                                                                settings, room)
            await run_in_threadpool(mark_scene_owner, settings, caller.id, staged.digest,
                                    staged.total_bytes)
        # Counted before the received files are removed.
        answer = SceneUploadOut(id=scene_id, files=len(staged.files) - 1,
                                bytes=staged.total_bytes)
    except SceneTooLarge as err:
        raise _too_large(str(err)) from None
    except SceneRefused as err:
        raise _unprocessable(["xml"], str(err)) from None
    except NoRoom as err:
        raise HTTPException(status.HTTP_507_INSUFFICIENT_STORAGE, str(err)) from None
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if not created:
        response.status_code = status.HTTP_200_OK
    return answer
