"""Initial schema: reference renders, runs, seed results, artifacts.

Revision ID: 0001
Revises:
Create Date: 2026-11-22 02:31:33.343139
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "reference_renders",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("key", sa.String(), nullable=False),
        sa.Column("scene_name", sa.String(), nullable=False),
        sa.Column("scene_fingerprint", sa.String(), nullable=False),
        sa.Column("width", sa.Integer(), nullable=False),
        sa.Column("height", sa.Integer(), nullable=False),
        sa.Column("integrator", sa.String(), nullable=False),
        sa.Column("max_depth", sa.Integer(), nullable=False),
        sa.Column("settings", sa.JSON(), nullable=False),
        sa.Column("spp", sa.Integer(), nullable=False),
        sa.Column("passes", sa.Integer(), nullable=False),
        sa.Column("rel_stderr", sa.Double(), nullable=False),
        sa.Column("image_path", sa.String(), nullable=False),
        sa.Column("variance_path", sa.String(), nullable=False),
        sa.Column("split_half", sa.JSON(), nullable=False),
        sa.Column("flip_exposures", sa.JSON(), nullable=False),
        sa.Column("render_seconds", sa.Double(), nullable=False),
        sa.Column("device", sa.JSON(), nullable=False),
        sa.Column("versions", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_reference_renders")),
        sa.UniqueConstraint("key", name=op.f("uq_reference_renders_key")),
    )
    op.create_table(
        "runs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("status", sa.String(), nullable=False),
        sa.Column("scene_name", sa.String(), nullable=False),
        sa.Column("scene_fingerprint", sa.String(), nullable=False),
        sa.Column("method", sa.String(), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("width", sa.Integer(), nullable=False),
        sa.Column("height", sa.Integer(), nullable=False),
        sa.Column("spp", sa.Integer(), nullable=False),
        sa.Column("frames", sa.Integer(), nullable=False),
        sa.Column("seeds", sa.Integer(), nullable=False),
        sa.Column("reference_id", sa.Integer(), nullable=True),
        sa.Column("metrics", sa.JSON(), nullable=False),
        sa.Column("timings", sa.JSON(), nullable=False),
        sa.Column("path_stats", sa.JSON(), nullable=False),
        sa.Column("device", sa.JSON(), nullable=False),
        sa.Column("device_key", sa.String(), nullable=False),
        sa.Column("versions", sa.JSON(), nullable=False),
        sa.Column("git_commit", sa.String(), nullable=True),
        sa.Column("quality", sa.JSON(), nullable=False),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("idempotency_key", sa.String(), nullable=True),
        sa.CheckConstraint("status IN ('succeeded', 'failed')", name=op.f("ck_runs_status")),
        sa.ForeignKeyConstraint(
            ["reference_id"],
            ["reference_renders.id"],
            name=op.f("fk_runs_reference_id_reference_renders"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_runs")),
        sa.UniqueConstraint("idempotency_key", name=op.f("uq_runs_idempotency_key")),
    )
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_runs_created_at"), ["created_at"], unique=False)
        batch_op.create_index(batch_op.f("ix_runs_device_key"), ["device_key"], unique=False)
        batch_op.create_index(batch_op.f("ix_runs_reference_id"), ["reference_id"], unique=False)
        batch_op.create_index(
            "ix_runs_scene_fingerprint_method", ["scene_fingerprint", "method"], unique=False
        )

    op.create_table(
        "seed_results",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=False),
        sa.Column("metrics", sa.JSON(), nullable=False),
        sa.Column("timings", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["run_id"], ["runs.id"], name=op.f("fk_seed_results_run_id_runs"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_seed_results")),
        sa.UniqueConstraint("run_id", "seed", name=op.f("uq_seed_results_run_id_seed")),
    )
    with op.batch_alter_table("seed_results", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_seed_results_run_id"), ["run_id"], unique=False)

    op.create_table(
        "artifacts",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=True),
        sa.Column("seed_result_id", sa.Integer(), nullable=True),
        sa.Column("reference_id", sa.Integer(), nullable=True),
        sa.Column("kind", sa.String(), nullable=False),
        sa.Column("media_type", sa.String(), nullable=False),
        sa.Column("sha256", sa.String(), nullable=False),
        sa.Column("path", sa.String(), nullable=False),
        sa.Column("bytes", sa.BigInteger(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint(
            "run_id IS NOT NULL OR seed_result_id IS NOT NULL OR reference_id IS NOT NULL",
            name=op.f("ck_artifacts_has_owner"),
        ),
        sa.ForeignKeyConstraint(
            ["reference_id"],
            ["reference_renders.id"],
            name=op.f("fk_artifacts_reference_id_reference_renders"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["run_id"], ["runs.id"], name=op.f("fk_artifacts_run_id_runs"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["seed_result_id"],
            ["seed_results.id"],
            name=op.f("fk_artifacts_seed_result_id_seed_results"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_artifacts")),
    )
    with op.batch_alter_table("artifacts", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_artifacts_reference_id"), ["reference_id"], unique=False
        )
        batch_op.create_index(batch_op.f("ix_artifacts_run_id"), ["run_id"], unique=False)
        batch_op.create_index(
            batch_op.f("ix_artifacts_seed_result_id"), ["seed_result_id"], unique=False
        )
        batch_op.create_index(batch_op.f("ix_artifacts_sha256"), ["sha256"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("artifacts", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_artifacts_sha256"))
        batch_op.drop_index(batch_op.f("ix_artifacts_seed_result_id"))
        batch_op.drop_index(batch_op.f("ix_artifacts_run_id"))
        batch_op.drop_index(batch_op.f("ix_artifacts_reference_id"))

    op.drop_table("artifacts")
    with op.batch_alter_table("seed_results", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_seed_results_run_id"))

    op.drop_table("seed_results")
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.drop_index("ix_runs_scene_fingerprint_method")
        batch_op.drop_index(batch_op.f("ix_runs_reference_id"))
        batch_op.drop_index(batch_op.f("ix_runs_device_key"))
        batch_op.drop_index(batch_op.f("ix_runs_created_at"))

    op.drop_table("runs")
    op.drop_table("reference_renders")
