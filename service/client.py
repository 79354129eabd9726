"""Submitting to a running service (``--server URL``) instead of running embedded."""

from __future__ import annotations

import io
import tarfile
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx

from jobs.record.models import FINAL_JOB_STATES

FINAL = tuple(state.value for state in FINAL_JOB_STATES)


#: Where a job of each kind is submitted, beside ``/api/v1/jobs`` (renders).
SUBMIT_PATHS = {"sweep": "sweeps", "reproduce": "reproductions"}


class RemoteError(RuntimeError):
    """The service refused a request or could not be reached (message says why)."""


def _detail(response: httpx.Response) -> str:
    try:
        detail = response.json().get("detail")
    except ValueError:
        detail = response.text
    return f"{response.status_code}: {detail}"


class ServiceClient:
    def __init__(self, server: str, api_key: str | None, timeout_s: float = 30.0) -> None:
        headers = {"X-API-Key": api_key} if api_key else {}
        self.http = httpx.Client(base_url=server.rstrip("/"), headers=headers,
                                 timeout=timeout_s)

    def _request(self, method: str, path: str, **kwargs: Any) -> Any:
        try:
            response = self.http.request(method, path, **kwargs)
        except httpx.HTTPError as err:
            raise RemoteError(f"cannot reach the service at {self.http.base_url}: {err}") from None
        if response.status_code >= 400:
            raise RemoteError(f"the service refused {method} {path}: {_detail(response)}")
        return response.json()

    def submit(self, kind: str, spec: dict[str, Any]) -> dict[str, Any]:
        return self._request("POST", f"/api/v1/{SUBMIT_PATHS.get(kind, 'jobs')}", json=spec)

    def upload_scene(self, path: str) -> str:
        """Upload the local Mitsuba XML scene at ``path`` with every file it reads and
        return its id on the service (``upload:<digest>``), to use as a job's scene.

        The service never reads the client's paths: the scene is vetted here as the
        service vets uploads (the same walk over includes and file references,
        here with the whole local filesystem allowed: the files are the user's own)
        and sent as a tar archive of the rewritten XML (``scene.xml``) and its files,
        spooled through a temporary file and streamed; the service vets it again under
        its own limits.
        """
        from renderers.scenes.vetting import Limits, blob_bytes, vet_root_scene

        scene = Path(path).expanduser().absolute()
        unlimited = Limits(max_file_bytes=1 << 62, max_total_bytes=1 << 62, max_files=1 << 30)
        staged = vet_root_scene(str(scene), [Path(scene.anchor)], unlimited)
        with tempfile.TemporaryFile() as archive:
            with tarfile.open(fileobj=archive, mode="w:") as tar:
                for name, blob in staged.files.items():
                    data = blob_bytes(blob)
                    info = tarfile.TarInfo(name)
                    info.size = len(data)
                    tar.addfile(info, io.BytesIO(data))
            archive.seek(0)
            return self._request("POST", "/api/v1/scenes", content=archive,
                                 headers={"Content-Type": "application/x-tar"})["id"]

    def get(self, path: str) -> Any:
        return self._request("GET", path)

    def download(self, path: str) -> bytes:
        """The raw body of ``GET path`` (an artifact's file)."""
        try:
            response = self.http.get(path)
        except httpx.HTTPError as err:
            raise RemoteError(f"cannot reach the service at {self.http.base_url}: {err}") from None
        if response.status_code >= 400:
            raise RemoteError(f"the service refused GET {path}: {_detail(response)}")
        return response.content

    def wait(self, job_id: int, progress: Callable[[str, int, int], None] | None = None,
             poll_s: float = 1.0) -> dict[str, Any]:
        """Long-poll the job until it is final (the answer comes as soon as it is),
        reporting its progress every ``poll_s`` (a sweep: how many of its stages are
        done, and the progress of each running stage)."""
        while True:
            asked = time.monotonic()
            job = self.get(f"/api/v1/jobs/{job_id}?wait_s={poll_s:g}")
            if progress:
                _report(job, progress)
            if job["status"] in FINAL:
                return job
            # A service that answered early (older, or capped by long_poll_max_s).
            time.sleep(max(0.0, poll_s - (time.monotonic() - asked)))


def _report(job: dict[str, Any], progress: Callable[[str, int, int], None]) -> None:
    stages = job.get("stages") or []
    if stages:
        done = sum(stage["status"] in FINAL for stage in stages)
        progress("stages", done, len(stages))
        for stage in stages:
            p = stage["progress"]
            if p:
                label = (stage["name"] if p["stage"] == stage["name"]
                         else f"{stage['name']}: {p['stage']}")
                progress(label, p["done"], p["total"])
    if job["progress"]:
        p = job["progress"]
        progress(p["stage"], p["done"], p["total"])
