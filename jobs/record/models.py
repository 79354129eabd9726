"""Database models of the job store: references, runs, per-seed results, cache
snapshots, sweeps, artifacts, queued jobs, API keys and dashboard sessions.

The SQL database is the durable record of every result (docs/results.md);
images live outside it, content-addressed, and are referenced
here by ``Artifact`` rows. Schema changes go through an Alembic revision in
``jobs/record/migrations/versions`` (a test checks that the models and the migrations
agree).

Relationships are ``lazy="raise"``: rows are used after their session closes
(``Store`` returns detached objects), so an attribute that was not loaded must
fail loudly instead of issuing a query on a closed session. ``Store`` loads what
each of its functions documents.
"""

from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    CheckConstraint,
    DateTime,
    Dialect,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

# Explicit constraint names: Alembic needs them to alter or drop constraints
# later (SQLite batch mode recreates tables and matches constraints by name).
NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


def utcnow() -> datetime:
    """The current time as an aware UTC datetime (the only kind stored)."""
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """A timestamp that is stored in UTC and always read back timezone-aware.

    SQLite has no timezone type and SQLAlchemy drops ``tzinfo`` when writing to
    it, so an aware non-UTC value would be silently shifted; converting to UTC
    first (and refusing naive values, whose zone is unknown) makes SQLite and
    PostgreSQL return the same instants.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError(
                f"naive datetime {value!r}: pass a timezone-aware time, e.g. datetime.now(UTC)"
            )
        value = value.astimezone(UTC)
        return value if dialect.name == "postgresql" else value.replace(tzinfo=None)

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {
        datetime: UTCDateTime(),
        dict[str, Any]: JSON(),
        list[Any]: JSON(),
    }


class RunStatus(StrEnum):
    """Final state of a run; a run row is written once, when it has finished."""

    SUCCEEDED = "succeeded"
    FAILED = "failed"


class Reference(Base):
    """A converged reference render, content-addressed by ``key`` and reused.

    ``key`` hashes everything that determines the image (scene fingerprint,
    resolution, reference integrator, max depth, reference settings), so a job
    looks it up before rendering and never renders an existing one twice.
    """

    __tablename__ = "reference_renders"  # "references" is an SQL keyword

    id: Mapped[int] = mapped_column(primary_key=True)
    key: Mapped[str] = mapped_column(String, unique=True)       # content address
    scene_name: Mapped[str] = mapped_column(String)
    scene_fingerprint: Mapped[str] = mapped_column(String)
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    integrator: Mapped[str] = mapped_column(String)             # 'path' or 'pt'
    max_depth: Mapped[int] = mapped_column(Integer)
    settings: Mapped[dict[str, Any]] = mapped_column(default=dict)  # ReferenceSettings.to_json()
    spp: Mapped[int] = mapped_column(Integer)                   # samples actually taken
    passes: Mapped[int] = mapped_column(Integer)
    rel_stderr: Mapped[float]                                   # reached, not targeted
    image_path: Mapped[str] = mapped_column(String)             # EXR mean
    variance_path: Mapped[str] = mapped_column(String)          # EXR variance of the mean
    split_half: Mapped[dict[str, Any]] = mapped_column(default=dict)  # half-vs-half: the floor
    flip_exposures: Mapped[list[Any]]                           # [start, stop], fixed per reference
    render_seconds: Mapped[float]
    device: Mapped[dict[str, Any]] = mapped_column(default=dict)
    versions: Mapped[dict[str, Any]] = mapped_column(default=dict)
    # "mitsuba <version>" for Mitsuba's path, "pt <version>" for ours ('1': before versions)
    estimator_version: Mapped[str] = mapped_column(String, server_default="1")
    metric_version: Mapped[int] = mapped_column(Integer, server_default="1")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    artifacts: Mapped[list["Artifact"]] = relationship(
        back_populates="reference",
        lazy="raise",
        order_by="Artifact.id",
        passive_deletes=True,
    )


class Run(Base):
    """One finished render job: a method on a scene, K seeds, aggregated metrics.

    Timings are only comparable between runs with equal ``device_key``.
    """

    __tablename__ = "runs"
    __table_args__ = (
        Index("ix_runs_scene_fingerprint_method", "scene_fingerprint", "method"),
        CheckConstraint(
            "status IN ('succeeded', 'failed')",
            name="status",
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    finished_at: Mapped[datetime | None]
    status: Mapped[str] = mapped_column(String)                 # a RunStatus value
    scene_name: Mapped[str] = mapped_column(String)
    scene_fingerprint: Mapped[str] = mapped_column(String)
    method: Mapped[str] = mapped_column(String)
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)  # method config, stored whole
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    spp: Mapped[int] = mapped_column(Integer)
    frames: Mapped[int] = mapped_column(Integer)
    seeds: Mapped[int] = mapped_column(Integer)                 # K independent renders
    # SET NULL: a reference whose files were lost may be deleted and rendered
    # again; the runs measured against it stay, without the link.
    reference_id: Mapped[int | None] = mapped_column(
        ForeignKey("reference_renders.id", ondelete="SET NULL"), index=True
    )
    metrics: Mapped[dict[str, Any]] = mapped_column(default=dict)     # aggregated over seeds
    timings: Mapped[dict[str, Any]] = mapped_column(default=dict)     # stages, warm-up, protocol
    path_stats: Mapped[dict[str, Any]] = mapped_column(default=dict)
    device: Mapped[dict[str, Any]] = mapped_column(default=dict)
    device_key: Mapped[str] = mapped_column(String, index=True)
    versions: Mapped[dict[str, Any]] = mapped_column(default=dict)
    git_commit: Mapped[str | None] = mapped_column(String)
    git_branch: Mapped[str | None] = mapped_column(String, index=True)   # None: not known
    quality: Mapped[dict[str, Any]] = mapped_column(default=dict)     # verdict, reasons, withheld
    # What computed the result (jobs.protocol.versions); 1 = stored before versions were recorded.
    estimator_version: Mapped[int] = mapped_column(Integer, server_default="1")
    metric_version: Mapped[int] = mapped_column(Integer, server_default="1")
    error: Mapped[str | None] = mapped_column(Text)
    idempotency_key: Mapped[str | None] = mapped_column(String, unique=True)
    name: Mapped[str | None] = mapped_column(String, index=True)        # the user's label
    tags: Mapped[dict[str, Any]] = mapped_column(default=dict, server_default=text("'{}'"))

    reference: Mapped[Reference | None] = relationship(lazy="raise")
    seed_results: Mapped[list["SeedResult"]] = relationship(
        back_populates="run",
        lazy="raise",
        order_by="SeedResult.seed",
        cascade="all, delete-orphan",
        passive_deletes=True,
    )
    # Every artifact of the run, including those that also belong to a seed.
    artifacts: Mapped[list["Artifact"]] = relationship(
        back_populates="run",
        lazy="raise",
        order_by="Artifact.id",
        cascade="all, delete-orphan",
        passive_deletes=True,
    )


class SeedResult(Base):
    """The metrics and timings of one of a run's K independent renders."""

    __tablename__ = "seed_results"
    __table_args__ = (UniqueConstraint("run_id", "seed"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    seed: Mapped[int] = mapped_column(Integer)
    metrics: Mapped[dict[str, Any]] = mapped_column(default=dict)
    timings: Mapped[dict[str, Any]] = mapped_column(default=dict)     # per frame / stage

    run: Mapped[Run] = relationship(back_populates="seed_results", lazy="raise")
    artifacts: Mapped[list["Artifact"]] = relationship(
        back_populates="seed_result",
        lazy="raise",
        order_by="Artifact.id",
        passive_deletes=True,
    )


class CacheSnapshot(Base):
    """A trained cache and its converged cache-at-v1 image (one method, scene, seed).

    The adaptive equal-bias sweep (NIRC paper Sec. 6.3) needs, per seed, a
    converged cache and the converged image of terminating into it at the first
    vertex; both are computed once per (scene, resolution, method parameters,
    training, seed) — ``key`` — and reused by every eps and every later sweep.
    Artifacts: the weights (.npz, with the v1 termination fraction per pixel)
    and the v1 image (.exr). ``stats`` holds the training loss, the convergence
    curve while training and the stage times.
    """

    __tablename__ = "cache_snapshots"

    id: Mapped[int] = mapped_column(primary_key=True)
    key: Mapped[str] = mapped_column(String, unique=True)
    scene_name: Mapped[str] = mapped_column(String)
    scene_fingerprint: Mapped[str] = mapped_column(String)
    method: Mapped[str] = mapped_column(String)
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)
    seed: Mapped[int] = mapped_column(Integer)
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    train_frames: Mapped[int] = mapped_column(Integer)
    v1_spp: Mapped[int] = mapped_column(Integer)
    reference_id: Mapped[int | None] = mapped_column(
        ForeignKey("reference_renders.id", ondelete="SET NULL")
    )
    stats: Mapped[dict[str, Any]] = mapped_column(default=dict)
    device: Mapped[dict[str, Any]] = mapped_column(default=dict)
    device_key: Mapped[str] = mapped_column(String)
    estimator_version: Mapped[int] = mapped_column(Integer, server_default="1")
    metric_version: Mapped[int] = mapped_column(Integer, server_default="1")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    artifacts: Mapped[list["Artifact"]] = relationship(
        back_populates="snapshot", lazy="raise", cascade="all, delete-orphan",
        passive_deletes=True,
    )


class Sweep(Base):
    """A sweep (e.g. the adaptive equal-bias protocol over eps): its spec and result.

    ``key`` addresses the spec on one device; re-running an identical sweep
    updates this row (its points are runs found by their idempotency keys).
    ``result`` holds the table rows (with run ids), calibrations and skipped
    methods; the plots are artifacts of the sweep.
    """

    __tablename__ = "sweeps"
    __table_args__ = (
        CheckConstraint("status IN ('running', 'succeeded', 'failed')", name="status"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    key: Mapped[str] = mapped_column(String, unique=True)
    kind: Mapped[str] = mapped_column(String)                   # 'eps' or 'nc'
    scene_name: Mapped[str] = mapped_column(String)
    scene_fingerprint: Mapped[str] = mapped_column(String)
    spec: Mapped[dict[str, Any]] = mapped_column(default=dict)
    status: Mapped[str] = mapped_column(String)
    result: Mapped[dict[str, Any]] = mapped_column(default=dict)
    device_key: Mapped[str] = mapped_column(String, index=True)
    # Method -> estimator version of the sweep's methods (None: before versions).
    estimator_versions: Mapped[dict[str, Any] | None]
    metric_version: Mapped[int] = mapped_column(Integer, server_default="1")
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    finished_at: Mapped[datetime | None]

    artifacts: Mapped[list["Artifact"]] = relationship(
        back_populates="sweep", lazy="raise", cascade="all, delete-orphan",
        passive_deletes=True,
    )


class Artifact(Base):
    """A file kept outside the database by content hash (see ``jobs.record.artifacts``).

    ``path`` is relative to ``Settings.artifacts_dir``. An artifact belongs to a
    run, a seed result of a run, a reference, a cache snapshot or a sweep (at
    least one of them).
    """

    __tablename__ = "artifacts"
    __table_args__ = (
        CheckConstraint(
            "run_id IS NOT NULL OR seed_result_id IS NOT NULL OR reference_id IS NOT NULL"
            " OR snapshot_id IS NOT NULL OR sweep_id IS NOT NULL",
            name="has_owner",
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    run_id: Mapped[int | None] = mapped_column(
        ForeignKey("runs.id", ondelete="CASCADE"), index=True
    )
    seed_result_id: Mapped[int | None] = mapped_column(
        ForeignKey("seed_results.id", ondelete="CASCADE"), index=True
    )
    reference_id: Mapped[int | None] = mapped_column(
        ForeignKey("reference_renders.id", ondelete="CASCADE"), index=True
    )
    snapshot_id: Mapped[int | None] = mapped_column(
        ForeignKey("cache_snapshots.id", ondelete="CASCADE"), index=True
    )
    sweep_id: Mapped[int | None] = mapped_column(
        ForeignKey("sweeps.id", ondelete="CASCADE"), index=True
    )
    kind: Mapped[str] = mapped_column(String)        # image, error_map, preview, variance, flip_map
    media_type: Mapped[str] = mapped_column(String)  # e.g. image/x-exr, image/png
    sha256: Mapped[str] = mapped_column(String, index=True)
    path: Mapped[str] = mapped_column(String)
    bytes: Mapped[int] = mapped_column(BigInteger)   # EXRs can pass 2 GiB at high resolution
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    run: Mapped[Run | None] = relationship(back_populates="artifacts", lazy="raise")
    seed_result: Mapped[SeedResult | None] = relationship(
        back_populates="artifacts", lazy="raise"
    )
    reference: Mapped[Reference | None] = relationship(back_populates="artifacts", lazy="raise")
    snapshot: Mapped[CacheSnapshot | None] = relationship(back_populates="artifacts",
                                                          lazy="raise")
    sweep: Mapped[Sweep | None] = relationship(back_populates="artifacts", lazy="raise")


class JobStatus(StrEnum):
    """Life cycle of a submitted job: queued -> running -> one of the final states.

    A running job whose worker died goes back to queued (another attempt) until
    its attempts are used up.
    """

    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELED = "canceled"


FINAL_JOB_STATES = (JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.CANCELED)
#: A spec has at most one job in these states (a new identical submission returns it);
#: the database enforces it (``uq_jobs_live_spec_key``).
DEDUPE_JOB_STATES = (JobStatus.QUEUED, JobStatus.RUNNING, JobStatus.SUCCEEDED)
#: The partial index's condition, the same text on SQLite and PostgreSQL.
LIVE_SPEC_KEY_WHERE = "status IN ('queued', 'running', 'succeeded')"


class Job(Base):
    """A submitted job (a render or a sweep), written before it is executed.

    The database is the queue's durable record: on start the service resubmits
    what is still queued or running. ``spec_key`` addresses the spec (equal
    specs dedupe to one live job); ``idempotency_key`` is the client's
    ``Idempotency-Key``. The result is ``run_id`` (render) or ``sweep_id``.
    A sweep runs as a task graph of *stage* jobs (kind ``stage``, ``parent_id``
    the sweep's job; jobs/execution/graph.py), each queued, retried and isolated like
    any job; a stage's ``work`` counts what it rendered and what it found
    stored (jobs/sweeps/sweep.py), and its sweep's result sums them.
    """

    __tablename__ = "jobs"
    __table_args__ = (
        CheckConstraint(
            "status IN ('queued', 'running', 'succeeded', 'failed', 'canceled')", name="status"
        ),
        CheckConstraint("kind IN ('render', 'sweep', 'stage', 'reproduce')", name="kind"),
        Index("ix_jobs_status_created_at", "status", "created_at"),
        # Exactly once: one live or succeeded job per spec (jobs.execution.queue.JobQueue.submit).
        Index("uq_jobs_live_spec_key", "spec_key", unique=True,
              sqlite_where=text(LIVE_SPEC_KEY_WHERE),
              postgresql_where=text(LIVE_SPEC_KEY_WHERE)),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(String)
    parent_id: Mapped[int | None] = mapped_column(
        ForeignKey("jobs.id", ondelete="CASCADE"), index=True)
    spec: Mapped[dict[str, Any]] = mapped_column(default=dict)
    spec_key: Mapped[str] = mapped_column(String, index=True)
    idempotency_key: Mapped[str | None] = mapped_column(String, unique=True)
    device_class: Mapped[str] = mapped_column(String, default="cpu")   # 'cpu' or 'gpu'
    status: Mapped[str] = mapped_column(String, default=JobStatus.QUEUED.value)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer, default=3)
    worker: Mapped[str | None] = mapped_column(String)
    error: Mapped[str | None] = mapped_column(Text)
    progress: Mapped[dict[str, Any]] = mapped_column(default=dict)
    cancel_requested: Mapped[bool] = mapped_column(default=False)
    run_id: Mapped[int | None] = mapped_column(ForeignKey("runs.id", ondelete="SET NULL"))
    sweep_id: Mapped[int | None] = mapped_column(ForeignKey("sweeps.id", ondelete="SET NULL"))
    work: Mapped[dict[str, Any] | None]
    # The API key (api_keys.id) that submitted it (a sweep's stages: the sweep's); None
    # for jobs of the CLI and those stored before owners were recorded. Only the owner
    # or an admin key may cancel it. No foreign key: keys are never deleted (a revoked
    # key keeps its row), and adding one would make SQLite rebuild this table.
    owner_key_id: Mapped[int | None] = mapped_column(Integer, index=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class ApiKey(Base):
    """An API key for the service's write endpoints, stored as a SHA-256 digest only.

    The key's first characters (``prefix``) find the row; the digest is then
    compared in constant time (``hmac.compare_digest``). An ``admin`` key may also
    cancel jobs of other keys.
    """

    __tablename__ = "api_keys"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String)
    prefix: Mapped[str] = mapped_column(String, unique=True)
    digest: Mapped[str] = mapped_column(String)
    admin: Mapped[bool] = mapped_column(default=False, server_default=text("false"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None]


class LoginSession(Base):
    """A dashboard login: the cookie holds a random token, the row only its SHA-256
    digest, the key it stands for and when it ends. Logging out deletes the row;
    revoking the key ends it too."""

    __tablename__ = "login_sessions"

    id: Mapped[int] = mapped_column(primary_key=True)
    digest: Mapped[str] = mapped_column(String, unique=True)
    api_key_id: Mapped[int] = mapped_column(ForeignKey("api_keys.id", ondelete="CASCADE"),
                                            index=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(index=True)
