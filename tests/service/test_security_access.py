"""Read access, each case replayed: reads without a key on a real `nirc-bench serve
--no-public-read` on loopback (and with public reads), `serve` on a non-loopback
address without a choice, the dashboard's login session (cookie flags, the key never
in the cookie, logout ending it on the server, and in a real headless Chromium under
the dashboard's Content-Security-Policy), security headers, lone surrogates in JSON,
the OpenAPI security schemes, owner-only files, and scale-out Dask over TLS with
certificates (a plain connection is refused, a plain scheduler off loopback too unless
a setting allows it)."""

from __future__ import annotations

import os
import socket
import ssl
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest
import uvicorn

from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.config import ServiceSettings
from tests.service.conftest import open_page, wait_until
from tests.service.live import Process, Service, Worker, free_port, service_env

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 2,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
#: Reads of every kind: lists, a job (its spec, error, worker), results, a file, scenes.
READS = ["/api/v1/jobs", "/api/v1/jobs/1", "/api/v1/jobs/1?wait_s=1", "/api/v1/results",
         "/api/v1/sweeps", "/api/v1/scenes", "/api/v1/runs/1", "/api/v1/artifacts/1",
         "/api/v1/compare?runs=1,2", "/api/v1/references/1/preview.png"]
COOKIE = "nirc_bench_session"


class LiveService(Service):
    """`nirc-bench serve`, ready once it answers at all (its reads may need a key), and
    failing at once if it exits instead (e.g. refusing its options)."""

    def start(self) -> None:
        Process.start(self)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if not self.alive():
                raise AssertionError(f"the service exited with status {self.proc.returncode}")
            try:
                httpx.get(f"{self.url}/openapi.json", timeout=2)
                return
            except httpx.HTTPError:
                time.sleep(0.3)
        raise AssertionError("the service did not start")


@pytest.fixture(scope="module")
def private(tmp_path_factory):
    """A service whose reads need a key, with one queued job (never dispatched)."""
    data_dir = tmp_path_factory.mktemp("private") / "data"
    service = LiveService(data_dir, options=["--no-public-read"])
    service.start()
    store = open_store(Settings(data_dir=data_dir))
    JobQueue(store).submit("render", SPEC, "queued")
    store.close()
    yield service
    service.stop()


def _status(url: str, **kwargs) -> int:
    return httpx.get(url, timeout=10, **kwargs).status_code


def test_reads_need_a_key_when_public_read_is_off(private):
    """Before: every GET answered 200 to anyone (job specs, errors, worker addresses)."""
    for path in READS:
        assert _status(f"{private.url}{path}") == 401, path
        assert _status(f"{private.url}{path}", headers={"X-API-Key": "nb_0_wrong"}) == 403, path
        assert _status(f"{private.url}{path}",
                       headers={"X-API-Key": private.key}) in (200, 404), path
    answer = httpx.get(f"{private.url}/api/v1/jobs/1", headers={"X-API-Key": private.key})
    assert answer.json()["spec"]["scene"] == "cornell-box"
    # The dashboard's page itself carries no data: it loads, and asks for a key.
    assert _status(f"{private.url}/") == 200
    data_dir = Path(private.env["NIRC_BENCH_DATA_DIR"])
    assert stat.S_IMODE(data_dir.stat().st_mode) == 0o700
    assert stat.S_IMODE((data_dir / "nirc-bench.db").stat().st_mode) == 0o600


@pytest.fixture
def app_with(tmp_path, monkeypatch):
    """``app_with(public_read)``: the app in-process, and a key."""
    from fastapi.testclient import TestClient

    from jobs.execution.apikeys import create_api_key
    from service.api.main import create_app

    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    store = open_store(Settings(data_dir=tmp_path / "data"))
    _, key = create_api_key(store, "tests")
    clients = []

    def make(public_read: bool | None) -> tuple:
        client = TestClient(create_app(ServiceSettings(data_dir=tmp_path / "data",
                                                       public_read=public_read)))
        clients.append(client)
        return client, key

    yield make
    for client in clients:
        client.close()
    store.close()


def test_public_read_is_a_setting(app_with):
    """Off: 401 without a key, 200 with it; on (and unset, as on loopback): 200."""
    private, key = app_with(False)
    for public_read in (True, None):
        public, _ = app_with(public_read)
        assert public.get("/api/v1/jobs").status_code == 200
        assert public.get("/api/v1/results").status_code == 200
    assert private.get("/api/v1/jobs").status_code == 401
    assert private.get("/api/v1/results").status_code == 401
    assert private.get("/api/v1/jobs", headers={"X-API-Key": key}).status_code == 200


def test_serve_off_loopback_needs_an_explicit_choice(tmp_path):
    """Before: `serve --host 0.0.0.0` opened every result to the network. After: one
    line and exit status 2, before anything binds; an explicit choice passes this gate
    (here it stops at the next check, still before binding)."""
    from service.cli import decide_public_read

    assert decide_public_read(None, "127.0.0.1") and decide_public_read(None, "::1")
    assert decide_public_read(None, "localhost") and decide_public_read(None, "127.0.0.2")
    assert decide_public_read(False, "0.0.0.0") is False
    assert decide_public_read(True, "0.0.0.0") is True
    env = service_env(tmp_path / "data")
    for host in ("0.0.0.0", "::", "10.1.2.3", "bench.example.org"):
        refused = subprocess.run([sys.executable, "-m", "service", "serve", "--host", host,
                                  "--port", str(free_port())], env=env, capture_output=True,
                                 text=True, timeout=60)
        assert refused.returncode == 2, refused.stderr
        assert refused.stderr.count("\n") == 1 and "--no-public-read" in refused.stderr
    chosen = subprocess.run([sys.executable, "-m", "service", "serve", "--host", "0.0.0.0",
                             "--tls-cert", "x.pem"], env={**env, "NIRC_BENCH_PUBLIC_READ": "0"},
                            capture_output=True, text=True, timeout=60)
    assert chosen.returncode == 2 and "public" not in chosen.stderr, chosen.stderr
    assert "--tls-" in chosen.stderr


def test_login_cookie_is_httponly_strict_and_authorizes_reads_only(private):
    url = private.url
    refused = httpx.post(f"{url}/api/v1/auth/login", json={"api_key": "nb_0_wrong"})
    assert refused.status_code == 403 and "set-cookie" not in refused.headers
    login = httpx.post(f"{url}/api/v1/auth/login", json={"api_key": private.key})
    assert login.status_code == 204, login.text
    flags = [part.strip().lower() for part in login.headers["set-cookie"].split(";")]
    assert flags[0].startswith(f"{COOKIE}=") and "httponly" in flags
    assert "samesite=strict" in flags and "path=/" in flags
    cookies = {COOKIE: login.cookies[COOKIE]}
    assert _status(f"{url}/api/v1/jobs", cookies=cookies) == 200
    # A cookie goes with any request the browser makes: it must not authorize a write.
    write = httpx.post(f"{url}/api/v1/jobs/1/cancel", cookies=cookies)
    assert write.status_code == 401
    logout = httpx.post(f"{url}/api/v1/auth/logout", cookies=cookies)
    assert logout.status_code == 204 and f'{COOKIE}=""' in logout.headers["set-cookie"]


def test_the_login_cookie_holds_a_session_not_the_key(private):
    """Before: the cookie held the API key itself for 30 days. After: a session token
    (its digest stored with the key's id), at most 12 hours, ended on the server by
    logging out: a copy of the cookie kept by an attacker stops working."""
    url = private.url
    login = httpx.post(f"{url}/api/v1/auth/login", json={"api_key": private.key})
    token = login.cookies[COOKIE]
    assert token and private.key not in login.headers["set-cookie"]
    secret = private.key.split("_", 2)[2]
    assert secret not in token and token not in private.key
    max_age = next(int(part.split("=")[1]) for part in login.headers["set-cookie"].split("; ")
                   if part.lower().startswith("max-age="))
    assert 0 < max_age <= 12 * 3600
    cookies = {COOKIE: token}
    assert _status(f"{url}/api/v1/jobs", cookies=cookies) == 200
    httpx.post(f"{url}/api/v1/auth/logout", cookies=cookies)
    stolen = httpx.get(f"{url}/api/v1/jobs", cookies=cookies)
    assert stolen.status_code == 401 and "log in again" in stolen.json()["detail"]
    assert _status(f"{url}/api/v1/jobs", cookies={COOKIE: private.key}) == 401


def test_a_lone_surrogate_in_json_is_422_not_500(private):
    """Before: `"\\ud800"` in a body (valid JSON, not Unicode) was a 500 on /jobs,
    /sweeps and the unauthenticated /auth/login. After: 422 in JSON naming the field."""
    url, key = private.url, {"X-API-Key": private.key, "Content-Type": "application/json"}
    for path, body, headers in (
            ("auth/login", '{"api_key": "nb_\\ud800_x"}', {"Content-Type": "application/json"}),
            ("jobs", '{"scene": "\\ud800", "method": "pt"}', key),
            ("sweeps", '{"scene": "cornell-box", "eps": [0.5], "params": {"\\udfff": 1}}', key)):
        answer = httpx.post(f"{url}/api/v1/{path}", content=body, headers=headers)
        assert answer.status_code == 422, (path, answer.text)
        assert "surrogate" in answer.json()["detail"][0]["msg"]


def test_every_answer_carries_security_headers(private):
    """Before: no Content-Security-Policy and no X-Frame-Options: any site could frame
    the dashboard, and an injected script would run. After: both, on every answer."""
    page = httpx.get(f"{private.url}/")
    policy = page.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in policy and "script-src 'self'" in policy
    assert "unsafe-inline" not in policy
    for answer in (page, httpx.get(f"{private.url}/api/v1/jobs"),
                   httpx.get(f"{private.url}/static/app.js")):
        assert answer.headers["x-frame-options"] == "DENY"
        assert answer.headers["x-content-type-options"] == "nosniff"


def test_a_plain_scheduler_off_loopback_is_refused_unless_allowed(tmp_path):
    """Before: `serve`/`worker --scheduler tcp://<other machine>` connected with only
    a warning. After: exit status 2 naming the setting that would allow it."""
    from service.cli import _with_tls

    env = service_env(tmp_path / "data")
    for command in (["serve", "--port", str(free_port())], ["worker"]):
        refused = subprocess.run([sys.executable, "-m", "service", *command, "--scheduler",
                                  "tcp://192.0.2.1:8786"], env=env, capture_output=True,
                                 text=True, timeout=60)
        assert refused.returncode == 2, refused.stderr
        assert "--allow-plaintext-scheduler" in refused.stderr
    allowed = _with_tls(ServiceSettings(data_dir=tmp_path), "tcp://192.0.2.1:8786", None, None,
                        None, allow_plaintext=True)
    assert allowed.allow_plaintext_scheduler


def test_openapi_declares_the_key_on_protected_operations(app_with):
    schema = app_with(False)[0].get("/openapi.json").json()
    schemes = schema["components"]["securitySchemes"]
    assert schemes["APIKeyHeader"] == {"type": "apiKey", "in": "header", "name": "X-API-Key",
                                       "description": schemes["APIKeyHeader"]["description"]}
    assert schemes["APIKeyCookie"]["in"] == "cookie"
    paths = schema["paths"]
    assert {"APIKeyHeader": []} in paths["/api/v1/jobs/{job_id}"]["get"]["security"]
    assert {"APIKeyCookie": []} in paths["/api/v1/results"]["get"]["security"]
    assert paths["/api/v1/jobs"]["post"]["security"] == [{"APIKeyHeader": []}]
    assert "security" not in paths["/api/v1/auth/login"]["post"]


def test_database_and_artifacts_are_owner_only(tmp_path):
    """Before: the data folder 0755, the SQLite file and artifacts 0644."""
    from jobs.record.artifacts import ArtifactStore

    data_dir = tmp_path / "data"
    open_store(Settings(data_dir=data_dir)).close()
    for name in ("nirc-bench.db", "nirc-bench.db-wal", "nirc-bench.db-shm"):
        if (data_dir / name).exists() or name == "nirc-bench.db":
            assert stat.S_IMODE((data_dir / name).stat().st_mode) == 0o600, name
    root = data_dir / "artifacts"
    blob = ArtifactStore(root).put_bytes(b"exr bytes", ".exr")
    assert stat.S_IMODE((root / blob.relpath).stat().st_mode) == 0o600
    for folder in (data_dir, root, (root / blob.relpath).parent):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder


@pytest.fixture
def site(tmp_path):
    """The app with public_read off, in a thread on loopback; and a key."""
    from jobs.execution.apikeys import create_api_key
    from service.api.main import create_app

    settings = ServiceSettings(data_dir=tmp_path / "data", public_read=False)
    store = open_store(settings)
    _, key = create_api_key(store, "browser")
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}", key
    server.should_exit = True
    thread.join(timeout=10)
    store.close()


def test_dashboard_asks_for_a_key_once(chromium, site):
    url, key = site
    page, errors = open_page(chromium, f"{url}/#/")
    page.wait_for_selector("form#login")
    page.fill("#api-key", "nb_0_wrong")
    page.click("form#login button")
    wait_until(page, "document.getElementById('login-error').textContent.includes('invalid')")
    page.fill("#api-key", key)
    page.click("form#login button")
    page.wait_for_selector("text=Latest results")
    cookie = next(c for c in page.context.cookies() if c["name"] == COOKIE)
    assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
    assert page.evaluate("document.cookie") == ""     # out of reach of page scripts
    page.goto(f"{url}/#/jobs")                          # a new page load: still logged in
    page.wait_for_selector("text=Jobs")
    page.close()
    assert [e for e in errors if "401" not in e and "403" not in e] == []


# ---- Scale-out over TLS ----

def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture(scope="module")
def certificates(tmp_path_factory) -> dict[str, Path]:
    """A throw-away CA and one certificate it signed (for 127.0.0.1, client and server)."""
    if subprocess.run(["which", "openssl"], capture_output=True).returncode != 0:
        pytest.fail("the TLS test needs the openssl command (apt-get install openssl)")
    folder = tmp_path_factory.mktemp("tls")
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out",
             "ca.pem", "-days", "2", "-subj", "/CN=nirc-bench test CA", "-addext",
             "basicConstraints=critical,CA:TRUE", "-addext",
             "keyUsage=critical,keyCertSign,cRLSign", cwd=folder)
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "node.key", "-out", "node.csr",
             "-subj", "/CN=127.0.0.1", cwd=folder)
    (folder / "node.ext").write_text(
        "basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature,keyEncipherment\n"
        "extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=IP:127.0.0.1\n"
        "authorityKeyIdentifier=keyid\nsubjectKeyIdentifier=hash\n")
    _openssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
             "-CAcreateserial", "-out", "node.pem", "-days", "2", "-extfile", "node.ext",
             cwd=folder)
    return {"ca": folder / "ca.pem", "cert": folder / "node.pem", "key": folder / "node.key"}


class TlsScheduler(Process):
    """A Dask scheduler on loopback that speaks only TLS and wants a certificate."""

    def __init__(self, certs: dict[str, Path]) -> None:
        self.port = free_port()
        self.address = f"tls://127.0.0.1:{self.port}"
        super().__init__([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host",
                          "127.0.0.1", "--port", str(self.port), "--protocol", "tls",
                          "--tls-ca-file", str(certs["ca"]), "--tls-cert", str(certs["cert"]),
                          "--tls-key", str(certs["key"]), "--no-dashboard"], dict(os.environ))

    def start(self) -> None:
        super().start()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with socket.socket() as sock:
                if sock.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            time.sleep(0.2)
        raise AssertionError("the Dask scheduler did not start")


def _refuses_a_client_without_certificate(port: int, ca: Path) -> bool:
    """Whether a TLS client that trusts the CA but has no certificate is turned away."""
    context = ssl.create_default_context(cafile=str(ca))
    context.check_hostname = False
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5) as raw, \
                context.wrap_socket(raw) as conn:
            conn.sendall(b"\0" * 8)
            return conn.recv(1) == b""      # TLS 1.3: the refusal arrives on the first read
    except (ssl.SSLError, ConnectionError):
        return True


def test_scale_out_over_tls_refuses_plain_connections(tmp_path, certificates):
    """Before: `serve --scheduler` and `worker` spoke plain TCP to a scheduler that runs
    whatever its clients send on the workers. After: with a tls:// scheduler and
    certificates, a worker joins and a job runs; a plain or certificate-less client is
    refused."""
    from distributed import Client
    from distributed.security import Security

    tls = ["--tls-ca-file", str(certificates["ca"]), "--tls-cert", str(certificates["cert"]),
           "--tls-key", str(certificates["key"])]
    data_dir = tmp_path / "data"
    scheduler = TlsScheduler(certificates)
    scheduler.start()
    worker = Worker(scheduler, data_dir)        # `nirc-bench worker --scheduler tls://...`
    worker.args += tls
    service = LiveService(data_dir, scheduler=scheduler.address, options=tls)
    try:
        worker.start()
        service.start()
        job = service.wait(service.submit(SPEC)["id"])
        assert job["status"] == "succeeded", job
        assert job["worker"].startswith("tls://127.0.0.1:"), job["worker"]
        with pytest.raises((OSError, TimeoutError)):
            Client(f"tcp://127.0.0.1:{scheduler.port}", timeout=3).close()
        assert _refuses_a_client_without_certificate(scheduler.port, certificates["ca"])
        security = Security(tls_ca_file=str(certificates["ca"]),
                            tls_client_cert=str(certificates["cert"]),
                            tls_client_key=str(certificates["key"]), require_encryption=True)
        with Client(scheduler.address, security=security, timeout=10) as client:
            assert all(address.startswith("tls://")
                       for address in client.scheduler_info()["workers"])
    finally:
        for process in (service, worker, scheduler):
            process.stop()
