"""The settings a run replaces are read from the scene file and from the files it
includes, as Mitsuba merges them into the scene; the including file's own win."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from renderers.scenes.xml_settings import xml_settings

SENSOR = """<scene version="3.0.0"><default name="spp" value="64"/>
  <sensor type="perspective">
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film>
  </sensor></scene>"""
INTEGRATOR = """<scene version="3.0.0"><integrator type="volpath">
  <integer name="max_depth" value="7"/></integrator>
  <include filename="main.xml"/></scene>"""


def _settings(folder: Path, text: str) -> dict:
    path = folder / "main.xml"
    path.write_text(text)
    return xml_settings(ET.fromstring(text), folder, frozenset({path.resolve()}))


def test_included_files_are_read_and_the_including_file_wins(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "camera.xml").write_text(SENSOR)
    (tmp_path / "parts" / "integrator.xml").write_text(INTEGRATOR)
    found = _settings(tmp_path, """<scene version="3.0.0">
      <integrator type="path"/>
      <include filename="parts/camera.xml"/><include filename="parts/integrator.xml"/>
    </scene>""")
    # The camera's film and spp come from its file (its own default resolved there);
    # the integrator is the including file's, the included max_depth still counts.
    assert found == {"film": [32, 24], "spp": 64, "integrator": "path", "max_depth": 7}


def test_a_missing_include_or_a_cycle_is_left_to_the_scene_load(tmp_path):
    (tmp_path / "loop.xml").write_text(INTEGRATOR.replace("main.xml", "loop.xml"))
    found = _settings(tmp_path, """<scene version="3.0.0">
      <include filename="absent.xml"/><include filename="loop.xml"/></scene>""")
    assert found == {"integrator": "volpath", "max_depth": 7}


def test_without_a_folder_only_the_file_itself_is_read(tmp_path):
    (tmp_path / "camera.xml").write_text(SENSOR)
    root = ET.fromstring('<scene version="3.0.0"><include filename="camera.xml"/></scene>')
    assert xml_settings(root) == {}


def test_defaults_are_substituted_in_the_integrator_type_as_mitsuba_does():
    """'$integrator' is reported as the value its <default> gives (what the file renders
    with), not as written; a name without a default stays as written."""
    text = """<scene version="3.0.0"><default name="integrator" value="path"/>
      <default name="depth" value="6"/>
      <integrator type="$integrator"><integer name="max_depth" value="$depth"/></integrator>
    </scene>"""
    assert xml_settings(ET.fromstring(text)) == {"integrator": "path", "max_depth": 6}
    unresolved = text.replace('<default name="integrator" value="path"/>', "")
    assert xml_settings(ET.fromstring(unresolved))["integrator"] == "$integrator"
