"""A run's images as float values for the dashboard's comparison view.

``GET /api/v1/runs/{id}/pixels/{layer}`` answers the raw pixels, little-endian float32,
row-major, top row first, channels interleaved, with their shape and what they are in
headers (``X-Width``, ``X-Height``, ``X-Channels``, ``X-Quantity``): the page tone-maps
or false-colours them itself, so its exposure and its pixel readout see true HDR values.

Layers: ``reference`` (the converged reference), ``image`` (the seed's accumulated
image), ``error`` (the seed's relative squared error (X-R)²/(R²+eps), averaged over
channels: the MRSE map, computed on request), ``bias`` and ``variance`` (the run's
per-pixel relative bias and variance over its seeds, stored by runs of 2+ seeds;
metrics/pixel_maps.py).
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Response, status

from jobs.record.artifacts import RELATIVE_BIAS_MAP, RELATIVE_VARIANCE_MAP, ArtifactStore
from metrics.errors import relative_squared_error_map
from metrics.imageio import ImageReadError, read_exr
from service.api.deps import RowId, SettingsDep, StoreDep

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
MAP_KINDS = {Layer.bias: RELATIVE_BIAS_MAP, Layer.variance: RELATIVE_VARIANCE_MAP}


def _missing(what: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, f"no {what}")


def _read(path: Path, what: str) -> np.ndarray:
    try:
        return read_exr(path)
    except (ImageReadError, OSError):
        raise _missing(f"{what} (its file is damaged or gone)") from None


def _pixels(image: np.ndarray, layer: Layer) -> Response:
    if image.ndim == 2:
        image = image[..., None]
    height, width, channels = image.shape
    return Response(np.ascontiguousarray(image, dtype="<f4").tobytes(),
                    media_type="application/octet-stream",
                    headers={"X-Width": str(width), "X-Height": str(height),
                             "X-Channels": str(channels),
                             "X-Quantity": QUANTITY[layer],
                             "Cache-Control": "private, max-age=3600"})


@router.get("/runs/{run_id}/pixels/{layer}", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}}}})
def run_pixels(run_id: RowId, layer: Layer, store: StoreDep, settings: SettingsDep,
               seed: Annotated[int | None, Query(ge=0, le=2**31 - 1,
                                                 description="the seed of ``image`` and "
                                                             "``error`` (default: the "
                                                             "run's first)")] = None
               ) -> Response:
    """A layer of a run as little-endian float32 values (module docstring)."""
    run = store.get_run(run_id)
    if run is None:
        raise _missing(f"run {run_id}")
    artifacts = ArtifactStore(settings.artifacts_dir)
    if layer in MAP_KINDS:
        found = next((a for a in run.artifacts if a.kind == MAP_KINDS[layer]), None)
        if found is None:
            raise _missing(f"{layer} map of run {run_id}: runs of 2 or more seeds store it "
                           "(runs stored before the maps existed have none)")
        return _pixels(_read(artifacts.path_of(found.path), f"{layer} map"), layer)
    if run.reference is None:
        raise _missing(f"reference of run {run_id}")
    ref = _read(settings.references_dir / run.reference.image_path,
                f"reference of run {run_id}")
    if layer is Layer.reference:
        return _pixels(ref, layer)
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
        return _pixels(image, layer)
    eps = float((run.params.get("spec") or {}).get("eps", 0.01))
    return _pixels(relative_squared_error_map(image, ref, eps), layer)
