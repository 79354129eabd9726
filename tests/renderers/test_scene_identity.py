"""One XML scene is one scene: its copy staged for a service (files renamed, includes
rewritten) has the same fingerprint as the file on the user's machine."""

from __future__ import annotations

from pathlib import Path

from renderers.scenes import load_scene
from renderers.scenes.vetting import Limits, blob_bytes, vet_root_scene

INCLUDED = """<scene version="3.0.0"><shape type="obj">
  <string name="filename" value="meshes/tri.obj"/><bsdf type="diffuse"/></shape></scene>"""
ROOT = """<scene version="3.0.0">
  <default name="spp" value="16"/>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <include filename="inc.xml"/>
  <emitter type="constant"/>
</scene>"""


def _write_scene(folder: Path, triangle: str) -> Path:
    (folder / "meshes").mkdir(parents=True)
    (folder / "inc.xml").write_text(INCLUDED)
    (folder / "meshes" / "tri.obj").write_text(triangle)
    (folder / "room.xml").write_text(ROOT)
    return folder / "room.xml"


def _staged_copy(scene: Path, folder: Path) -> Path:
    """The scene as an upload stages it: scene.xml and its files under new names."""
    unlimited = Limits(max_file_bytes=1 << 40, max_total_bytes=1 << 40, max_files=1000)
    staged = vet_root_scene(str(scene), [Path(scene.anchor)], unlimited)
    assert set(staged.files) != {"room.xml", "inc.xml", "meshes/tri.obj"}
    for name, blob in staged.files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(blob_bytes(blob))
    return folder / "scene.xml"


def test_a_staged_copy_is_the_same_scene_and_content_still_counts(mi, tmp_path):
    triangle = "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n"
    scene = _write_scene(tmp_path / "mine", triangle)
    copy = _staged_copy(scene, tmp_path / "service")
    assert load_scene(str(copy), 8).fingerprint == load_scene(str(scene), 16).fingerprint
    moved = _write_scene(tmp_path / "moved", triangle.replace("0 1 0", "0 2 0"))
    assert load_scene(str(moved), 8).fingerprint != load_scene(str(scene), 8).fingerprint
