"""Settings of the job store: where the data folder and the database live.

Read from environment variables with the prefix ``NIRC_BENCH_`` (e.g.
``NIRC_BENCH_DATA_DIR``, ``NIRC_BENCH_DATABASE_URL``), in the style of the
FastAPI full-stack template's ``core/config.py``. The embedded default keeps
everything in ``./data`` under the working directory: a SQLite database plus
the artifact and reference folders beside it. Scenes over REST are limited to
built-ins, uploads and the configured scene roots (docs/service.md).

What only the service reads (HTTP access and limits, the scale-out scheduler's TLS)
is the service's own configuration: ``service/config.py``, which extends these.
"""

import json
import os
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

DATABASE_FILENAME = "nirc-bench.db"


class Settings(BaseSettings):
    """Store settings; ``database_url`` is always a string after validation."""

    model_config = SettingsConfigDict(env_prefix="NIRC_BENCH_", extra="ignore")

    # Resolved at construction (not import) time so that a test or a CLI call
    # that changes directory or environment sees its own working directory.
    data_dir: Path = Field(default_factory=lambda: Path.cwd() / "data")
    # None means "the embedded SQLite database inside data_dir".
    database_url: str | None = None
    # A running job whose runner has not renewed its heartbeat for this long is
    # taken over by another runner (its worker or the service died).
    job_lease_s: float = Field(30.0, gt=0.0)
    # How long a database statement waits for a lock held by another connection before
    # it fails (SQLite busy_timeout, PostgreSQL lock_timeout); a runner that cannot
    # renew its heartbeat for a whole lease gives its job up to be taken over.
    db_lock_timeout_s: float = Field(30.0, gt=0.0)
    # How often the service looks for jobs that nothing runs (queued ones whose task
    # ended without claiming them, running ones whose lease expired) and dispatches
    # them again (jobs/execution/dispatch.py).
    redispatch_interval_s: float = Field(10.0, gt=0.0)
    # ---- Bounded work and disk (docs/operations.md; estimates in jobs/execution/work.py) ----
    # The most path samples (pixels x spp x frames x seeds, references and sweep
    # stages included) one submission may ask for; more is refused with 422.
    max_job_work: int = Field(100_000_000_000, ge=1)
    # The longest one submission may be estimated to run on this device, from measured
    # costs (jobs/execution/timecost.py); longer is refused with 422. None: no limit.
    max_job_seconds: float | None = Field(3600.0, gt=0.0)
    # The most stage jobs one sweep may make (seeds x methods + 2, or N_c values + 1).
    max_sweep_stages: int = Field(256, ge=1)
    # Without --job-timeout an attempt gets job_timeout_min_s plus its estimated
    # samples at timeout_samples_per_s (a slow machine's rate: a generous bound).
    job_timeout_min_s: float = Field(600.0, gt=0.0)
    timeout_samples_per_s: float = Field(1_000_000.0, gt=0.0)
    # Per API key: the most unfinished (queued or running) jobs and sweeps it may hold
    # (a submission beyond is answered 429), and the most jobs (a sweep's stages
    # included) it may run at once (a claim beyond waits, so that one key cannot
    # hold every worker). None: no limit.
    max_jobs_per_key: int | None = Field(100, ge=1)
    max_running_jobs_per_key: int | None = Field(4, ge=1)
    # Disk: None means no limit; with a limit, a submission whose estimated files would
    # take the data folder past it is refused (507).
    max_data_bytes: int | None = Field(None, ge=0)
    # Per API key: the bytes its stored results (its runs' and sweeps' artifacts), its
    # uploads (scenes, images) and the estimated files of its unfinished jobs may take;
    # a submission or upload past it is refused (507). None or 0: no quota.
    key_quota_bytes: int | None = Field(10 * 2**30, ge=0)
    # Free-space floor: new jobs, sweeps and uploads are refused (507) while the data
    # folder's filesystem has less free than the larger of these two.
    min_free_bytes: int = Field(2 * 2**30, ge=0)
    min_free_fraction: float = Field(0.05, ge=0.0, le=1.0)
    # `nirc-bench gc` removes unreferenced files, scenes and references older than this.
    gc_keep_days: float = Field(30.0, ge=0.0)
    # Retention of results' files (jobs/record/gc.py): `nirc-bench gc` removes the
    # artifacts (images, previews, plots; the results' rows stay) of runs and sweeps
    # older than artifact_keep_days, and the oldest first while the artifact store is
    # over artifact_max_bytes. None: no such limit.
    artifact_keep_days: float | None = Field(365.0, gt=0.0)
    artifact_max_bytes: int | None = Field(None, ge=0)
    # The service applies that retention on its own every retention_interval_h hours
    # (the first round one interval after it starts). None or 0: only `nirc-bench gc`.
    retention_interval_h: float | None = Field(24.0, ge=0.0)
    # Folders whose Mitsuba XML scenes REST clients may name by path (docs/service.md);
    # none by default. The environment variable is a JSON list or an os.pathsep-
    # separated one: NIRC_BENCH_SCENE_ROOTS=/srv/scenes:/data/more-scenes.
    scene_roots: Annotated[list[Path], NoDecode] = Field(default_factory=list)
    # The size limit of scenes (each file, all files together) is one for every scene,
    # by path or over REST, read where it is used: renderers.scenes.vetting.scene_limits.

    @field_validator("key_quota_bytes", "retention_interval_h")
    @classmethod
    def _zero_is_off(cls, value: float | None) -> float | None:
        return value or None

    @field_validator("scene_roots", mode="before")
    @classmethod
    def _split_scene_roots(cls, value: Any) -> Any:
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                return json.loads(text)
            return [part for part in text.split(os.pathsep) if part.strip()]
        return value

    @field_validator("scene_roots")
    @classmethod
    def _absolute_scene_roots(cls, value: list[Path]) -> list[Path]:
        return [root.expanduser().absolute() for root in value]

    @field_validator("data_dir")
    @classmethod
    def _absolute_data_dir(cls, value: Path) -> Path:
        # An absolute path keeps the SQLite URL and the artifact paths valid if
        # the process later changes directory (workers, test fixtures).
        return value.expanduser().absolute()

    @model_validator(mode="after")
    def _default_database_url(self) -> "Settings":
        if not self.database_url:
            self.database_url = f"sqlite:///{(self.data_dir / DATABASE_FILENAME).as_posix()}"
        return self

    @property
    def artifacts_dir(self) -> Path:
        """Root of the content-addressed artifact files (EXR, PNG, error maps)."""
        return self.data_dir / "artifacts"

    @property
    def scenes_dir(self) -> Path:
        """Folder of the stored (uploaded or staged) scenes, one folder per id digest."""
        return self.data_dir / "scenes"

    @property
    def uploaded_images_dir(self) -> Path:
        """Folder of the EXR images users upload to compare runs against
        (``<key id>/<run id>/<sha256>.exr``)."""
        return self.data_dir / "uploaded_images"

    @property
    def references_dir(self) -> Path:
        """Folder for converged reference images and their variance images."""
        return self.data_dir / "references"

    @property
    def reproductions_dir(self) -> Path:
        """Folder of the reproduced papers' figures, one folder per figure
        (``<paper>-<figure>``, a service job's in its ``job-<id>``; jobs/reproduce)."""
        return self.data_dir / "reproduce"


def get_settings() -> Settings:
    """Fresh settings from the current environment.

    Deliberately not cached: constructing settings is cheap, and a cache would
    hide environment changes made by tests or by the CLI's ``--data-dir``.
    """
    return Settings()
