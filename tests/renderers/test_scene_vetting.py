"""Vetting of XML scenes named over REST (renderers/scenes/vetting.py): every file a
scene reads, through nested includes and ``$`` defaults, must lie under the scene
roots (or in the upload); the staged copy names only its own files; one message for
"missing" and "not allowed"."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from renderers.scenes import load_scene
from renderers.scenes.vetting import (
    STAGED_SCENE,
    Limits,
    SceneRefused,
    SceneTooLarge,
    vet_root_scene,
    vet_upload,
)

LIMITS = Limits(max_file_bytes=1 << 20, max_total_bytes=4 << 20)
MISSING = "not available"
SENSOR = ('<sensor type="perspective"><transform name="to_world"><lookat origin="0,0,4" '
          'target="0,0,0" up="0,1,0"/></transform><film type="hdrfilm">'
          '<integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>')
QUAD = b"v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n"


def scene(body: str, defaults: str = "") -> str:
    return f'<scene version="3.0.0">{defaults}{body}<emitter type="constant"/>{SENSOR}</scene>'


def write(path: Path, text: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(text, str):
        text = text.encode()
    path.write_bytes(text)
    return path


@pytest.fixture
def roots(tmp_path):
    """A scene root with a full scene: nested includes (each relative to its own
    folder), a mesh named through a ``$`` default, a spectrum file; and a folder
    outside the root holding a "secret"."""
    root = tmp_path / "root"
    write(root / "scene.xml", scene(
        '<include filename="parts/parts.xml"/>'
        '<shape type="obj"><string name="filename" value="$mesh"/><bsdf type="diffuse">'
        '<spectrum name="reflectance" filename="parts/refl.spd"/></bsdf></shape>',
        defaults='<default name="mesh" value="parts/quad.obj"/>'))
    write(root / "parts" / "parts.xml", '<scene version="3.0.0"><include filename="more.xml"/>'
                                         '</scene>')
    write(root / "parts" / "more.xml", '<scene version="3.0.0"><shape type="sphere">'
                                        '<float name="radius" value="0.5"/></shape></scene>')
    write(root / "parts" / "quad.obj", QUAD)
    write(root / "parts" / "refl.spd", "400 0.5\n700 0.5\n")
    write(tmp_path / "outside" / "secret.spd", "400 0.123456789\n")
    write(tmp_path / "outside" / "scene.xml", scene('<shape type="sphere"/>'))
    return root, tmp_path / "outside"


def vet(path: Path | str, root: Path) -> object:
    return vet_root_scene(str(path), [root], LIMITS, missing=MISSING)


def test_nested_includes_and_defaults_are_staged_under_their_own_names(roots, tmp_path):
    root, _ = roots
    staged = vet(root / "scene.xml", root)
    names = sorted(staged.files)
    assert len(names) == 5 and STAGED_SCENE in names
    assert {name.split("-", 1)[1] for name in names if name != STAGED_SCENE} == {
        "parts.xml", "more.xml", "quad.obj", "refl.spd"}
    every_xml = b"".join(data for name, data in staged.files.items() if name.endswith(".xml"))
    # The copies name each other only: no original path, no parameter, no default.
    assert b"parts/" not in every_xml and b"$" not in every_xml and b"<default" not in every_xml
    # A relative scene path is looked up under each root; same content, same digest.
    assert vet("scene.xml", root).digest == staged.digest


def test_the_staged_copy_loads_in_mitsuba(roots, tmp_path, mi):
    root, _ = roots
    staged = vet(root / "scene.xml", root)
    folder = tmp_path / "staged"
    for name, data in staged.files.items():
        write(folder / name, data)
    loaded = load_scene(folder / STAGED_SCENE, 8)
    assert loaded.features.shape_count == 2 and loaded.resolution == (8, 8)


@pytest.mark.parametrize("reference", [
    '<bsdf type="diffuse"><spectrum name="reflectance" filename="{secret}"/></bsdf>',
    '<bsdf type="diffuse"><spectrum name="reflectance" filename="../outside/secret.spd"/>'
    '</bsdf>',
    '<bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
    '<string name="filename" value="{secret}"/></texture></bsdf>',
    '<bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
    '<string name="filename" value="$file"/></texture></bsdf>',
    '<bsdf type="diffuse"><spectrum name="reflectance" filename="/etc/passwd"/></bsdf>',
    '<bsdf type="diffuse"><spectrum name="reflectance" filename="no-such.spd"/></bsdf>',
])
def test_a_reference_outside_the_roots_or_missing_is_refused(roots, reference):
    root, outside = roots
    body = f'<shape type="sphere">{reference.format(secret=outside / "secret.spd")}</shape>'
    write(root / "bad.xml", scene(body, defaults=f'<default name="file" '
                                                 f'value="{outside / "secret.spd"}"/>'))
    with pytest.raises(SceneRefused) as refused:
        vet(root / "bad.xml", root)
    assert "is not available" in str(refused.value)
    assert "0.123456789" not in str(refused.value)


def test_a_nested_include_may_not_leave_the_root(roots):
    root, outside = roots
    write(outside / "evil.xml", '<scene version="3.0.0"><shape type="sphere"/></scene>')
    write(root / "parts" / "leaky.xml",
          '<scene version="3.0.0"><include filename="../../outside/evil.xml"/></scene>')
    write(root / "top.xml", scene('<include filename="parts/leaky.xml"/>'))
    with pytest.raises(SceneRefused, match="is not available"):
        vet(root / "top.xml", root)


def test_missing_and_outside_and_escaping_symlinks_get_one_answer(roots):
    root, outside = roots
    (root / "link.xml").symlink_to(outside / "scene.xml")
    (root / "inner-link.xml").symlink_to(root / "scene.xml")
    answers = set()
    for path in ("/etc/shadow", "/etc/hostname", "/etc/does-not-exist", str(outside / "scene.xml"),
                 str(root / "link.xml"), "link.xml", "../outside/scene.xml", str(root / "parts"),
                 "no-such.xml", "a\x00b"):
        with pytest.raises(SceneRefused) as refused:
            vet(path, root)
        answers.add(str(refused.value))
    assert answers == {MISSING}
    assert vet(root / "inner-link.xml", root).digest == vet(root / "scene.xml", root).digest


@pytest.mark.parametrize("body, message", [
    ('<path value="/etc"/><shape type="sphere"/>', "<path>"),
    ('<shape type="obj"><string name="filename" value="$undefined"/></shape>', "parameter"),
    ('<include filename="bad.xml"/>', "includes itself"),
])
def test_resolver_tags_undefined_parameters_and_cycles_are_refused(roots, body, message):
    root, _ = roots
    write(root / "bad.xml", scene(body))
    with pytest.raises(SceneRefused, match=message):
        vet(root / "bad.xml", root)


def test_document_type_declarations_are_refused(roots):
    root, _ = roots
    write(root / "dtd.xml", '<!DOCTYPE scene [<!ENTITY e SYSTEM "/etc/passwd">]>'
                            + scene('<shape type="sphere"/>'))
    with pytest.raises(SceneRefused, match="DOCTYPE"):
        vet(root / "dtd.xml", root)


def test_a_root_that_is_a_symlink_is_resolved(roots, tmp_path):
    root, _ = roots
    alias = tmp_path / "alias"
    alias.symlink_to(root)
    assert vet(alias / "scene.xml", alias).digest == vet(root / "scene.xml", root).digest


def test_a_fifo_under_a_root_does_not_hang(roots):
    root, _ = roots
    os.mkfifo(root / "pipe.spd")
    write(root / "fifo.xml", scene('<shape type="sphere"><bsdf type="diffuse"><spectrum '
                                   'name="reflectance" filename="pipe.spd"/></bsdf></shape>'))
    with pytest.raises(SceneRefused, match="is not available"):
        vet(root / "fifo.xml", root)


# ---- Uploads -------------------------------------------------------------------

def upload_files() -> dict[str, bytes]:
    return {"parts/parts.xml": b'<scene version="3.0.0"><include filename="more.xml"/></scene>',
            "parts/more.xml": b'<scene version="3.0.0"><shape type="sphere"/></scene>',
            "mesh/quad.obj": QUAD}


UPLOAD_XML = scene('<include filename="parts/parts.xml"/><shape type="obj">'
                   '<string name="filename" value="$m"/></shape>',
                   defaults='<default name="m" value="mesh/quad.obj"/>').encode()


def test_an_upload_reads_only_its_own_files():
    staged = vet_upload(UPLOAD_XML, upload_files(), LIMITS)
    assert len(staged.files) == 4
    assert vet_upload(UPLOAD_XML, upload_files(), LIMITS).digest == staged.digest
    changed = {**upload_files(), "mesh/quad.obj": QUAD + b"\n"}
    assert vet_upload(UPLOAD_XML, changed, LIMITS).digest != staged.digest
    for reference in ("/etc/passwd", "../quad.obj", "mesh/missing.obj", "~/x.obj"):
        xml = scene(f'<shape type="obj"><string name="filename" value="{reference}"/></shape>')
        with pytest.raises(SceneRefused, match="is not available"):
            vet_upload(xml.encode(), upload_files(), LIMITS)


@pytest.mark.parametrize("name", ["/abs.obj", "../up.obj", "a/../b.obj", "a\\b.obj", ""])
def test_upload_file_names_must_be_plain_relative_names(name):
    with pytest.raises(SceneRefused, match="must be relative"):
        vet_upload(UPLOAD_XML, {**upload_files(), name: b"x"}, LIMITS)


def test_upload_size_limits_name_the_limit():
    small = Limits(max_file_bytes=100, max_total_bytes=1000)
    with pytest.raises(SceneTooLarge, match="limit is 100 bytes per file"):
        vet_upload(b"<scene/>", {"big.obj": b"x" * 101}, small)
    with pytest.raises(SceneTooLarge, match="1000 bytes in all"):
        vet_upload(b"<scene/>", {f"f{i}.obj": b"x" * 100 for i in range(10)}, small)


def test_a_parameter_that_makes_a_property_a_filename_is_vetted(roots):
    root, _ = roots
    write(root / "passwd", "not a secret")   # a slash-less name Mitsuba would also find
    body = '<shape type="obj"><string value="no-such-file" name="$n"/></shape>'
    write(root / "renamed.xml", scene(body, defaults='<default name="n" value="filename"/>'))
    with pytest.raises(SceneRefused, match="'no-such-file' it references is not available"):
        vet(root / "renamed.xml", root)


def test_a_document_type_in_another_encoding_is_refused(roots):
    root, _ = roots
    text = ('<?xml version="1.0" encoding="UTF-16"?><!DOCTYPE scene [<!ENTITY e "x">]>'
            + scene('<shape type="sphere"/>'))
    write(root / "utf16.xml", text.encode("utf-16"))
    with pytest.raises(SceneRefused, match="DOCTYPE"):
        vet(root / "utf16.xml", root)
