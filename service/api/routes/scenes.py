"""Uploading a Mitsuba XML scene with the files it reads (docs/service.md).

Over REST a scene is a built-in name, an uploaded scene's id, or a file under the
service's scene roots. An upload is one JSON body: the XML as text, and every file
it reads (meshes, textures, spectra, included XML) by the relative name the XML
uses, base64-encoded. The scene is vetted — it may read only its own files — and
stored content-addressed; the answer's ``id`` (``upload:<digest>``) is then the
``scene`` of a job or sweep. The same upload twice gives the same id.
"""

from __future__ import annotations

import base64
import binascii
import json

from fastapi import APIRouter, HTTPException, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from jobs.protocol.scene_store import save_upload
from renderers.scenes.vetting import SceneRefused, SceneTooLarge
from service.api.deps import SettingsDep, WriteAccess
from service.api.schemas import SceneUploadOut

router = APIRouter(prefix="/api/v1", tags=["scenes"])

#: The upload route; it reads its body under its own cap, not the service-wide one.
UPLOAD_PATH = "/api/v1/scenes"

#: JSON around the content: field names, quotes, the file names.
_BODY_OVERHEAD = 1 << 20


class SceneUpload(BaseModel):
    """The body of ``POST /api/v1/scenes``."""

    model_config = ConfigDict(extra="forbid", strict=True)

    xml: str = Field(min_length=1, description="the scene's Mitsuba XML (text)")
    files: dict[str, str] = Field(
        default_factory=dict,
        description="the files the XML reads: relative name as the XML writes it -> "
                    "base64 of the file's bytes")


def _too_large(message: str) -> HTTPException:
    return HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, message)


def _unprocessable(loc: list[str], message: str) -> HTTPException:
    return HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                         [{"loc": ["body", *loc], "msg": message, "type": "value_error"}])


async def _read_body(request: Request, limit: int, total_limit: int) -> bytes:
    """The request body, refused (413) as soon as it is longer than ``limit``: the
    JSON of a scene at the size limit (base64 makes files 4/3 as long)."""
    message = (f"the request body is more than {limit} bytes; a scene and its files may "
               f"be at most {total_limit} bytes in all")
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:
        raise _too_large(message)
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise _too_large(message)
    return bytes(body)


def _decode(upload: SceneUpload) -> tuple[bytes, dict[str, bytes]]:
    files: dict[str, bytes] = {}
    for name, text in upload.files.items():
        try:
            files[name] = base64.b64decode(text, validate=True)
        except (binascii.Error, ValueError):
            raise _unprocessable(["files", name[:200]], "not valid base64") from None
    return upload.xml.encode("utf-8"), files


@router.post(UPLOAD_PATH.removeprefix(router.prefix), status_code=status.HTTP_201_CREATED, response_model=SceneUploadOut,
             dependencies=[WriteAccess],
             responses={200: {"model": SceneUploadOut, "description": "already stored"},
                        413: {"description": "a file or the whole scene is over the limit"}},
             openapi_extra={"requestBody": {"required": True, "content": {
                 "application/json": {"schema": SceneUpload.model_json_schema()}}}})
async def upload_scene(request: Request, response: Response,
                       settings: SettingsDep) -> SceneUploadOut:
    """Upload a Mitsuba XML scene and the files it reads; answers its id
    (``upload:<digest>``), to use as the ``scene`` of jobs and sweeps."""
    limit = 2 * settings.scene_max_bytes + _BODY_OVERHEAD
    body = await _read_body(request, limit, settings.scene_max_bytes)
    try:
        upload = SceneUpload.model_validate(json.loads(body))
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise _unprocessable([], "the body must be JSON: {\"xml\": ..., \"files\": "
                                 "{name: base64}}") from None
    except ValidationError as err:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            [{"loc": ["body", *map(str, e["loc"])], "msg": e["msg"],
                              "type": e["type"]} for e in err.errors()]) from None
    xml, files = _decode(upload)
    try:
        scene_id, staged, created = await run_in_threadpool(save_upload, xml, files, settings)
    except SceneTooLarge as err:
        raise _too_large(str(err)) from None
    except SceneRefused as err:
        raise _unprocessable(["xml"], str(err)) from None
    if not created:
        response.status_code = status.HTTP_200_OK
    return SceneUploadOut(id=scene_id, files=len(staged.files) - 1, bytes=staged.total_bytes)
