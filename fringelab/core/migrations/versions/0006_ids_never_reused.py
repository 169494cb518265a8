"""Ids are never reused: SQLite tables with integer ids get AUTOINCREMENT.

Without it SQLite hands the id of the highest deleted row to the next insert, so an audit event or an old job
spec that names "recording 7" would then name another user's recording. PostgreSQL sequences never go back and
are left alone. Each table is rebuilt (SQLite cannot add AUTOINCREMENT in place) with foreign keys off, so that
dropping the old table cascades nowhere; the copied rows keep their ids and `sqlite_sequence` starts above them
(an id deleted above the highest remaining one before this migration can still be given once more).

Revision ID: 0006
Revises: 0005
"""

from __future__ import annotations

from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None

# Parents before children; every table with an integer id.
TABLES = ("users", "groups", "experiments", "cameras", "recordings", "calibrations", "api_tokens", "audit_events",
          "job_logs")  # fmt: skip


def _rebuild(autoincrement: bool) -> None:
    if op.get_bind().dialect.name != "sqlite":
        return
    with op.get_context().autocommit_block():
        op.execute("PRAGMA foreign_keys=OFF")
    for table in TABLES:
        with op.batch_alter_table(table, recreate="always", table_kwargs={"sqlite_autoincrement": autoincrement}):
            pass
    problems = op.get_bind().exec_driver_sql("PRAGMA foreign_key_check").fetchall()
    if problems:
        raise RuntimeError(f"foreign keys broken by the rebuild: {problems[:5]}")
    with op.get_context().autocommit_block():
        op.execute("PRAGMA foreign_keys=ON")


def upgrade() -> None:
    _rebuild(True)


def downgrade() -> None:
    _rebuild(False)
