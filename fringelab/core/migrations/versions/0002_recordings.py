"""recordings: the upload a recording came from, the recording it duplicates, its latest ingest job

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-21 01:08:49.540159
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("recordings", schema=None) as batch_op:
        batch_op.add_column(sa.Column("upload_id", sa.String(length=64), nullable=True))
        batch_op.add_column(sa.Column("duplicate_of", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("ingest_job_id", sa.String(length=36), nullable=True))
        batch_op.create_index(batch_op.f("ix_recordings_upload_id"), ["upload_id"], unique=True)
        batch_op.create_foreign_key(
            "fk_recordings_duplicate_of_recordings", "recordings", ["duplicate_of"], ["id"], ondelete="SET NULL"
        )
        batch_op.create_foreign_key(
            "fk_recordings_ingest_job_id_jobs", "jobs", ["ingest_job_id"], ["id"], ondelete="SET NULL"
        )


def downgrade() -> None:
    with op.batch_alter_table("recordings", schema=None) as batch_op:
        batch_op.drop_constraint("fk_recordings_ingest_job_id_jobs", type_="foreignkey")
        batch_op.drop_constraint("fk_recordings_duplicate_of_recordings", type_="foreignkey")
        batch_op.drop_index(batch_op.f("ix_recordings_upload_id"))
        batch_op.drop_column("ingest_job_id")
        batch_op.drop_column("duplicate_of")
        batch_op.drop_column("upload_id")
