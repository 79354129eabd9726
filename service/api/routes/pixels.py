"""A run's images as float values for the dashboard's comparison view.

``GET /api/v1/runs/{id}/pixels/{layer}`` answers the raw pixels, little-endian float32,
row-major, top row first, channels interleaved, with their shape and what they are in
headers (``X-Width``, ``X-Height``, ``X-Channels``, ``X-Quantity``): the page tone-maps
or false-colours them itself, so its exposure and its pixel readout see true HDR values.

Layers: ``reference`` (the converged reference), ``image`` (the seed's accumulated
image), ``error`` (the seed's relative squared error (X-R)²/(R²+eps), averaged over
channels: the MRSE map, computed on request), ``bias`` and ``variance`` (the run's
per-pixel relative bias and variance over its seeds, stored by runs of 2+ seeds;
metrics/pixel_maps.py). ``error?against=ID`` is the seed's error map against an image
the user uploaded (service/api/routes/images.py) instead of the reference, and
``GET /api/v1/images/{id}`` that image's pixels.
"""

from __future__ import annotations

import pathlib
from enum import StrEnum
from typing import Annotated

import numpy as np
from fastapi import APIRouter, HTTPException, Path, Query, Response, status

from jobs.record.artifacts import RELATIVE_BIAS_MAP, RELATIVE_VARIANCE_MAP, ArtifactStore
from metrics.errors import relative_squared_error_map
from metrics.imageio import ImageReadError, read_exr
from service.api.deps import RowId, SettingsDep, StoreDep
from service.api.routes.images import IMAGE_ID_PATTERN, uploaded_image
from service.api.unprocessable import unprocessable

router = APIRouter(prefix="/api/v1", tags=["results"])


class Layer(StrEnum):
    reference = "reference"
    image = "image"
    error = "error"
    bias = "bias"
    variance = "variance"


#: What each layer's values are (the X-Quantity header, Latin-1 as headers are; the page
#: names the colour bar so).
QUANTITY = {
    Layer.reference: "radiance (linear RGB)",
    Layer.image: "radiance (linear RGB)",
    Layer.error: "relative squared error (X-R)^2/(R^2+eps), mean of RGB",
    Layer.bias: "relative bias (M-R)/sqrt(R^2+eps) over the seeds",
    Layer.variance: "relative variance S^2/(R^2+eps) over the seeds",
}
UPLOADED = "radiance (linear RGB) of the uploaded image"
AGAINST_UPLOADED = "relative squared error (X-U)^2/(U^2+eps) against the uploaded image U, mean of RGB"
MAP_KINDS = {Layer.bias: RELATIVE_BIAS_MAP, Layer.variance: RELATIVE_VARIANCE_MAP}


def _missing(what: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, f"no {what}")


def _read(path: pathlib.Path, what: str) -> np.ndarray:
    try:
        return read_exr(path)
    except (ImageReadError, OSError):
        raise _missing(f"{what} (its file is damaged or gone)") from None


def _pixels(image: np.ndarray, quantity: str) -> Response:
    if image.ndim == 2:
        image = image[..., None]
    height, width, channels = image.shape
    return Response(np.ascontiguousarray(image, dtype="<f4").tobytes(),
                    media_type="application/octet-stream",
                    headers={"X-Width": str(width), "X-Height": str(height),
                             "X-Channels": str(channels),
                             "X-Quantity": quantity,
                             "Cache-Control": "private, max-age=3600"})


@router.get("/runs/{run_id}/pixels/{layer}", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}}}})
def run_pixels(run_id: RowId, layer: Layer, store: StoreDep, settings: SettingsDep,
               seed: Annotated[int | None, Query(ge=0, le=2**31 - 1,
                                                 description="the seed of ``image`` and "
                                                             "``error`` (default: the "
                                                             "run's first)")] = None,
               against: Annotated[str | None, Query(
                   pattern=IMAGE_ID_PATTERN,
                   description="``error`` only: the id of an uploaded image to measure "
                               "the error against, instead of the reference")] = None
               ) -> Response:
    """A layer of a run as little-endian float32 values (module docstring)."""
    if against is not None and layer is not Layer.error:
        raise unprocessable("against applies to the error layer only", ("query", "against"))
    run = store.get_run(run_id)
    if run is None:
        raise _missing(f"run {run_id}")
    artifacts = ArtifactStore(settings.artifacts_dir)
    if layer in MAP_KINDS:
        found = next((a for a in run.artifacts if a.kind == MAP_KINDS[layer]), None)
        if found is None:
            raise _missing(f"{layer} map of run {run_id}: runs of 2 or more seeds store it "
                           "(runs stored before the maps existed have none)")
        return _pixels(_read(artifacts.path_of(found.path), f"{layer} map"), QUANTITY[layer])
    if run.reference is None:
        raise _missing(f"reference of run {run_id}")
    ref = _read(settings.references_dir / run.reference.image_path,
                f"reference of run {run_id}")
    if layer is Layer.reference:
        return _pixels(ref, QUANTITY[layer])
    seeds = {s.seed: s for s in run.seed_results}
    chosen = min(seeds) if seed is None else seed
    if chosen not in seeds:
        raise _missing(f"seed {seed} in run {run_id} (its seeds: "
                       f"{', '.join(map(str, sorted(seeds)))})")
    stored = next((a for a in seeds[chosen].artifacts if a.kind == "image"), None)
    if stored is None:
        raise _missing(f"image of seed {chosen} of run {run_id} (removed by gc)")
    image = _read(artifacts.path_of(stored.path), f"image of seed {chosen}")
    if layer is Layer.image:
        return _pixels(image, QUANTITY[layer])
    eps = float((run.params.get("spec") or {}).get("eps", 0.01))
    if against is None:
        return _pixels(relative_squared_error_map(image, ref, eps), QUANTITY[layer])
    uploaded = uploaded_image(settings, against)
    if uploaded.shape != image.shape:
        raise unprocessable(f"uploaded image {against} is {uploaded.shape[1]}x"
                            f"{uploaded.shape[0]} pixels, run {run_id}'s images "
                            f"{image.shape[1]}x{image.shape[0]}", ("query", "against"))
    return _pixels(relative_squared_error_map(image, uploaded, eps), AGAINST_UPLOADED)


@router.get("/images/{image_id}", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}}}})
def image_pixels(image_id: Annotated[str, Path(pattern=IMAGE_ID_PATTERN)],
                 settings: SettingsDep) -> Response:
    """An uploaded image's pixels (POST /api/v1/images), as a run's layers are answered."""
    return _pixels(uploaded_image(settings, image_id), UPLOADED)
