"""Bounds on what a request can make the service parse, replayed against the
in-process app: bodies and scene XML nested ~1000 deep (Python's parsers recurse
per level: 500 on the scene upload, 400 elsewhere, before the depth limits)."""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.record.db import open_store
from service.api.main import create_app
from service.api.nesting import nested_deeper_than
from service.config import ServiceSettings

#: The limits of service/api/limits.py and renderers/scenes/vetting.py, spelled out so
#: that this module also runs against a service without them (and fails there).
MAX_JSON_DEPTH = 10
MAX_XML_DEPTH = 64
#: Deep enough to exhaust Python's recursion (its limit is 1000 frames).
ABUSIVE_DEPTH = 2000
SCENE = '<scene version="3.0.0"><emitter type="constant"/>{}</scene>'


@pytest.fixture(scope="module")
def api(tmp_path_factory) -> Iterator[TestClient]:
    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("bounds") / "data",
                               database_url=None)
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    with TestClient(create_app(settings)) as client:
        client.headers["X-API-Key"] = key
        yield client
    store.close()


def nested_json(depth: int) -> bytes:
    """A JSON object nesting ``depth`` arrays and objects (the body is level 1)."""
    return ('{"params": ' + "[" * (depth - 1) + "]" * (depth - 1) + "}").encode()


def assert_refused_for_depth(answer, limit: int) -> None:
    assert answer.status_code == 422, answer.text[:300]
    error = answer.json()["detail"][0]
    assert set(error) >= {"loc", "msg", "type"} and error["loc"][0] == "body"
    assert f"nested deeper than {limit}" in error["msg"] or f"more than {limit} deep" \
        in error["msg"], error


@pytest.mark.parametrize("path", ["/api/v1/jobs", "/api/v1/sweeps", "/api/v1/auth/login",
                                  "/api/v1/scenes"])
def test_a_deeply_nested_body_is_refused_in_the_422_shape(api, path):
    """Before: 400 "There was an error parsing the body" (500 on the scene upload)."""
    answer = api.post(path, content=nested_json(ABUSIVE_DEPTH),
                      headers={"Content-Type": "application/json"})
    assert_refused_for_depth(answer, MAX_JSON_DEPTH)
    # Just over the limit is refused the same way, before any parse.
    assert_refused_for_depth(api.post(path, content=nested_json(MAX_JSON_DEPTH + 1),
                                      headers={"Content-Type": "application/json"}),
                             MAX_JSON_DEPTH)


def test_a_body_at_the_depth_limit_is_not_refused_for_depth(api):
    answer = api.post("/api/v1/jobs", content=nested_json(MAX_JSON_DEPTH),
                      headers={"Content-Type": "application/json"})
    assert answer.status_code == 422
    assert "nested deeper" not in answer.text      # refused for its fields only


def test_brackets_inside_strings_nest_nothing():
    deep = MAX_JSON_DEPTH + 5
    quoted = json.dumps({"note": "[" * 100 + '\\"{{{' + "\\" * 7}).encode()
    assert not nested_deeper_than(quoted, MAX_JSON_DEPTH)
    # An escaped backslash ends a string like any other: what follows counts.
    after = b'{"a": "x\\\\", "b": ' + b"[" * deep + b"]" * deep + b"}"
    assert json.loads(after) and nested_deeper_than(after, MAX_JSON_DEPTH)
    # An escaped quote does not end it: the brackets stay text.
    inside = b'{"a": "x\\" ' + b"[" * deep + b'"}'
    assert json.loads(inside) and not nested_deeper_than(inside, MAX_JSON_DEPTH)


def test_a_deeply_nested_scene_xml_is_refused_naming_the_limit(api):
    """Before: 500 "internal error (RecursionError)" with a traceback in the log."""
    for depth in (ABUSIVE_DEPTH, MAX_XML_DEPTH + 1):
        nested = '<bsdf type="diffuse">' * depth + "</bsdf>" * depth
        answer = api.post("/api/v1/scenes", json={"xml": SCENE.format(nested)})
        assert_refused_for_depth(answer, MAX_XML_DEPTH)
        assert answer.json()["detail"][0]["loc"] == ["body", "xml"]


def spheres(count: int) -> str:
    return SCENE.format('<shape type="sphere"/>' * (count - 2))   # + <scene>, <emitter>


def test_a_scene_over_the_element_limit_is_refused_before_its_tree(api, monkeypatch):
    """Before: a 63 MB scene.xml of 1.04 M elements was parsed whole (RSS +920 MiB,
    27 s). The count stops the streaming parse at the first element too many."""
    monkeypatch.setenv("NIRC_BENCH_SCENE_MAX_XML_ELEMENTS", "50")
    refused = api.post("/api/v1/scenes", json={"xml": spheres(51)})
    assert refused.status_code == 422, refused.text
    assert "more than 50 elements" in refused.json()["detail"][0]["msg"]
    assert "NIRC_BENCH_SCENE_MAX_XML_ELEMENTS" in refused.text
    # At the limit the scene is vetted (and stored: it reads no file).
    assert api.post("/api/v1/scenes", json={"xml": spheres(50)}).status_code in (200, 201)
    # Includes count with the scene that includes them.
    included = base64.b64encode(spheres(30).encode()).decode()
    main = SCENE.format('<include filename="more.xml"/>' + '<shape type="sphere"/>' * 25)
    answer = api.post("/api/v1/scenes", json={"xml": main, "files": {"more.xml": included}})
    assert answer.status_code == 422 and "more than 50 elements" in answer.text


def test_uploads_vetted_at_once_are_bounded(api):
    """Over the slots (every one held here): 503 with Retry-After, nothing parsed."""
    slots = api.app.state.scene_parses
    held = 0
    while not slots.locked():
        api.portal.call(slots.acquire)
        held += 1
    try:
        busy = api.post("/api/v1/scenes", json={"xml": spheres(3)})
        assert busy.status_code == 503 and int(busy.headers["Retry-After"]) > 0, busy.text
        assert "NIRC_BENCH_MAX_SCENE_PARSES" in busy.json()["detail"]
    finally:
        for _ in range(held):
            slots.release()
    assert api.post("/api/v1/scenes", json={"xml": spheres(3)}).status_code in (200, 201)
