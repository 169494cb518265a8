"""simulations' checked store counted in the quota: the bytes of `checked.h5`, which the check job writes beside
the upload (about as large as the model again); 0 for simulations checked before (their store is counted from
their next check on)

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-27 14:40:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("simulations", schema=None) as batch_op:
        batch_op.add_column(sa.Column("checked_bytes", sa.BigInteger(), nullable=False, server_default="0"))


def downgrade() -> None:
    with op.batch_alter_table("simulations", schema=None) as batch_op:
        batch_op.drop_column("checked_bytes")
