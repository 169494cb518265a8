"""cameras: the pixel pitch along v (image rows) beside the one along u; empty means square pixels

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-23 04:35:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("cameras") as batch:
        batch.add_column(sa.Column("pixel_pitch_v_um", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("cameras") as batch:
        batch.drop_column("pixel_pitch_v_um")
