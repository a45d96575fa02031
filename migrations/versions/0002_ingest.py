"""Ingest: videos, frame provenance, unique content per sequence.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-21 23:00:18.575741
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op


revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "videos",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("sequence_id", sa.Integer(), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("path", sa.String(length=500), nullable=False),
        sa.Column("original_name", sa.String(length=255), nullable=False),
        sa.Column("container", sa.String(length=16), nullable=False),
        sa.Column("size_bytes", sa.BigInteger(), nullable=False),
        sa.Column("width", sa.Integer(), nullable=False),
        sa.Column("height", sa.Integer(), nullable=False),
        sa.Column("fps", sa.Float(), nullable=False),
        sa.Column("frame_count", sa.Integer(), nullable=False),
        sa.Column("every_nth", sa.Integer(), nullable=False),
        sa.Column("job_id", sa.Integer(), nullable=True),
        sa.Column("uploaded_by_id", sa.Integer(), nullable=True),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.ForeignKeyConstraint(
            ["job_id"], ["jobs.id"], name=op.f("fk_videos_job_id_jobs"), ondelete="SET NULL"
        ),
        sa.ForeignKeyConstraint(
            ["sequence_id"],
            ["sequences.id"],
            name=op.f("fk_videos_sequence_id_sequences"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["uploaded_by_id"],
            ["users.id"],
            name=op.f("fk_videos_uploaded_by_id_users"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_videos")),
    )
    with op.batch_alter_table("videos", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_videos_sequence_id"), ["sequence_id"], unique=False)

    with op.batch_alter_table("frames", schema=None) as batch_op:
        batch_op.add_column(sa.Column("video_id", sa.Integer(), nullable=True))
        batch_op.drop_index(batch_op.f("ix_frames_sequence_sha"))
        batch_op.create_index(batch_op.f("ix_frames_video_id"), ["video_id"], unique=False)
        batch_op.create_index("uq_frames_sequence_sha", ["sequence_id", "sha256"], unique=True)
        batch_op.create_index(
            "uq_frames_unsequenced_sha",
            ["sha256"],
            unique=True,
            sqlite_where=sa.text("sequence_id IS NULL"),
            postgresql_where=sa.text("sequence_id IS NULL"),
        )
        batch_op.create_foreign_key(
            batch_op.f("fk_frames_video_id_videos"),
            "videos",
            ["video_id"],
            ["id"],
            ondelete="SET NULL",
        )


def downgrade() -> None:
    with op.batch_alter_table("frames", schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f("fk_frames_video_id_videos"), type_="foreignkey")
        batch_op.drop_index(
            "uq_frames_unsequenced_sha",
            sqlite_where=sa.text("sequence_id IS NULL"),
            postgresql_where=sa.text("sequence_id IS NULL"),
        )
        batch_op.drop_index("uq_frames_sequence_sha")
        batch_op.drop_index(batch_op.f("ix_frames_video_id"))
        batch_op.create_index(
            batch_op.f("ix_frames_sequence_sha"), ["sequence_id", "sha256"], unique=False
        )
        batch_op.drop_column("video_id")

    with op.batch_alter_table("videos", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_videos_sequence_id"))

    op.drop_table("videos")
