"""simulation checks: a simulation is stored as received and read by a job in a worker (its state, the reason it
failed, its check job); the simulations registered before were read at upload, so they are ready

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-27 11:00:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("simulations", schema=None) as batch_op:
        batch_op.add_column(sa.Column("state", sa.String(length=16), nullable=False, server_default="ready"))
        batch_op.add_column(sa.Column("error", sa.Text(), nullable=False, server_default=""))
        batch_op.add_column(sa.Column("check_job_id", sa.String(length=36), nullable=True))
        batch_op.create_foreign_key(
            "fk_simulations_check_job_id_jobs", "jobs", ["check_job_id"], ["id"], ondelete="SET NULL"
        )
    with op.batch_alter_table("simulations", schema=None) as batch_op:  # the model's default is "checking"
        batch_op.alter_column("state", server_default=None)
        batch_op.alter_column("error", server_default=None)


def downgrade() -> None:
    with op.batch_alter_table("simulations", schema=None) as batch_op:
        batch_op.drop_constraint("fk_simulations_check_job_id_jobs", type_="foreignkey")
        batch_op.drop_column("check_job_id")
        batch_op.drop_column("error")
        batch_op.drop_column("state")
