"""Scene paths over REST must not expose the server's files.

Each attack is replayed against the in-process app and against a real `nirc-bench
serve` on loopback (one start for the module, scene roots and size limits from its
environment): an existence oracle (`/etc/shadow` vs a missing file), a path relative
to the server's working directory, a symlink leading out of a scene root, an XML
under a root that reads `/etc/passwd` through `<spectrum filename>`, an oversized
upload. And the way that remains: an uploaded scene renders, under one id however
often it is uploaded; a scene under a configured root is accepted; a scene that
Mitsuba refuses fails with a fixed message, never quoting one of its files.
"""

from __future__ import annotations

import base64
import io
import os
import re
import subprocess
import sys
import tarfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.record.config import Settings
from jobs.record.db import open_store
from renderers.scenes import load_scene
from service.api.main import create_app
from service.config import ServiceSettings
from tests.service.live import Service

MAX_FILE_BYTES = 100_000
MAX_BYTES = 200_000
#: A line of /etc/passwd on every Linux machine.
PASSWD_LINE = "root:x:0:0"
SECRET = "secret-line-4711"
SENSOR = ('<sensor type="perspective"><transform name="to_world"><lookat origin="0,0,4" '
          'target="0,0,0" up="0,1,0"/></transform><film type="hdrfilm">'
          '<integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>')
QUAD = b"v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n"
TINY = {"method": "pt", "resolution": 16, "spp": 1, "frames": 1, "seeds": 1,
        "reference": {"spp": 8, "spp_per_pass": 8}}


def scene(body: str) -> str:
    return f'<scene version="3.0.0">{body}<emitter type="constant"/>{SENSOR}</scene>'


def write(path: Path, data: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


@pytest.fixture(scope="module")
def layout(tmp_path_factory) -> dict[str, Path]:
    """A scene root (a good scene, one reading /etc/passwd, a symlink leading out)
    and a folder outside it with a valid scene."""
    base = tmp_path_factory.mktemp("scenes")
    root, outside = base / "root", base / "outside"
    write(root / "good" / "scene.xml", scene(
        '<shape type="obj"><string name="filename" value="quad.obj"/></shape>'))
    write(root / "good" / "quad.obj", QUAD)
    write(root / "leak.xml", scene('<shape type="sphere"><bsdf type="diffuse"><spectrum '
                                   'name="reflectance" filename="/etc/passwd"/></bsdf></shape>'))
    write(outside / "scene.xml", scene('<shape type="sphere"/>'))
    (root / "evil.xml").symlink_to(outside / "scene.xml")
    return {"root": root, "outside": outside, "base": base}


class Target:
    """The API under test, over HTTP: the in-process app or the live service."""

    def __init__(self, client: httpx.Client | TestClient, key: str,
                 service: Service | None = None) -> None:
        self.client, self.key, self.service = client, key, service

    def post(self, path: str, body: dict, key: str | None = None) -> httpx.Response:
        return self.client.post(f"/api/v1/{path}", json=body,
                                headers={"X-API-Key": self.key if key is None else key})

    def get(self, path: str) -> httpx.Response:
        return self.client.get(f"/api/v1/{path}")


@pytest.fixture(scope="module")
def live(layout, tmp_path_factory) -> Iterator[Target]:
    """`nirc-bench serve` on loopback; its scene roots and limits set by environment."""
    service = Service(tmp_path_factory.mktemp("live") / "data")
    service.env.update({"NIRC_BENCH_SCENE_ROOTS": str(layout["root"]),
                        "NIRC_BENCH_SCENE_MAX_FILE_BYTES": str(MAX_FILE_BYTES),
                        "NIRC_BENCH_SCENE_MAX_BYTES": str(MAX_BYTES)})
    service.start()
    try:
        with httpx.Client(base_url=service.url, timeout=30) as client:
            yield Target(client, service.key, service)
    finally:
        service.stop()


@pytest.fixture(scope="module")
def in_process(layout, tmp_path_factory) -> Iterator[Target]:
    """The app in this process (no dispatcher: jobs stay queued)."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("app") / "data", database_url=None,
                        scene_roots=[layout["root"]])
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    with pytest.MonkeyPatch.context() as patch, TestClient(create_app(settings, None)) as client:
        _scene_limits(patch)
        yield Target(client, key)
    store.close()


def _scene_limits(patch: pytest.MonkeyPatch) -> None:
    """The scenes' size limit of these tests, set the way an operator sets it."""
    patch.setenv("NIRC_BENCH_SCENE_MAX_FILE_BYTES", str(MAX_FILE_BYTES))
    patch.setenv("NIRC_BENCH_SCENE_MAX_BYTES", str(MAX_BYTES))


@pytest.fixture(params=["in-process", "live"])
def api(request) -> Target:
    return request.getfixturevalue(request.param.replace("-", "_"))


def refusal(target: Target, scene_name: str, kind: str = "jobs") -> httpx.Response:
    body = {"scene": scene_name, **TINY} if kind == "jobs" else {"scene": scene_name, "nc": [1]}
    response = target.post(kind, body)
    assert response.status_code == 422, (scene_name, response.text)
    return response


def every_job_text(target: Target) -> str:
    return target.get("jobs?limit=1000").text


def upload(target: Target, xml: str, files: dict[str, bytes], key: str | None = None):
    return target.post("scenes", {"xml": xml, "files": {
        name: base64.b64encode(data).decode() for name, data in files.items()}}, key=key)


def wait(target: Target, job_id: int, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    job: dict = {}
    while time.monotonic() < deadline:
        job = target.get(f"jobs/{job_id}").json()
        if job["status"] in ("succeeded", "failed", "canceled"):
            return job
        time.sleep(0.3)
    raise AssertionError(f"job {job_id} did not finish: {job}")


# ---- Attacks ---------------------------------------------------------------------

def test_an_existing_and_a_missing_server_file_get_the_same_answer(api):
    for kind in ("jobs", "sweeps"):
        shadow = refusal(api, "/etc/shadow", kind)
        missing = refusal(api, "/etc/does-not-exist", kind)
        assert shadow.content == missing.content
        assert shadow.headers["content-type"] == missing.headers["content-type"]
        assert "not available" in shadow.json()["detail"][0]["msg"]


def climb(prefix: str, target: Path) -> str:
    """``prefix`` followed by as many ``..`` as it has parts, then ``target``: as text,
    the path is ``target``; on disk, each step after ``prefix`` asks what it is."""
    return prefix + "/.." * (len(Path(prefix).parts) - 1) + str(target)


def test_dotdot_after_a_server_path_tells_nothing_about_it(api, layout):
    """`X/../..` names what it names as text: whether X exists outside the roots (a
    file, /etc/shadow, a process in /proc) never changes the answer."""
    good = layout["root"] / "good" / "scene.xml"
    prefixes = [str(layout["outside"] / "scene.xml"), str(layout["outside"] / "nothing.xml"),
                "/etc/shadow", "/etc/shadowXX", f"/proc/{os.getpid()}", "/proc/999999999"]
    answers = set()
    for prefix in prefixes:
        response = api.post("jobs", {"scene": climb(prefix, good), **TINY})
        answers.add((response.status_code, response.json().get("id")))
    assert len(answers) == 1, answers
    # Text that still climbs out of every root is refused like a missing file.
    outside = api.post("jobs", {"scene": climb("/etc/shadow", Path("/etc/passwd")), **TINY})
    assert outside.status_code == 422
    assert outside.content == refusal(api, "/etc/does-not-exist").content


def test_dotdot_in_a_scene_reference_tells_nothing_about_server_files(api, layout):
    quad = layout["root"] / "good" / "quad.obj"
    answers = set()
    for prefix in (str(layout["outside"] / "scene.xml"), str(layout["outside"] / "nothing.xml")):
        name = f"probe-{len(answers)}-{Path(prefix).stem}.xml"
        write(layout["root"] / name, scene(
            f'<shape type="obj"><string name="filename" value="{climb(prefix, quad)}"/></shape>'))
        response = api.post("jobs", {"scene": name, **TINY})
        answers.add(response.status_code)
    assert answers == {202}


def test_a_relative_path_is_not_looked_up_in_the_working_directory(api, layout):
    # The server's working directory is this process's: a relative path to a real scene.
    relative = os.path.relpath(layout["outside"] / "scene.xml", Path.cwd())
    assert Path(relative).is_file() and not Path(relative).is_absolute()
    assert refusal(api, relative).content == refusal(api, "/etc/does-not-exist").content


def test_a_symlink_under_a_root_leading_out_of_it_is_refused(api, layout):
    assert (layout["root"] / "evil.xml").resolve().is_file()
    answers = {refusal(api, name).content for name in (
        str(layout["root"] / "evil.xml"), "evil.xml", str(layout["outside"] / "scene.xml"),
        "/etc/does-not-exist")}
    assert len(answers) == 1


def test_a_scene_reading_etc_passwd_is_refused_and_nothing_of_it_is_shown(api, layout):
    for name in (str(layout["root"] / "leak.xml"), "leak.xml"):
        response = refusal(api, name)
        message = response.json()["detail"][0]["msg"]
        assert "'/etc/passwd'" in message and "not available" in message
        assert PASSWD_LINE not in response.text
    assert PASSWD_LINE not in every_job_text(api)
    assert "leak.xml" not in every_job_text(api)   # no job was queued


def test_a_scene_under_a_configured_root_is_accepted_as_a_stored_copy(api, layout):
    absolute = api.post("jobs", {"scene": str(layout["root"] / "good" / "scene.xml"), **TINY})
    assert absolute.status_code == 202, absolute.text
    staged = absolute.json()["spec"]["scene"]
    assert staged.startswith("staged:") and len(staged) == len("staged:") + 32
    relative = api.post("jobs", {"scene": "good/scene.xml", **TINY})
    assert relative.status_code == 202 and relative.json()["id"] == absolute.json()["id"]
    assert str(layout["root"]) not in every_job_text(api)
    assert api.post("jobs", {"scene": staged, **TINY}).json()["id"] == absolute.json()["id"]


def test_an_upload_needs_a_key_and_the_same_upload_gets_the_same_id(api):
    xml = scene('<shape type="obj"><string name="filename" value="mesh/quad.obj"/></shape>')
    assert upload(api, xml, {"mesh/quad.obj": QUAD}, key="").status_code == 401
    first = upload(api, xml, {"mesh/quad.obj": QUAD})
    assert first.status_code in (200, 201), first.text
    again = upload(api, xml, {"mesh/quad.obj": QUAD})
    assert again.status_code == 200 and again.json()["id"] == first.json()["id"]
    assert first.json()["id"].startswith("upload:") and first.json()["files"] == 1
    changed = upload(api, xml, {"mesh/quad.obj": QUAD + b"\n"})
    assert changed.json()["id"] != first.json()["id"]
    job = api.post("jobs", {"scene": first.json()["id"], **TINY})
    assert job.status_code == 202 and job.json()["spec"]["scene"] == first.json()["id"]
    unknown = "upload:" + "0" * 32
    assert refusal(api, unknown).content == refusal(api, "/etc/does-not-exist").content


@pytest.mark.parametrize("reference", ["/etc/passwd", "../../etc/passwd", "missing.obj"])
def test_an_upload_may_read_only_its_own_files(api, reference):
    xml = scene(f'<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" '
                f'filename="{reference}"/></bsdf></shape>')
    response = upload(api, xml, {"quad.obj": QUAD})
    assert response.status_code == 422, response.text
    assert "not available" in response.text and PASSWD_LINE not in response.text


def test_an_oversized_upload_is_refused_with_the_limit(api):
    xml = scene('<shape type="obj"><string name="filename" value="big.obj"/></shape>')
    big_file = upload(api, xml, {"big.obj": b"#" * (MAX_FILE_BYTES + 1)})
    assert big_file.status_code == 413 and str(MAX_FILE_BYTES) in big_file.text
    files = {f"part{i}.obj": b"#" * (MAX_FILE_BYTES // 2) for i in range(5)}
    too_much = upload(api, xml, files)
    assert too_much.status_code == 413 and str(MAX_BYTES) in too_much.text
    huge_json = api.client.post("/api/v1/scenes", content=b"x" * (1_000_001),
                                headers={"X-API-Key": api.key,
                                         "Content-Type": "application/json"})
    assert huge_json.status_code == 413 and "application/x-tar" in huge_json.text
    huge_tar = api.client.post("/api/v1/scenes", content=b"x" * (MAX_BYTES + (5 << 20)),
                               headers={"X-API-Key": api.key,
                                        "Content-Type": "application/x-tar"})
    assert huge_tar.status_code == 413 and str(MAX_BYTES) in huge_tar.text


# ---- Renders (the live service runs them) ----------------------------------------

def test_an_uploaded_scene_renders(live):
    xml = scene('<include filename="parts/shapes.xml"/>')
    files = {"parts/shapes.xml": b'<scene version="3.0.0"><shape type="obj"><string '
                                 b'name="filename" value="quad.obj"/></shape></scene>',
             "parts/quad.obj": QUAD}
    scene_id = upload(live, xml, files).json()["id"]
    job = wait(live, live.post("jobs", {"scene": scene_id, **TINY}).json()["id"])
    assert job["status"] == "succeeded", job
    run = live.get(f"runs/{job['run_id']}").json()
    assert run["scene"] == scene_id


def test_a_scene_mitsuba_refuses_fails_without_quoting_its_files(live):
    xml = scene('<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" '
                'filename="values.spd"/></bsdf></shape>')
    scene_id = upload(live, xml, {"values.spd": f"{SECRET} is not a number\n".encode()})
    scene_id = scene_id.json()["id"]
    job = wait(live, live.post("jobs", {"scene": scene_id, **TINY}).json()["id"])
    assert job["status"] == "failed", job
    assert scene_id in job["error"] and "could not be loaded" in job["error"], job["error"]
    assert SECRET not in every_job_text(live)


def test_the_cli_uploads_a_local_scene_the_service_may_not_read(live, layout):
    """`render --server` with a local XML path (outside every scene root): the CLI
    uploads the scene and the files it reads, the job renders the uploaded copy, and
    the table names the file and its content fingerprint as a local run's does."""
    local = layout["base"] / "client"
    write(local / "scene.xml", scene('<shape type="obj"><string name="filename" '
                                     'value="../client-meshes/quad.obj"/></shape>'))
    write(layout["base"] / "client-meshes" / "quad.obj", QUAD)
    done = subprocess.run(
        [sys.executable, "-m", "service", "render", "--scene", str(local / "scene.xml"),
         "--res", "16", "--spp", "1", "--frames", "1", "--seeds", "1", "--ref-spp", "8",
         "--server", live.service.url, "--api-key", live.key],
        capture_output=True, text=True, timeout=300,
        env={**os.environ, "COLUMNS": "400"})
    assert done.returncode == 0, done.stderr[-2000:]
    uploaded = re.search(r"uploaded as (upload:[0-9a-f]{32})", done.stdout)
    assert uploaded, done.stdout
    run = live.get(f"results?scene={uploaded.group(1)}").json()
    assert len(run) == 1 and run[0]["scene"] == uploaded.group(1), run
    fingerprint = load_scene(str(local / "scene.xml")).fingerprint
    assert run[0]["scene_fingerprint"] == fingerprint
    assert f"{(local / 'scene.xml').resolve()} / pt" in done.stdout, done.stdout
    assert fingerprint in done.stdout


def tar_of(files: dict[str, bytes], links: dict[str, str] | None = None) -> bytes:
    """A tar archive of ``files`` (name -> bytes) and symbolic ``links`` (name -> target)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        for name, target in (links or {}).items():
            info = tarfile.TarInfo(name)
            info.type, info.linkname = tarfile.SYMTYPE, target
            tar.addfile(info)
    return buffer.getvalue()


def upload_tar(target: Target, archive: bytes):
    return target.client.post("/api/v1/scenes", content=archive,
                              headers={"X-API-Key": target.key,
                                       "Content-Type": "application/x-tar"})


def test_a_tar_upload_holds_only_regular_files_under_relative_names(api):
    xml = scene('<shape type="obj"><string name="filename" value="quad.obj"/></shape>')
    good = upload_tar(api, tar_of({"scene.xml": xml.encode(), "quad.obj": QUAD}))
    assert good.status_code in (200, 201), good.text
    same = upload(api, xml, {"quad.obj": QUAD})          # the same scene sent as JSON
    assert same.json()["id"] == good.json()["id"]
    for archive in (tar_of({"scene.xml": xml.encode()}, links={"quad.obj": "/etc/passwd"}),
                    tar_of({"scene.xml": xml.encode(), "../quad.obj": QUAD}),
                    tar_of({"quad.obj": QUAD}), b"not a tar archive" * 100):
        refused = upload_tar(api, archive)
        assert refused.status_code == 422, refused.text
        assert PASSWD_LINE not in refused.text


def test_a_scene_upload_has_its_own_body_cap_not_the_service_wide_one(tmp_path, monkeypatch):
    """Bodies are capped service-wide (max_body_bytes), but a tar upload carries its
    files: it is read under the scene limits instead (and still refused beyond them)."""
    _scene_limits(monkeypatch)
    settings = ServiceSettings(data_dir=tmp_path / "data", database_url=None, max_body_bytes=2000)
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    mesh = QUAD + b"# padding\n" * 1000          # ~10 kB: over the service-wide cap
    xml = scene('<shape type="obj"><string name="filename" value="quad.obj"/></shape>')
    with TestClient(create_app(settings, None)) as client:
        target = Target(client, key)
        assert upload(target, xml, {"quad.obj": mesh}).status_code == 413   # JSON: 2000 B
        assert upload_tar(target, tar_of({"scene.xml": xml.encode(),
                                          "quad.obj": mesh})).status_code == 201
        assert target.post("jobs", {"scene": "x" * 3000, **TINY}).status_code == 413
        too_big = upload_tar(target, tar_of({"scene.xml": xml.encode(),
                                             "quad.obj": b"#" * (MAX_FILE_BYTES + 1)}))
        assert too_big.status_code == 413
    store.close()


def _peak_rss_reset(pid: int) -> int:
    """Reset the process's peak resident size (VmHWM) to its current size; returns it."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")
    return _peak_rss(pid)


def _peak_rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


def test_an_upload_streams_to_disk_counts_in_the_budget_and_gc_removes_it(tmp_path):
    """Before: a 513 MiB body was buffered whole (the server's memory grew by 3.7x the
    body), and stored scenes were neither counted in max_data_bytes nor ever removed.
    After, on a real server: a 24 MiB upload raises its peak memory by less than a
    quarter of that; a second scene that would pass max_data_bytes is refused (507);
    `gc --apply` removes the scene no job names, and then the second one fits."""
    mesh = 24 << 20
    service = Service(tmp_path / "data")
    service.env.update({"NIRC_BENCH_SCENE_MAX_FILE_BYTES": str(32 << 20),
                        "NIRC_BENCH_SCENE_MAX_BYTES": str(32 << 20),
                        "NIRC_BENCH_MAX_DATA_BYTES": str(40_000_000)})
    service.start()
    try:
        xml = scene('<shape type="obj"><string name="filename" value="big.obj"/></shape>')
        with httpx.Client(base_url=service.url, timeout=120) as client:
            target = Target(client, service.key)
            first = tar_of({"scene.xml": xml.encode(), "big.obj": b"#" * mesh})
            before = _peak_rss_reset(service.proc.pid)
            stored = upload_tar(target, first)
            assert stored.status_code == 201, stored.text
            assert _peak_rss(service.proc.pid) - before < mesh / 4
            second = tar_of({"scene.xml": xml.encode(), "big.obj": b"%" * mesh})
            full = upload_tar(target, second)
            assert full.status_code == 507 and "max_data_bytes" in full.json()["detail"]
            collected = subprocess.run([sys.executable, "-m", "service", "gc", "--apply",
                                        "--keep-days", "0"], env=service.env,
                                       capture_output=True, text=True, timeout=120)
            assert collected.returncode == 0, collected.stderr
            assert stored.json()["id"].split(":")[1] in collected.stdout
            assert upload_tar(target, second).status_code == 201
            assert refusal(target, stored.json()["id"]).status_code == 422   # gone
    finally:
        service.stop()
