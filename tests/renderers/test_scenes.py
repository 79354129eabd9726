"""Tests of the scene library: built-ins, XML scenes, fingerprints, features, errors.

Renders are tiny (32x32, a few spp): these check that scenes load and light
up, not what they converge to.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from renderers.backend import init_backend
from renderers.scenes import (
    LoadedScene,
    SceneError,
    builtin_names,
    describe,
    is_scene_file,
    library,
    load_scene,
)
from renderers.scenes.resolution import MAX_RESOLUTION, normalize_resolution

mi = init_backend()

BUILTINS = (
    "cornell-box",
    "cornell-glossy",
    "door",
    "corridor",
    "sky",
    "many-lights",
    "many-lights-300",
    "white-room",
)
REPO = Path(__file__).resolve().parents[2]


def render(loaded: LoadedScene, spp: int = 8) -> np.ndarray:
    integrator = mi.load_dict({"type": "path", "max_depth": 8})
    return np.array(mi.render(loaded.scene, integrator=integrator, spp=spp))


# ---- Built-in scenes ---------------------------------------------------------

def test_builtin_names_and_descriptions() -> None:
    assert builtin_names() == list(BUILTINS)
    for name in BUILTINS:
        text = describe(name)
        assert text and "\n" not in text


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_renders_something_finite(name: str) -> None:
    loaded = load_scene(name, 32)
    assert loaded.source == "builtin" and loaded.name == name
    assert loaded.resolution == (32, 32)
    assert tuple(loaded.scene.sensors()[0].film().size()) == (32, 32)
    image = render(loaded)
    assert image.shape == (32, 32, 3)
    assert np.isfinite(image).all()
    assert image.mean() > 1e-3, "scene renders black"
    # At least a tenth of the pixels receive light even at 8 spp.
    assert (image.mean(axis=2) > 0).mean() > 0.1


def test_default_and_rectangular_resolution() -> None:
    assert load_scene("cornell-box").resolution == (256, 256)
    loaded = load_scene("door", (48, 32))
    assert loaded.resolution == (48, 32)
    assert loaded.features.resolution == (48, 32)
    assert tuple(loaded.scene.sensors()[0].film().size()) == (48, 32)


def test_builtin_definitions_follow_the_conventions() -> None:
    for name in BUILTINS:
        definition = library.BUILTINS[name].build()
        # The renderer under test brings its own integrator.
        assert "integrator" not in definition
        assert all(
            not (isinstance(v, dict) and v.get("type") in ("path", "direct", "volpath"))
            for v in definition.values()
        )
        camera = definition["sensor"]
        assert camera["type"] == "perspective"
        assert camera["sampler"]["type"] == "independent"
        assert camera["film"]["type"] == "hdrfilm"
        assert camera["film"]["rfilter"] == {"type": "box"}
        assert camera["film"]["pixel_format"] == "rgb"
        # Resolution is written at load time, never part of the definition.
        assert "width" not in camera["film"] and "height" not in camera["film"]


# ---- Fingerprints ------------------------------------------------------------

def _fingerprints(resolution: int | tuple[int, int]) -> dict[str, str]:
    return {name: load_scene(name, resolution).fingerprint for name in BUILTINS}


def test_builtin_fingerprints_deterministic_distinct_resolution_free() -> None:
    first = _fingerprints(8)
    assert _fingerprints(8) == first
    assert _fingerprints((24, 16)) == first
    assert len(set(first.values())) == len(BUILTINS)
    assert all(len(f) == 16 and int(f, 16) >= 0 for f in first.values())


# ---- XML scenes ----------------------------------------------------------------

QUAD_OBJ = """\
v -1 0 -1
v 1 0 -1
v 1 0 1
v -1 0 1
f 1 3 2
f 1 4 3
"""

SCENE_XML = """\
<?xml version="1.0" encoding="utf-8"?>
<scene version="3.0.0">
    <!-- a test scene: a textured floor lit by a constant sky -->
    <default name="res" value="40"/>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world">
            <lookat origin="0, 3, 4" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="$res"/>
            <integer name="height" value="$res"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="constant"/>
    <shape type="obj">
        <string name="filename" value="floor.obj"/>
        <bsdf type="diffuse">
            <texture type="bitmap" name="reflectance">
                <string name="filename" value="checker.png"/>
            </texture>
        </bsdf>
    </shape>
    <shape type="sphere">
        <bsdf type="roughconductor"/>
    </shape>
</scene>
"""


def _write_bitmap(path: Path, seed: int) -> None:
    pixels = np.random.default_rng(seed).integers(0, 256, size=(8, 8, 3), dtype=np.uint8)
    mi.Bitmap(pixels).write(str(path))


@pytest.fixture
def xml_scene(tmp_path: Path) -> Path:
    (tmp_path / "floor.obj").write_text(QUAD_OBJ)
    _write_bitmap(tmp_path / "checker.png", seed=1)
    path = tmp_path / "scene.xml"
    path.write_text(SCENE_XML)
    return path


def test_xml_scene_loads_with_its_own_and_overridden_resolution(xml_scene: Path) -> None:
    own = load_scene(str(xml_scene))
    assert own.source == "xml" and own.name == str(xml_scene)
    assert own.resolution == (40, 40)
    overridden = load_scene(str(xml_scene), (24, 16))
    assert overridden.resolution == (24, 16)
    assert tuple(overridden.scene.sensors()[0].film().size()) == (24, 16)
    assert overridden.fingerprint == own.fingerprint
    image = render(overridden, spp=2)
    assert np.isfinite(image).all() and image.mean() > 0


def test_xml_features(xml_scene: Path) -> None:
    features = load_scene(str(xml_scene), 8).features
    assert features.has_envmap and features.has_glossy and not features.has_delta
    assert features.emitter_count == 1 and features.area_emitter_count == 0
    assert features.shape_count == 2
    assert features.bbox_min == pytest.approx([-1, -1, -1])
    assert features.bbox_max == pytest.approx([1, 1, 1])


def test_xml_fingerprint_follows_content_not_resolution(xml_scene: Path) -> None:
    base = load_scene(str(xml_scene)).fingerprint
    # The resolution default only feeds the film: not content.
    xml_scene.write_text(SCENE_XML.replace('value="40"', 'value="96"'))
    assert load_scene(str(xml_scene)).fingerprint == base
    # Comments and indentation are not content either.
    xml_scene.write_text(SCENE_XML.replace("a test scene", "edited").replace("    ", "  "))
    assert load_scene(str(xml_scene)).fingerprint == base
    xml_scene.write_text(SCENE_XML)

    # Referenced files are content.
    _write_bitmap(xml_scene.parent / "checker.png", seed=2)
    after_bitmap = load_scene(str(xml_scene)).fingerprint
    assert after_bitmap != base
    (xml_scene.parent / "floor.obj").write_text(QUAD_OBJ.replace("v -1 0 -1", "v -2 0 -1"))
    after_mesh = load_scene(str(xml_scene)).fingerprint
    assert after_mesh not in (base, after_bitmap)
    # So is the XML itself.
    xml_scene.write_text(SCENE_XML.replace('value="45"', 'value="50"'))
    assert load_scene(str(xml_scene)).fingerprint not in (base, after_bitmap, after_mesh)


def test_xml_delta_bsdf_and_directional_light(tmp_path: Path) -> None:
    path = tmp_path / "glass.xml"
    path.write_text(
        '<scene version="3.0.0"><sensor type="perspective"/>'
        '<emitter type="directional"><vector name="direction" value="0, -1, 0"/></emitter>'
        '<shape type="sphere"><bsdf type="dielectric"/></shape></scene>'
    )
    features = load_scene(str(path), 8).features
    assert features.has_delta and not features.has_glossy
    # A directional light is infinite but delta: not an environment map.
    assert not features.has_envmap and features.emitter_count == 1


@pytest.mark.parametrize(
    "film",
    [
        '<film type="hdrfilm"/>',
        '<film type="hdrfilm"><integer name="width" value="7"/></film>',
        "",
    ],
    ids=["self-closing-film", "width-only", "no-film"],
)
def test_xml_resolution_inserted_where_missing(tmp_path: Path, film: str) -> None:
    path = tmp_path / "bare.xml"
    path.write_text(
        f'<scene version="3.0.0"><sensor type="perspective">{film}</sensor>'
        '<shape type="sphere"/></scene>'
    )
    assert load_scene(str(path), (20, 12)).resolution == (20, 12)


def test_fingerprints_match_in_a_fresh_process(xml_scene: Path) -> None:
    here = {**_fingerprints(8), "xml": load_scene(str(xml_scene), 8).fingerprint}
    code = textwrap.dedent(
        f"""
        import json
        from renderers.scenes import builtin_names, load_scene
        prints = {{name: load_scene(name, 12).fingerprint for name in builtin_names()}}
        prints["xml"] = load_scene({str(xml_scene)!r}, 30).fingerprint
        print(json.dumps(prints))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1]) == here


def test_listing_scenes_does_not_load_mitsuba() -> None:
    code = (
        "import sys; from renderers.scenes import builtin_names, describe; "
        "[describe(n) for n in builtin_names()]; print('mitsuba' in sys.modules)"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"


# ---- Features and JSON -----------------------------------------------------------

def test_builtin_features() -> None:
    sky = load_scene("sky", 8).features
    assert sky.has_envmap and sky.area_emitter_count == 0
    many = load_scene("many-lights", 8).features
    assert many.area_emitter_count == 32 and many.emitter_count == 32 and many.has_many_lights
    assert not many.has_envmap
    glossy = load_scene("cornell-glossy", 8).features
    assert glossy.has_glossy and not glossy.has_delta
    box = load_scene("cornell-box", 8).features
    assert not box.has_glossy and not box.has_envmap and not box.has_delta
    assert box.emitter_count == box.area_emitter_count == 1 and not box.has_many_lights
    assert box.bbox_min == pytest.approx([-1, -1.01, -1], abs=1e-4)
    assert box.bbox_max == pytest.approx([1, 1, 1], abs=1e-4)


def test_loaded_scene_to_json_roundtrips() -> None:
    data = load_scene("white-room", 16).to_json()
    assert json.loads(json.dumps(data)) == data
    assert set(data) == {"name", "source", "fingerprint", "features", "resolution", "description"}
    assert data["resolution"] == [16, 16] and data["features"]["resolution"] == [16, 16]


# ---- Errors a user can make -----------------------------------------------------

def _error(name: str, resolution: object = None) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(name, resolution)  # type: ignore[arg-type]
    message = str(info.value)
    assert "\n" not in message and "Traceback" not in message
    return message


def test_unknown_name_lists_builtins() -> None:
    message = _error("cornel-box")
    assert "cornel-box" in message and all(name in message for name in BUILTINS)
    assert issubclass(SceneError, ValueError)


def test_missing_xml_file(tmp_path: Path) -> None:
    message = _error(str(tmp_path / "nope.xml"))
    assert "nope.xml" in message and "not found" in message


@pytest.mark.parametrize("name", ["~no-such-user-x9/scene.xml", "~0", "a\x00b.xml",
                                  "x" * 5000 + ".xml"])
def test_names_no_file_can_have_are_not_found(name: str) -> None:
    # An unknown user's home (~user), a NUL byte, a name too long: not found, no crash.
    assert not is_scene_file(name)
    assert "scene" in _error(name)


def test_malformed_xml_says_where(tmp_path: Path) -> None:
    path = tmp_path / "broken.xml"
    path.write_text('<scene version="3.0.0">\n  <shape type="sphere">\n</scene>\n')
    message = _error(str(path))
    assert "broken.xml" in message and "malformed XML" in message and "line 3" in message


def test_not_a_scene(tmp_path: Path) -> None:
    path = tmp_path / "bsdf.xml"
    path.write_text('<bsdf version="3.0.0" type="diffuse"/>')
    assert "<bsdf>" in _error(str(path))


def test_mitsuba_errors_name_file_and_line(tmp_path: Path) -> None:
    resolver_size = len(mi.file_resolver())
    path = tmp_path / "plugin.xml"
    path.write_text(
        '<scene version="3.0.0">\n'
        '    <sensor type="perspective"><film type="hdrfilm"/></sensor>\n'
        '    <shape type="teapot-of-doom"/>\n'
        "</scene>\n"
    )
    # With a resolution override the lines of the user's file still hold.
    message = _error(str(path), 16)
    assert "plugin.xml" in message and "teapot-of-doom" in message and "line 3" in message
    assert len(mi.file_resolver()) == resolver_size  # the folder was not left behind


def test_missing_referenced_file(xml_scene: Path) -> None:
    (xml_scene.parent / "floor.obj").unlink()
    message = _error(str(xml_scene))
    assert "scene.xml" in message and "floor.obj" in message


@pytest.mark.parametrize("resolution", [0, -1, MAX_RESOLUTION + 1, (0, 4), (4,), "64", True, 2.5])
def test_bad_resolution(resolution: object) -> None:
    assert "resolution" in _error("cornell-box", resolution)


@given(st.integers(min_value=-10, max_value=MAX_RESOLUTION + 10))
def test_resolution_range(side: int) -> None:
    if 1 <= side <= MAX_RESOLUTION:
        assert normalize_resolution(side) == (side, side)
        assert normalize_resolution((side, 1)) == (side, 1)
    else:
        with pytest.raises(SceneError):
            normalize_resolution(side)
