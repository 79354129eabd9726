"""The job store's repository: the few reads and writes the executor and service need.

Every function runs in its own short transaction and returns *detached* model
objects (``expire_on_commit=False``) that stay usable after the session closes.
What each function loads is stated in its docstring; relationships that were
not loaded raise on access (``lazy="raise"`` in ``jobs.record.models``) rather than
querying a closed session.

Writes start with ``BEGIN IMMEDIATE`` on SQLite (see ``jobs.record.db``): the write
lock is taken up front, so concurrent writers queue on ``busy_timeout`` instead
of failing with "database is locked" when a read transaction tries to upgrade.
"""

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from datetime import datetime
from typing import Any

from sqlalchemy import Engine, and_, delete, false, or_, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, selectinload, sessionmaker

from jobs.record.models import Artifact, CacheSnapshot, Reference, Run, SeedResult, Sweep

# Execution option read by the SQLite "begin" hook in jobs.record.db; ignored elsewhere.
BEGIN_IMMEDIATE_OPTION = "nirc_bench_begin_immediate"

# Everything get_run() promises to load.
_RUN_DETAILS = (
    selectinload(Run.reference).selectinload(Reference.artifacts),
    selectinload(Run.seed_results).selectinload(SeedResult.artifacts),
    selectinload(Run.artifacts),
)


class DuplicateKeyError(ValueError):
    """A row with the same unique key already exists; ``existing`` is that row."""

    def __init__(self, message: str, existing: Reference | Run | CacheSnapshot) -> None:
        super().__init__(message)
        self.existing = existing


class Store:
    """Repository over one engine (SQLite or PostgreSQL); see ``jobs.record.db.open_store``."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self._read_sessions = sessionmaker(engine, expire_on_commit=False)
        self._write_sessions = sessionmaker(
            engine.execution_options(**{BEGIN_IMMEDIATE_OPTION: True}),
            expire_on_commit=False,
        )

    @contextmanager
    def session(self, *, write: bool = False) -> Iterator[Session]:
        """A session in one transaction: committed on exit, rolled back on error.

        Pass ``write=True`` when the session will write, so that SQLite takes the
        write lock at BEGIN (waiting up to busy_timeout) instead of mid-transaction.
        """
        factory = self._write_sessions if write else self._read_sessions
        with factory.begin() as session:
            yield session

    def close(self) -> None:
        """Release pooled connections (the engine stays usable; it reconnects)."""
        self.engine.dispose()

    # ---- References ----

    def find_reference(self, key: str) -> Reference | None:
        """The reference with this content key, with its artifacts loaded."""
        with self.session() as session:
            return session.scalars(
                select(Reference).where(Reference.key == key).options(
                    selectinload(Reference.artifacts)
                )
            ).one_or_none()

    def add_reference(
        self, *, artifacts: Sequence[Mapping[str, Any]] = (), **fields: Any
    ) -> Reference:
        """Insert a reference (``fields`` are ``Reference`` columns) and its artifacts.

        Raises ``DuplicateKeyError`` carrying the stored reference when one with
        the same ``key`` exists, e.g. when two sweep jobs rendered it at once:
        the caller can keep ``err.existing`` and drop its own copy.
        """
        reference = Reference(**fields)
        reference.artifacts = [Artifact(**a) for a in artifacts]
        try:
            with self.session(write=True) as session:
                session.add(reference)
        except IntegrityError as err:
            existing = self.find_reference(reference.key) if reference.key else None
            if existing is None:
                raise
            raise DuplicateKeyError(
                f"a reference with key {reference.key!r} already exists (id {existing.id})",
                existing,
            ) from err
        return reference

    def delete_reference(self, reference_id: int) -> bool:
        """Delete a reference row (e.g. its files were lost); False if it did not exist.

        The database cascades: its artifact rows go, and runs measured against
        it keep their results with ``reference_id`` set to NULL. Files on disk
        are left alone (other rows may share content-addressed files).
        """
        with self.session(write=True) as session:
            result = session.execute(delete(Reference).where(Reference.id == reference_id))
            return bool(result.rowcount)

    # ---- Runs ----

    def add_run(
        self,
        run_fields: Mapping[str, Any],
        seed_results: Sequence[Mapping[str, Any]] = (),
        artifacts: Sequence[Mapping[str, Any]] = (),
    ) -> Run:
        """Insert a finished run with its seed results and artifacts in ONE transaction.

        ``run_fields`` are ``Run`` columns, each of ``seed_results`` holds
        ``SeedResult`` columns (``seed``, ``metrics``, ``timings``), and each of
        ``artifacts`` holds ``Artifact`` columns plus an optional ``seed``: an
        artifact naming a seed belongs to that seed's result as well as to the
        run. Either everything is stored or nothing is.

        Returns the run as ``get_run`` does. Raises ``DuplicateKeyError``
        carrying the stored run when its ``idempotency_key`` is taken (a retried
        job), and ``ValueError`` for an artifact naming an unknown seed.
        """
        run = Run(**run_fields)
        by_seed: dict[int, SeedResult] = {}
        for fields in seed_results:
            result = SeedResult(**fields)
            if result.seed in by_seed:
                raise ValueError(f"seed {result.seed} appears twice in the seed results")
            by_seed[result.seed] = result
        run.seed_results = list(by_seed.values())
        run.artifacts = []
        for fields in artifacts:
            fields = dict(fields)
            seed = fields.pop("seed", None)
            artifact = Artifact(**fields)
            run.artifacts.append(artifact)
            if seed is not None:
                if seed not in by_seed:
                    raise ValueError(
                        f"artifact {artifact.kind!r} names seed {seed}, which has no seed result"
                    )
                by_seed[seed].artifacts.append(artifact)
        try:
            with self.session(write=True) as session:
                session.add(run)
        except IntegrityError as err:
            key = run.idempotency_key
            existing = self.find_run_by_idempotency_key(key) if key is not None else None
            if existing is None:
                raise
            raise DuplicateKeyError(
                f"a run with idempotency key {key!r} already exists (id {existing.id})",
                existing,
            ) from err
        # Re-read so the result has exactly the shape get_run() documents.
        stored = self.get_run(run.id)
        assert stored is not None  # just committed
        return stored

    def get_run(self, run_id: int) -> Run | None:
        """A run with its reference, seed results (by seed) and all artifacts loaded."""
        with self.session() as session:
            return session.scalars(
                select(Run).where(Run.id == run_id).options(*_RUN_DETAILS)
            ).one_or_none()

    def find_run_by_idempotency_key(self, key: str) -> Run | None:
        """The run stored under this idempotency key, loaded as by ``get_run``."""
        with self.session() as session:
            return session.scalars(
                select(Run).where(Run.idempotency_key == key).options(*_RUN_DETAILS)
            ).one_or_none()

    def list_runs(
        self,
        scene: str | None = None,
        method: str | None = None,
        device_key: str | None = None,
        *,
        limit: int | None = None,
        current: Mapping[str, int] | None = None,
        metric_version: int | None = None,
        git_ref: str | None = None,
        created_after: datetime | None = None,
        created_before: datetime | None = None,
    ) -> list[Run]:
        """Runs matching the given filters, newest first, without relationships.

        ``scene`` matches the scene name. ``current`` (method -> estimator version)
        keeps only runs of those methods at those versions, ``metric_version``
        only runs scored under it, ``git_ref`` only runs of that branch or of a
        commit starting with it, ``created_after`` / ``created_before`` only runs
        started at or after / before those times. Use ``get_run`` for seeds and
        artifacts.
        """
        query = select(Run).order_by(Run.created_at.desc(), Run.id.desc())
        if scene is not None:
            query = query.where(Run.scene_name == scene)
        if method is not None:
            query = query.where(Run.method == method)
        if device_key is not None:
            query = query.where(Run.device_key == device_key)
        if current is not None:
            query = query.where(or_(false(), *(and_(Run.method == name, Run.estimator_version == v)
                                             for name, v in current.items())))
        if metric_version is not None:
            query = query.where(Run.metric_version == metric_version)
        if git_ref is not None:
            query = query.where(or_(Run.git_branch == git_ref,
                                    Run.git_commit.startswith(git_ref, autoescape=True)))
        if created_after is not None:
            query = query.where(Run.created_at >= created_after)
        if created_before is not None:
            query = query.where(Run.created_at < created_before)
        if limit is not None:
            query = query.limit(limit)
        with self.session() as session:
            return list(session.scalars(query))

    def list_history_runs(self, scene: str, method: str, *, limit: int) -> list[Run]:
        """The newest ``limit`` succeeded runs of ``method`` on the scene named ``scene``,
        newest first, with their seed results loaded (the CI history,
        jobs/ci/history.py)."""
        query = (select(Run).where(Run.scene_name == scene, Run.method == method,
                                   Run.status == "succeeded")
                 .order_by(Run.created_at.desc(), Run.id.desc()).limit(limit)
                 .options(selectinload(Run.seed_results)))
        with self.session() as session:
            return list(session.scalars(query))

    def label_run(self, run_id: int, *, name: str | None = None,
                  set_tags: Mapping[str, str] | None = None,
                  remove_tags: Sequence[str] = ()) -> Run | None:
        """Give the run ``name`` (when given), add ``set_tags`` and drop ``remove_tags``;
        the run as ``get_run`` loads it, or None when there is no such run."""
        with self.session(write=True) as session:
            run = session.get(Run, run_id)
            if run is None:
                return None
            if name is not None:
                run.name = name
            tags = {**(run.tags or {}), **(set_tags or {})}
            run.tags = {key: value for key, value in tags.items() if key not in remove_tags}
        return self.get_run(run_id)

    def has_runs(self, *, scene: str | None = None, method: str | None = None) -> bool:
        """Whether any stored run has this scene name and/or method."""
        query = select(Run.id).limit(1)
        if scene is not None:
            query = query.where(Run.scene_name == scene)
        if method is not None:
            query = query.where(Run.method == method)
        with self.session() as session:
            return session.scalars(query).first() is not None

    # ---- Cache snapshots (the sweep's trained caches and cache-at-v1 images) ----

    def find_snapshot(self, key: str) -> CacheSnapshot | None:
        """The cache snapshot with this content key, with its artifacts loaded."""
        with self.session() as session:
            return session.scalars(
                select(CacheSnapshot).where(CacheSnapshot.key == key).options(
                    selectinload(CacheSnapshot.artifacts))
            ).one_or_none()

    def add_snapshot(self, *, artifacts: Sequence[Mapping[str, Any]] = (),
                     **fields: Any) -> CacheSnapshot:
        """Insert a snapshot (``CacheSnapshot`` columns) and its artifacts in one
        transaction; ``DuplicateKeyError`` carries the stored one if the key exists."""
        snapshot = CacheSnapshot(**fields)
        snapshot.artifacts = [Artifact(**a) for a in artifacts]
        try:
            with self.session(write=True) as session:
                session.add(snapshot)
        except IntegrityError as err:
            existing = self.find_snapshot(snapshot.key)
            if existing is None:
                raise
            raise DuplicateKeyError(
                f"a cache snapshot with key {snapshot.key!r} already exists (id {existing.id})",
                existing) from err
        return snapshot

    # ---- Sweeps ----

    def find_sweep(self, key: str) -> Sweep | None:
        """The sweep with this key, with its artifacts loaded."""
        with self.session() as session:
            return session.scalars(
                select(Sweep).where(Sweep.key == key).options(selectinload(Sweep.artifacts))
            ).one_or_none()

    def get_sweep(self, sweep_id: int) -> Sweep | None:
        """A sweep by id, with its artifacts loaded."""
        with self.session() as session:
            return session.scalars(
                select(Sweep).where(Sweep.id == sweep_id).options(selectinload(Sweep.artifacts))
            ).one_or_none()

    def start_sweep(self, **fields: Any) -> Sweep:
        """The sweep row of ``fields['key']``, created or (re-run) set back to running."""
        with self.session(write=True) as session:
            sweep = session.scalars(
                select(Sweep).where(Sweep.key == fields["key"])).one_or_none()
            if sweep is None:
                sweep = Sweep(**fields, status="running")
                session.add(sweep)
            else:
                sweep.status, sweep.finished_at = "running", None
            session.flush()
            return sweep

    def finish_sweep(self, sweep_id: int, *, status: str, result: dict[str, Any],
                     finished_at: Any, artifacts: Sequence[Mapping[str, Any]] = ()) -> Sweep:
        """Store a sweep's outcome; its artifacts (plots) replace the previous ones."""
        with self.session(write=True) as session:
            sweep = session.get(Sweep, sweep_id)
            if sweep is None:
                raise ValueError(f"no sweep with id {sweep_id}")
            sweep.status, sweep.result, sweep.finished_at = status, result, finished_at
            session.execute(delete(Artifact).where(Artifact.sweep_id == sweep_id))
            for fields in artifacts:
                session.add(Artifact(**fields, sweep_id=sweep_id))
        stored = self.get_sweep(sweep_id)
        assert stored is not None
        return stored

    def delete_snapshot(self, snapshot_id: int) -> bool:
        """Delete a snapshot row and its artifact rows (e.g. its files were lost)."""
        with self.session(write=True) as session:
            result = session.execute(delete(CacheSnapshot).where(CacheSnapshot.id == snapshot_id))
            return bool(result.rowcount)

    def clone_run(self, run_id: int, *, idempotency_key: str,
                  metrics_update: Mapping[str, Any]) -> Run:
        """A new run with the results of ``run_id`` (seed results, artifacts) plus
        ``metrics_update``: e.g. a calibration that chose exactly the settings of
        an existing run, recorded as a point of its own without rendering again."""
        source = self.get_run(run_id)
        if source is None:
            raise ValueError(f"no run with id {run_id}")
        columns = {c.key: getattr(source, c.key) for c in Run.__table__.columns
                   if c.key not in ("id", "idempotency_key")}
        columns["metrics"] = {**source.metrics, **metrics_update}
        columns["params"] = {**source.params, **metrics_update}
        seeds = {result.id: result.seed for result in source.seed_results}
        artifact_columns = ("kind", "media_type", "sha256", "path", "bytes")
        return self.add_run(
            {**columns, "idempotency_key": idempotency_key},
            [{"seed": r.seed, "metrics": r.metrics, "timings": r.timings}
             for r in source.seed_results],
            [{**{c: getattr(a, c) for c in artifact_columns},
              "seed": seeds.get(a.seed_result_id)} for a in source.artifacts],
        )

    def list_sweeps(self, scene: str | None = None, *, limit: int = 50,
                    metric_version: int | None = None) -> list[Sweep]:
        """Sweeps, newest first, with their artifacts loaded (only those scored under
        ``metric_version`` when it is given)."""
        query = (select(Sweep).order_by(Sweep.id.desc()).limit(limit)
                 .options(selectinload(Sweep.artifacts)))
        if scene is not None:
            query = query.where(Sweep.scene_name == scene)
        if metric_version is not None:
            query = query.where(Sweep.metric_version == metric_version)
        with self.session() as session:
            return list(session.scalars(query))

    def get_reference(self, reference_id: int) -> Reference | None:
        with self.session() as session:
            return session.get(Reference, reference_id)
