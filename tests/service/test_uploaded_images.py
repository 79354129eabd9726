"""Images uploaded to compare a run against (POST /api/v1/images): the error map measured
against the upload, the key rules of a write, the service's size limits, a per-key count
bound, and every bad file answered 4xx with a message saying what is wrong."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.db import open_store
from metrics.errors import relative_squared_error_map
from metrics.imageio import read_exr, write_exr
from service.api.deps import SESSION_COOKIE
from service.api.main import create_app
from service.api.routes.images import IMAGES_PER_KEY
from service.config import ServiceSettings

SPEC = RenderSpec(scene="cornell-box", resolution=8, spp=1, frames=1, seeds=2,
                  reference=ReferenceSpec(spp=16, spp_per_pass=8))
EXR = {"Content-Type": "image/x-exr"}


@pytest.fixture(scope="module")
def served(tmp_path_factory, mi):
    """(client, settings, run id, reference pixels, two keys, a scratch folder)."""
    folder = tmp_path_factory.mktemp("uploads")
    settings = ServiceSettings(data_dir=folder / "data")
    store = open_store(settings)
    run_id = execute(RenderJob.parse(SPEC), store, settings).run_id
    reference = read_exr(settings.references_dir / store.get_run(run_id).reference.image_path)
    keys = [create_api_key(store, name)[1] for name in ("a", "b")]
    with TestClient(create_app(settings)) as client:
        yield client, settings, run_id, reference, keys, folder
    store.close()


def exr_bytes(folder, image: np.ndarray, name: str = "upload.exr") -> bytes:
    write_exr(folder / name, image)
    return (folder / name).read_bytes()


def upload(client, run_id: int, body: bytes, key: str | None, headers=EXR):
    return client.post(f"/api/v1/images?run={run_id}", content=body,
                       headers={**headers, **({"X-API-Key": key} if key else {})})


def floats(answer) -> np.ndarray:
    assert answer.status_code == 200, answer.text
    shape = [int(answer.headers[h]) for h in ("X-Height", "X-Width", "X-Channels")]
    return np.frombuffer(answer.content, dtype="<f4").reshape(shape)


def test_the_error_map_is_measured_against_the_uploaded_image(served):
    client, settings, run_id, reference, (key, _), folder = served
    brighter = reference * np.float32(1.5) + np.float32(0.01)
    answer = upload(client, run_id, exr_bytes(folder, brighter), key)
    assert answer.status_code == 201, answer.text
    image_id = answer.json()["id"]
    np.testing.assert_array_equal(floats(client.get(f"/api/v1/images/{image_id}")), brighter)
    image = floats(client.get(f"/api/v1/runs/{run_id}/pixels/image?seed=1"))
    against = client.get(f"/api/v1/runs/{run_id}/pixels/error?seed=1&against={image_id}")
    assert "uploaded image" in against.headers["X-Quantity"]
    np.testing.assert_allclose(floats(against)[..., 0],
                               relative_squared_error_map(image, brighter, SPEC.eps))
    # The map of the reference is another one: a route ignoring `against` fails above.
    own = floats(client.get(f"/api/v1/runs/{run_id}/pixels/error?seed=1"))[..., 0]
    assert np.abs(own - floats(against)[..., 0]).max() > 1e-3
    # The same file again is the same image, stored once.
    again = upload(client, run_id, exr_bytes(folder, brighter), key)
    assert again.status_code == 200 and again.json()["id"] == image_id


def test_an_upload_is_a_write_the_login_cookie_does_not_authorize(served):
    client, _, run_id, reference, (key, _), folder = served
    body = exr_bytes(folder, reference)
    assert upload(client, run_id, body, None).status_code == 401
    assert upload(client, run_id, body, "nirc_not-a-key").status_code == 403
    assert client.post("/api/v1/auth/login", json={"api_key": key}).status_code == 204
    assert client.cookies.get(SESSION_COOKIE)
    try:
        assert upload(client, run_id, body, None).status_code == 401   # the cookie alone
    finally:
        client.post("/api/v1/auth/logout")


def test_bad_uploads_are_4xx_saying_what_is_wrong(served):
    client, settings, run_id, reference, (key, _), folder = served
    good = exr_bytes(folder, reference)
    nan = reference.copy()
    nan[2, 3, 1] = np.nan
    cases = [
        (b"not an image at all", 422, "not an OpenEXR file"),
        (good[: len(good) // 2], 422, "EXR"),
        (exr_bytes(folder, np.ones((8, 9, 3), np.float32)), 422, "9x8 pixels; the run's "
                                                                   "images are 8x8"),
        (exr_bytes(folder, np.ones((8, 8, 1), np.float32)), 422, "only a Y channel"),
        (exr_bytes(folder, nan), 422, "1 values that are not finite"),
        (b"", 422, "empty"),
        (b"x" * (settings.max_body_bytes + 1), 413, "max_body_bytes"),
    ]
    for body, code, message in cases:
        answer = upload(client, run_id, body, key)
        assert answer.status_code == code, (message, answer.text)
        assert message.lower() in answer.text.lower(), answer.text
    assert upload(client, run_id, good, key, {"Content-Type": "image/png"}).status_code == 415
    assert "no run 99999" in upload(client, 99999, good, key).text
    pixels = f"/api/v1/runs/{run_id}/pixels"
    assert client.get(f"{pixels}/image?against={'0' * 64}").status_code == 422
    assert client.get(f"{pixels}/error?against=../../etc").status_code == 422
    missing = client.get(f"{pixels}/error?against={'0' * 64}")
    assert missing.status_code == 404 and "upload it again" in missing.json()["detail"]


def test_a_key_keeps_its_latest_uploads_only(served):
    client, settings, run_id, reference, (key, other_key), folder = served
    kept_by_other = upload(client, run_id, exr_bytes(folder, reference + 7), other_key)
    ids = []
    for k in range(IMAGES_PER_KEY + 1):
        answer = upload(client, run_id, exr_bytes(folder, reference + k), key)
        assert answer.status_code in (200, 201), answer.text
        ids.append(answer.json()["id"])
    assert answer.json()["kept"] == IMAGES_PER_KEY
    assert client.get(f"/api/v1/images/{ids[0]}").status_code == 404     # the oldest went
    assert all(client.get(f"/api/v1/images/{i}").status_code == 200 for i in ids[1:])
    # Another key's uploads are its own.
    assert client.get(f"/api/v1/images/{kept_by_other.json()['id']}").status_code == 200
    stored = list((settings.data_dir / "uploaded_images").rglob("*.exr"))
    assert len(stored) <= 2 * IMAGES_PER_KEY


def test_an_upload_past_the_data_limit_is_refused(served):
    client, settings, run_id, reference, (key, _), folder = served
    full = settings.model_copy(update={"max_data_bytes": 1})
    with TestClient(create_app(full)) as tight:
        answer = upload(tight, run_id, exr_bytes(folder, reference + 100), key)
    assert answer.status_code == 507 and "max_data_bytes" in answer.text


def test_uploaded_images_count_in_the_data_folder_s_size(served):
    """The size jobs, scenes and uploads are admitted against grows by each new upload's
    file, and an upload that just fits is stored, one byte less is refused."""
    from jobs.execution.work import data_bytes

    client, settings, run_id, reference, _, folder = served
    store = open_store(settings)
    try:
        key = create_api_key(store, "sizes")[1]      # none of its uploads is removed here
        before = data_bytes(store, settings)
        body = exr_bytes(folder, reference + 200)
        assert upload(client, run_id, body, key).status_code == 201
        assert data_bytes(store, settings) == before + len(body)
        for room, status in ((-1, 507), (0, 201)):
            body = exr_bytes(folder, reference + 300 + room)
            limit = data_bytes(store, settings) + len(body) + room
            with TestClient(create_app(settings.model_copy(
                    update={"max_data_bytes": limit}))) as tight:
                assert upload(tight, run_id, body, key).status_code == status
    finally:
        store.close()


def test_one_file_uploaded_for_two_runs_is_stored_once(served):
    """The same bytes uploaded by one key for two runs of the image's size are one file
    on disk (a hard link under the second run, so gc still removes each run's name with
    its run): the second answer is 200 with the same id, the data folder and the key's
    usage grow by the file's size once. Planted: a second copy under another run (what
    storing per run did) grows both by the size again."""
    from jobs.execution.work import data_bytes
    from jobs.record.usage import stored_bytes
    from tests.jobs.factories import run_fields

    client, settings, run_id, reference, _, folder = served
    store = open_store(settings)
    try:
        row, key = create_api_key(store, "twice")
        key_id = row.id
        other_run = store.add_run(run_fields(width=8, height=8), [], []).id
        body = exr_bytes(folder, reference + 400)
        # A refused upload leaves no folder behind (it left an empty one per run).
        assert upload(client, other_run, b"not an EXR file", key).status_code == 422
        assert not (settings.uploaded_images_dir / str(key_id)).exists() or not any(
            (settings.uploaded_images_dir / str(key_id)).iterdir())
        before = data_bytes(store, settings)
        first, second = (upload(client, run, body, key) for run in (run_id, other_run))
        assert (first.status_code, second.status_code) == (201, 200), second.text
        assert first.json()["id"] == second.json()["id"]
        names = sorted((settings.uploaded_images_dir / str(key_id)).rglob("*.exr"))
        assert [path.parent.name for path in names] == sorted([str(run_id), str(other_run)])
        assert names[0].samefile(names[1])
        assert data_bytes(store, settings) == before + len(body)
        assert stored_bytes(store, settings, key_id) == len(body)
        # Planted: a copy per run is counted as what it is, twice the bytes.
        names[1].unlink()
        names[1].write_bytes(body)
        assert data_bytes(store, settings) == before + 2 * len(body)
        assert stored_bytes(store, settings, key_id) == 2 * len(body)
    finally:
        store.close()
