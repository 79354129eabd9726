"""The variant a process that has chosen none loads scenes' features with."""

from __future__ import annotations

import pytest

from jobs.protocol import scene_store
from renderers.backend import BackendError


def _machine(monkeypatch: pytest.MonkeyPatch, *, llvm: bool, default: str) -> list[str]:
    """A machine with (or without) a usable libLLVM whose default variant is ``default``;
    returns the list the chosen variants are appended to."""
    chosen: list[str] = []

    def init_backend(variant: str) -> None:
        if variant.startswith("llvm") and not llvm:
            raise BackendError("no libLLVM >= 16 found")
        chosen.append(variant)

    monkeypatch.setattr(scene_store, "init_backend", init_backend)
    monkeypatch.setattr(scene_store, "default_variant", lambda: default)
    return chosen


def test_features_use_the_cpu_variant_where_libllvm_is_usable(monkeypatch):
    chosen = _machine(monkeypatch, llvm=True, default="cuda_ad_rgb")
    scene_store.features_backend()
    assert chosen == ["llvm_ad_rgb"]  # no GPU context for features


def test_a_gpu_machine_without_libllvm_loads_features_on_the_gpu(monkeypatch):
    chosen = _machine(monkeypatch, llvm=False, default="cuda_ad_rgb")
    scene_store.features_backend()
    assert chosen == ["cuda_ad_rgb"]


def test_a_machine_with_neither_names_the_missing_libllvm(monkeypatch):
    chosen = _machine(monkeypatch, llvm=False, default="llvm_ad_rgb")
    with pytest.raises(BackendError, match="libLLVM"):
        scene_store.features_backend()
    assert chosen == []
