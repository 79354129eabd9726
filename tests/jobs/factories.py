"""Plausible field dictionaries for references, runs, seed results and artifacts."""

from datetime import UTC, datetime
from typing import Any


def reference_fields(key: str = "ref-key-1", **overrides: Any) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "key": key,
        "scene_name": "cornell-box",
        "scene_fingerprint": "fp-cornell",
        "width": 64,
        "height": 64,
        "integrator": "path",
        "max_depth": 8,
        "settings": {"spp": 4096, "spp_per_pass": 64, "min_passes": 8},
        "spp": 4096,
        "passes": 64,
        "rel_stderr": 0.004,
        "image_path": "ab/cdef.exr",
        "variance_path": "12/3456.exr",
        "split_half": {"mrse": 1.5e-4, "flip": 0.01},
        "flip_exposures": [-3.5, 4.25],
        "render_seconds": 12.5,
        "device": {"backend": "llvm_ad_rgb", "cpu": "test cpu"},
        "versions": {"mitsuba": "3.9.1"},
    }
    fields.update(overrides)
    return fields


def run_fields(**overrides: Any) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "finished_at": datetime(2025, 1, 2, 3, 4, 5, tzinfo=UTC),
        "status": "succeeded",
        "scene_name": "cornell-box",
        "scene_fingerprint": "fp-cornell",
        "method": "pt",
        "params": {"max_depth": 8},
        "width": 64,
        "height": 64,
        "spp": 1,
        "frames": 4,
        "seeds": 2,
        "metrics": {"mrse": {"mean": 0.1, "ci": [0.09, 0.11]}, "flip": 0.2},
        "timings": {"frame": {"median_s": 0.01}, "compile_s": 1.2},
        "path_stats": {"mean_length": 2.5},
        "device": {"backend": "llvm_ad_rgb", "cpu": "test cpu"},
        "device_key": "llvm:test-cpu",
        "versions": {"mitsuba": "3.9.1", "drjit": "1.5.0"},
        "git_commit": "0123abc",
        "quality": {"finite": True, "nonfinite_pixels": 0},
    }
    fields.update(overrides)
    return fields


def seed_fields(seed: int) -> dict[str, Any]:
    return {"seed": seed, "metrics": {"mrse": 0.1 + seed}, "timings": {"frames_s": [0.01] * 4}}


def artifact_fields(kind: str, sha256: str, seed: int | None = None) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "kind": kind,
        "media_type": "image/x-exr",
        "sha256": sha256,
        "path": f"{sha256[:2]}/{sha256[2:]}.exr",
        "bytes": 1234,
    }
    if seed is not None:
        fields["seed"] = seed
    return fields
