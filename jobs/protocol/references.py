"""Converged references, content-addressed and reused.

A reference is identified by what determines its pixels: the scene fingerprint,
the resolution and the reference settings (integrator, max depth, spp, pass
size, stopping rule) and the versions of the reference integrator and of the
metric definitions (its split-half floor is a metric). That key names its files
and its database row; asking for an existing reference loads it instead of
rendering it again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jobs.protocol.provenance import library_versions
from jobs.protocol.versions import reference_estimator_version
from jobs.record.store import DuplicateKeyError, Store
from metrics import METRIC_VERSION
from metrics.flip import hdr_exposures
from metrics.imageio import ImageReadError, read_exr, write_exr
from renderers.backend import device_info
from renderers.reference import ReferenceSettings, render_reference
from renderers.seeding import digest


@dataclass
class LoadedReference:
    """A reference ready for metrics: its row id, pixels, variance and FLIP exposures."""

    id: int
    key: str
    mean: np.ndarray
    variance: np.ndarray
    spp: int
    flip_exposures: tuple[float, float]
    split_half: dict[str, float]
    image_path: Path
    rendered_now: bool


def reference_key(scene: Any, settings: ReferenceSettings) -> str:
    return digest("reference", scene.fingerprint, list(scene.resolution), settings.to_json(),
                  reference_estimator_version(settings.integrator), METRIC_VERSION, length=32)


def get_or_render_reference(
    store: Store,
    references_dir: Path,
    scene: Any,
    settings: ReferenceSettings,
    progress: Callable[[int, int], None] | None = None,
) -> LoadedReference:
    """Load the reference for (scene, settings), rendering and storing it if missing."""
    key = reference_key(scene, settings)
    row = store.find_reference(key)
    if row is not None:
        try:
            return _load(row, references_dir)
        except ImageReadError:
            # The files were deleted or damaged: render again and replace the row.
            store.delete_reference(row.id)

    image = render_reference(scene.scene, settings, seed_parts=(scene.fingerprint, key),
                             progress=progress)
    references_dir.mkdir(parents=True, exist_ok=True)
    image_name, variance_name = f"{key}.exr", f"{key}.variance.exr"
    write_exr(references_dir / image_name, image.mean)
    write_exr(references_dir / variance_name, image.variance)
    exposures = hdr_exposures(image.mean)
    try:
        row = store.add_reference(
            key=key, settings=settings.to_json(), scene_name=scene.name,
            scene_fingerprint=scene.fingerprint, width=scene.resolution[0],
            height=scene.resolution[1], integrator=settings.integrator,
            max_depth=settings.max_depth, spp=image.spp, passes=image.passes,
            rel_stderr=image.rel_stderr, image_path=image_name, variance_path=variance_name,
            split_half=image.split_half, flip_exposures=list(exposures),
            render_seconds=image.seconds, device=device_info(), versions=library_versions(),
            estimator_version=reference_estimator_version(settings.integrator),
            metric_version=METRIC_VERSION)
    except DuplicateKeyError as err:
        # Another job rendered the same reference meanwhile; the pixels are equal
        # (same key, same seeds), so keep the stored row.
        row = err.existing
    return LoadedReference(
        id=row.id, key=key, mean=image.mean, variance=image.variance, spp=image.spp,
        flip_exposures=exposures, split_half=image.split_half,
        image_path=references_dir / image_name, rendered_now=True)


def stored_reference(store: Store, references_dir: Path, reference_id: int) -> LoadedReference:
    """The stored reference ``reference_id`` (e.g. a run's), read from its files."""
    row = store.get_reference(reference_id)
    if row is None:
        raise ImageReadError(f"reference {reference_id} is not stored")
    return _load(row, references_dir)


def _load(row: Any, references_dir: Path) -> LoadedReference:
    """Read a stored reference; its file paths are relative to ``references_dir``."""
    return LoadedReference(
        id=row.id, key=row.key, mean=read_exr(references_dir / row.image_path),
        variance=read_exr(references_dir / row.variance_path), spp=row.spp,
        flip_exposures=tuple(row.flip_exposures), split_half=row.split_half,
        image_path=references_dir / row.image_path, rendered_now=False)
