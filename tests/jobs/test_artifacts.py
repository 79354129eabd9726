"""Content-addressed artifact files: dedupe, atomic writes, safe paths."""

import hashlib
import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jobs.record.artifacts import ArtifactStore


def all_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file())


def test_put_bytes_layout(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    data = b"exr bytes"
    sha256, relpath = store.put_bytes(data, ".exr")
    assert sha256 == hashlib.sha256(data).hexdigest()
    assert relpath == f"{sha256[:2]}/{sha256[2:]}.exr"
    assert store.path_of(relpath) == tmp_path / sha256[:2] / f"{sha256[2:]}.exr"
    assert store.path_of(relpath).read_bytes() == data
    assert store.put_bytes(data, "exr").relpath == relpath  # dot optional


def test_same_content_is_written_once(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    first = store.put_bytes(b"same", ".png")
    path = store.path_of(first.relpath)
    before = path.stat().st_mtime_ns
    os.utime(path, ns=(before - 10**9, before - 10**9))  # so a rewrite would show
    assert store.put_bytes(b"same", ".png") == first
    assert path.stat().st_mtime_ns == before - 10**9
    assert all_files(tmp_path) == [path]


def test_put_file(tmp_path: Path) -> None:
    source = tmp_path / "render.exr"
    source.write_bytes(b"\x00" * 3_000_000)
    store = ArtifactStore(tmp_path / "artifacts")
    sha256, relpath = store.put_file(source)
    assert relpath.endswith(".exr") and sha256 == hashlib.sha256(source.read_bytes()).hexdigest()
    assert store.put_bytes(source.read_bytes(), ".exr").relpath == relpath
    assert store.put_file(source, ".bin").relpath.endswith(".bin")
    assert len(all_files(tmp_path / "artifacts")) == 2


def test_failed_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = ArtifactStore(tmp_path)

    def crash(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="disk full"):
        store.put_bytes(b"partial", ".exr")
    assert all_files(tmp_path) == []


def test_truncated_file_is_replaced(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    sha256, relpath = store.put_bytes(b"full content", ".exr")
    store.path_of(relpath).write_bytes(b"full")
    store.put_bytes(b"full content", ".exr")
    assert store.path_of(relpath).read_bytes() == b"full content"


@pytest.mark.parametrize("relpath", ["/etc/passwd", "../outside", "ab/../../x", ""])
def test_path_of_stays_inside_root(tmp_path: Path, relpath: str) -> None:
    with pytest.raises(ValueError):
        ArtifactStore(tmp_path).path_of(relpath)


@pytest.mark.parametrize("suffix", ["/x", "..", "a/b"])
def test_bad_suffix(tmp_path: Path, suffix: str) -> None:
    with pytest.raises(ValueError):
        ArtifactStore(tmp_path).put_bytes(b"x", suffix)


@settings(max_examples=30, deadline=None)
@given(blobs=st.lists(st.binary(max_size=64), max_size=8))
def test_no_temp_files_and_one_file_per_content(tmp_path_factory: pytest.TempPathFactory,
                                                blobs: list[bytes]) -> None:
    root = tmp_path_factory.mktemp("artifacts")
    store = ArtifactStore(root)
    stored = [store.put_bytes(blob, ".bin") for blob in blobs]
    for blob, (_, relpath) in zip(blobs, stored, strict=True):
        assert store.path_of(relpath).read_bytes() == blob
    assert len(all_files(root)) == len(set(blobs))
    assert not any(p.name.startswith(".tmp-") for p in all_files(root))
