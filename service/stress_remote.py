"""``nirc-bench stress --server``: the stress suite's jobs run on a service.

Each case's scene is uploaded (``POST /api/v1/scenes``, the client reads its own
files, the service none), every method is submitted as a render job, and the
seeds' images are read back from the run's artifacts. The service does not
serve a reference's pixels, so unbiased methods are tested for agreement
against the baseline's seeds of the same case (jobs.stress.stress).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from jobs.protocol.spec import RenderSpec
from jobs.stress.stress import Outcome, Refused
from metrics.imageio import read_exr
from service.client import RemoteError, ServiceClient


class RemoteBackend:
    """A :class:`jobs.stress.stress.Backend` on the service ``client`` talks to."""

    against = "baseline"

    def __init__(self, client: ServiceClient,
                 progress: Callable[[str, int, int], None] | None = None) -> None:
        self.client, self.progress = client, progress

    def scene(self, path: Path) -> str:
        try:
            return self.client.upload_scene(str(path))
        except RemoteError as err:
            raise Refused(str(err)) from None

    def run(self, spec: RenderSpec) -> Outcome:
        job = self.client.submit("render", spec.model_dump(mode="json"))
        job = self.client.wait(job["id"], progress=self.progress)
        if job["status"] != "succeeded":
            raise RemoteError(f"job {job['id']} {job['status']}: {job['error']}")
        detail = self.client.get(f"/api/v1/runs/{job['run_id']}")
        images = [self._image(a["url"]) for a in detail["artifacts"] if a["kind"] == "image"]
        return Outcome(detail, images, None)

    def _image(self, url: str) -> np.ndarray:
        with tempfile.TemporaryDirectory(prefix="nirc-stress-") as folder:
            path = Path(folder) / "image.exr"
            path.write_bytes(self.client.download(url))
            return read_exr(path)
