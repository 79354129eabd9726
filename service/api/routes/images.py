"""EXR images a user uploads to compare a run's images against (tev's "reference").

``POST /api/v1/images?run=ID`` stores the body, an OpenEXR file (``image/x-exr`` or
``application/octet-stream``), for the API key that sent it; it is a write, so it needs
the key in the ``X-API-Key`` header as every write does (the dashboard's login cookie
does not authorize it). Bounds, all existing limits of the service:

* the body is at most ``max_body_bytes`` (the service-wide body limit, 413 beyond);
* the image must have the resolution of run ``ID``, read from the file's header before
  any pixel is decoded, so a small compressed file cannot make the service decode a
  large image (422 otherwise, naming both sizes);
* a key keeps its latest :data:`IMAGES_PER_KEY` uploads: a new one removes its oldest;
* a new image that would take the data folder past ``max_data_bytes``, its key past its
  quota, or that comes while the disk is under its free-space floor is refused (507,
  service/api/quota.py); a key's images count in its quota;
  uploaded images count in the data folder's size (jobs.execution.work.data_bytes), so
  jobs and scene uploads are refused for them as for any stored file;
* they are kept under their run (``<key id>/<run id>/<sha256>.exr``): ``nirc-bench gc``
  removes them with their run's artifacts and once older than ``gc_keep_days`` since
  their last upload (jobs/record/gc.py);
* a key's file is stored once, whatever the runs it is uploaded for: the same bytes for
  another run are a hard link to the key's stored copy (content-addressed by their
  digest within the key's folder), counted once in the key's usage and the data
  folder's size.

A file that is not OpenEXR, is damaged, has no R, G, B channels or holds a value that is
not finite is a 422 saying which. The answer's ``id`` is the SHA-256 of the file's bytes
(the same file twice: the same id, 200 instead of 201). Its pixels and the run's error
map against it are read as the run's layers are (service/api/routes/pixels.py).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Annotated

import numpy as np
import OpenEXR
from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from jobs.execution.work import data_bytes
from jobs.record.artifacts import make_private_dir
from jobs.record.config import Settings
from jobs.record.store import Store
from metrics.imageio import ImageReadError, read_exr
from service.api.deps import CallerDep, SettingsDep, StoreDep
from service.api.quota import check_room
from service.api.unprocessable import unprocessable

router = APIRouter(prefix="/api/v1", tags=["images"])

#: Uploaded images a key keeps; a further upload removes its oldest.
IMAGES_PER_KEY = 8
EXR_TYPES = ("image/x-exr", "application/octet-stream")
#: The id of an uploaded image: the SHA-256 of its file, in hex.
IMAGE_ID_PATTERN = r"^[0-9a-f]{64}$"


class ImageUploadOut(BaseModel):
    """An uploaded image, as stored."""

    id: str = Field(description="the SHA-256 of the file (hex): GET /api/v1/images/{id}")
    width: int
    height: int
    bytes: int = Field(description="the file's size")
    kept: int = Field(description=f"uploads this key keeps (at most {IMAGES_PER_KEY})")


def _refused(message: str) -> HTTPException:
    return unprocessable(message, ("body",))


def _checked(path: Path, resolution: tuple[int, int]) -> np.ndarray:
    """The pixels of the uploaded file at ``path`` if it is an RGB OpenEXR image of
    ``resolution`` (width, height) with finite values; else a 422 saying what is wrong."""
    if not OpenEXR.isOpenExrFile(str(path)):
        raise _refused("the body is not an OpenEXR file (send the .exr file's bytes)")
    try:
        (x0, y0), (x1, y1) = OpenEXR.File(str(path), header_only=True).header()["dataWindow"]
    except (RuntimeError, ValueError, OSError, KeyError) as err:
        raise _refused(f"the EXR file's header cannot be read ({err})") from None
    size = (int(x1) - int(x0) + 1, int(y1) - int(y0) + 1)
    if size != resolution:
        raise _refused(f"the image is {size[0]}x{size[1]} pixels; the run's images are "
                       f"{resolution[0]}x{resolution[1]}: upload an image of that size")
    try:
        image = read_exr(path)
    except ImageReadError as err:
        raise _refused(str(err).replace(str(path), "the uploaded EXR file")) from None
    if image.shape[-1] != 3:
        raise _refused("the image has only a Y channel; the run's images are RGB "
                       "(R, G, B channels)")
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise _refused(f"the image holds {bad} values that are not finite (NaN or "
                       "infinite); an error map against it would be undefined there")
    return image


def _store(body: bytes, key_id: int, run_id: int, resolution: tuple[int, int], store: Store,
           settings: Settings) -> tuple[ImageUploadOut, bool]:
    """Check and keep ``body`` for key ``key_id`` under run ``run_id``; (the stored
    image, whether it is new)."""
    key_folder = make_private_dir(settings.uploaded_images_dir / str(key_id))
    folder = key_folder / str(run_id)    # made once the image is kept: a refusal leaves none
    image_id = hashlib.sha256(body).hexdigest()
    target = folder / f"{image_id}.exr"
    stored = _stored_copy(key_folder, image_id)
    created = stored is None or not _linked(stored, make_private_dir(folder) / target.name)
    if created:
        check_room(store, settings, key_id, len(body), "image upload")
        if settings.max_data_bytes is not None:
            if data_bytes(store, settings) + len(body) > settings.max_data_bytes:
                raise HTTPException(status.HTTP_507_INSUFFICIENT_STORAGE,
                                    f"storing {len(body)} bytes would take the data folder "
                                    f"past its limit of {settings.max_data_bytes} bytes "
                                    "(max_data_bytes)")
        scratch = key_folder / f".{image_id}.{os.getpid()}.part"
        try:
            scratch.write_bytes(body)
            os.chmod(scratch, 0o600)
            _checked(scratch, resolution)
            make_private_dir(folder)
            scratch.replace(target)
        finally:
            scratch.unlink(missing_ok=True)
    os.utime(target)   # the newest upload of this key, whether new or repeated
    kept = sorted(key_folder.rglob("*.exr"), key=lambda p: p.stat().st_mtime_ns, reverse=True)
    for old in kept[IMAGES_PER_KEY:]:
        old.unlink(missing_ok=True)
    return ImageUploadOut(id=image_id, width=resolution[0], height=resolution[1],
                          bytes=len(body), kept=min(len(kept), IMAGES_PER_KEY)), created


def _stored_copy(key_folder: Path, image_id: str) -> Path | None:
    """The key's stored file of ``image_id`` (under any of its runs), if it keeps one."""
    return next(iter(sorted(key_folder.glob(f"*/{image_id}.exr"))), None)


def _linked(stored: Path, target: Path) -> bool:
    """Whether ``target`` now names the bytes of ``stored`` (a hard link: one file on
    disk); False when ``stored`` went meanwhile (a concurrent upload removed it)."""
    if stored == target:
        return True
    try:
        os.link(stored, target)
    except FileExistsError:
        return True         # a concurrent upload of the same bytes for the same run
    except FileNotFoundError:
        return False
    return True


def uploaded_image(settings: Settings, image_id: str) -> np.ndarray:
    """The pixels of uploaded image ``image_id`` (any key's); 404 when none is kept."""
    found = next(iter(sorted(settings.uploaded_images_dir.rglob(f"{image_id}.exr"))), None)
    if found is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no uploaded image {image_id} (each key keeps its latest "
                            f"{IMAGES_PER_KEY} uploads: upload it again)")
    try:
        return read_exr(found)
    except ImageReadError:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"uploaded image {image_id} is damaged or gone") from None


@router.post("/images", status_code=status.HTTP_201_CREATED, response_model=ImageUploadOut,
             responses={200: {"model": ImageUploadOut, "description": "already stored"},
                        404: {"description": "no such run"},
                        413: {"description": "the file is over max_body_bytes"},
                        415: {"description": "not sent as an EXR file"},
                        422: {"description": "not a readable RGB EXR of the run's size"},
                        507: {"description": "no room: the data folder's cap or "
                                             "free-space floor, or the API key's quota"}},
             openapi_extra={"requestBody": {"required": True, "content": {
                 "image/x-exr": {"schema": {"type": "string", "format": "binary"}}}}})
async def upload_image(request: Request, response: Response, caller: CallerDep,
                       store: StoreDep, settings: SettingsDep,
                       run: Annotated[int, Query(ge=1, le=2**31 - 1,
                                                 description="the run whose images it is "
                                                             "compared with (its size must "
                                                             "match)")]) -> ImageUploadOut:
    """Upload an OpenEXR image to compare run ``run``'s images against (module
    docstring): the error map of ``GET /api/v1/runs/{run}/pixels/error?against={id}``."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind not in EXR_TYPES:
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                            "send the EXR file's bytes as the body, with Content-Type "
                            "image/x-exr")
    stored = await run_in_threadpool(store.get_run, run)
    if stored is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no run {run}")
    body = await request.body()
    if not body:
        raise _refused("the body is empty: send the EXR file's bytes")
    answer, created = await run_in_threadpool(_store, body, caller.id, run,
                                              (stored.width, stored.height),
                                              store, settings)
    if not created:
        response.status_code = status.HTTP_200_OK
    return answer
