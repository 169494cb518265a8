"""Database tables (SQLAlchemy 2 declarative). API schemas live apart from these, in `backend/schemas/`.

The job row is the source of truth for a job's state; Celery only carries it out.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    # Named constraints, so that migrations can alter them on SQLite (batch mode) and PostgreSQL alike.
    metadata = MetaData(
        naming_convention={
            "ix": "ix_%(column_0_label)s",
            "uq": "uq_%(table_name)s_%(column_0_name)s",
            "ck": "ck_%(table_name)s_%(constraint_name)s",
            "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
            "pk": "pk_%(table_name)s",
        }
    )
    type_annotation_map = {dict[str, Any]: JSON, list[Any]: JSON}


class Experiment(Base):
    __tablename__ = "experiments"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    plate: Mapped[str] = mapped_column(String(200), default="")
    punch: Mapped[str] = mapped_column(String(200), default="")
    test_date: Mapped[str] = mapped_column(String(10), default="")
    notes: Mapped[str] = mapped_column(Text, default="")
    # Ownership (used when auth is on): the owner, and a group that may read or write the experiment.
    owner_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True, index=True)
    group_id: Mapped[int | None] = mapped_column(ForeignKey("groups.id", ondelete="SET NULL"), nullable=True)
    group_access: Mapped[str] = mapped_column(String(8), default="read")  # read | write
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow, onupdate=utcnow)

    cameras: Mapped[list[Camera]] = relationship(back_populates="experiment", cascade="all, delete-orphan")
    simulations: Mapped[list[Simulation]] = relationship(back_populates="experiment", cascade="all, delete-orphan")
    owner: Mapped[User | None] = relationship()
    group: Mapped[Group | None] = relationship()


class Camera(Base):
    __tablename__ = "cameras"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    experiment_id: Mapped[int] = mapped_column(ForeignKey("experiments.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(100))
    image_width_px: Mapped[int] = mapped_column(Integer)
    image_height_px: Mapped[int] = mapped_column(Integer)
    # Pixel pitch along u (a row: the image's width) and along v (a column); v empty means square pixels.
    pixel_pitch_um: Mapped[float] = mapped_column(Float)
    pixel_pitch_v_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)

    experiment: Mapped[Experiment] = relationship(back_populates="cameras")

    @property
    def pixel_pitch_uv_um(self) -> tuple[float, float]:
        """(pitch along u, pitch along v) in µm: D_u = 1000 / pitch_u px/mm, D_v = 1000 / pitch_v px/mm."""
        return self.pixel_pitch_um, self.pixel_pitch_v_um or self.pixel_pitch_um

    recordings: Mapped[list[Recording]] = relationship(back_populates="camera", cascade="all, delete-orphan")


class Recording(Base):
    __tablename__ = "recordings"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(32))  # camera_calibration | projector_calibration | test
    state: Mapped[str] = mapped_column(String(16), default="uploading")  # uploading|ingesting|ready|invalid
    filename: Mapped[str] = mapped_column(String(255), default="")
    format: Mapped[str] = mapped_column(String(32), default="")
    path: Mapped[str] = mapped_column(String(500), default="")  # relative to the data directory
    size_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    sha256: Mapped[str] = mapped_column(String(64), default="", index=True)
    frame_count: Mapped[int] = mapped_column(Integer, default=0)
    width_px: Mapped[int] = mapped_column(Integer, default=0)
    height_px: Mapped[int] = mapped_column(Integer, default=0)
    bit_depth: Mapped[int] = mapped_column(Integer, default=0)
    fps: Mapped[float | None] = mapped_column(Float, nullable=True)
    sidecar: Mapped[dict[str, Any]] = mapped_column(default=dict)
    qa: Mapped[dict[str, Any]] = mapped_column(default=dict)
    error: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    # The tus upload it came from (None for a plain PUT): a client that lost the last response finds it by this.
    upload_id: Mapped[str | None] = mapped_column(String(64), nullable=True, unique=True, index=True)
    # An earlier recording with the same bytes (same SHA-256); the file is stored once, hard-linked.
    duplicate_of: Mapped[int | None] = mapped_column(ForeignKey("recordings.id", ondelete="SET NULL"), nullable=True)
    ingest_job_id: Mapped[str | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"), nullable=True)

    camera: Mapped[Camera] = relationship(back_populates="recordings")


class Simulation(Base):
    """A finite-element simulation uploaded into an experiment (one file, or a ZIP of a folder format). Stored as
    received (`checking`), then read by its check job in a worker (`worker.jobs.simulation_check`): `ready` with
    what it holds, or `failed` with the reason in `error`. Only a ready one can be compared."""

    __tablename__ = "simulations"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    experiment_id: Mapped[int] = mapped_column(ForeignKey("experiments.id", ondelete="CASCADE"), index=True)
    filename: Mapped[str] = mapped_column(String(255), default="")
    kind: Mapped[str] = mapped_column(String(32), default="")  # d3plot | vtu | pvd | exodus | csv
    path: Mapped[str] = mapped_column(String(500), default="")  # the file or folder, relative to the data directory
    size_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    sha256: Mapped[str] = mapped_column(String(64), default="")
    n_states: Mapped[int] = mapped_column(Integer, default=0)
    n_nodes: Mapped[int] = mapped_column(Integer, default=0)
    info: Mapped[dict[str, Any]] = mapped_column(default=dict)  # time range, punch and force present, units
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    state: Mapped[str] = mapped_column(String(16), default="checking")  # checking | ready | failed
    error: Mapped[str] = mapped_column(Text, default="")  # why it failed, for people
    check_job_id: Mapped[str | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"), nullable=True)
    # What the check stored beside the upload (`checked.h5`), counted in its owner's quota with `size_bytes`.
    checked_bytes: Mapped[int] = mapped_column(BigInteger, default=0)

    experiment: Mapped[Experiment] = relationship(back_populates="simulations")


class Job(Base):
    __tablename__ = "jobs"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)  # also the Celery task id
    kind: Mapped[str] = mapped_column(String(32), index=True)
    state: Mapped[str] = mapped_column(String(16), default="queued", index=True)
    spec: Mapped[dict[str, Any]] = mapped_column(default=dict)
    experiment_id: Mapped[int | None] = mapped_column(
        ForeignKey("experiments.id", ondelete="SET NULL"), nullable=True, index=True
    )
    stage: Mapped[str] = mapped_column(String(100), default="")
    progress_done: Mapped[int] = mapped_column(Integer, default=0)
    progress_total: Mapped[int] = mapped_column(Integer, default=0)
    error: Mapped[str] = mapped_column(Text, default="")
    worker: Mapped[str] = mapped_column(String(200), default="")
    result: Mapped[dict[str, Any]] = mapped_column(default=dict)
    provenance: Mapped[dict[str, Any]] = mapped_column(default=dict)
    attempt: Mapped[int] = mapped_column(Integer, default=1)
    retry_of: Mapped[str | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"), nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    # When the current stage began (for the ETA) and when a worker last said it is alive (for reconciliation).
    stage_started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    # Result files: [{"name", "path" (relative to the data directory), "size_bytes", "sha256", "media_type"}].
    files: Mapped[list[Any]] = mapped_column(default=list)
    # Times the server re-sent this job's tasks because the broker had lost them (capped; see fringelab.core.jobs).
    requeues: Mapped[int] = mapped_column(Integer, default=0)
    # A chunked job's current phase (0, 1, ...: chunks in parallel, then a merge that may start the next phase),
    # and when that phase's merge task was sent (claimed once, so that two last chunks cannot both send it).
    phase: Mapped[int] = mapped_column(Integer, default=0)
    merge_queued_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)


class JobChunk(Base):
    """One frame range of one phase of a chunked job, run as its own Celery task (id `<job>:<phase>:<index>`)."""

    __tablename__ = "job_chunks"

    job_id: Mapped[str] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True)
    phase: Mapped[int] = mapped_column(Integer, primary_key=True, default=0)
    index: Mapped[int] = mapped_column(Integer, primary_key=True)
    first_frame: Mapped[int] = mapped_column(Integer)
    stop_frame: Mapped[int] = mapped_column(Integer)  # exclusive
    state: Mapped[str] = mapped_column(String(16), default="pending")  # pending | running | done
    done: Mapped[int] = mapped_column(Integer, default=0)
    worker: Mapped[str] = mapped_column(String(200), default="")
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)


class JobLog(Base):
    """A line of a job's log, for people: what it did, what went wrong and what to do."""

    __tablename__ = "job_logs"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True, autoincrement=True)
    job_id: Mapped[str] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"), index=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    level: Mapped[str] = mapped_column(String(8), default="info")  # info | warning | error
    message: Mapped[str] = mapped_column(Text)


class Calibration(Base):
    """A versioned calibration result (camera or projector) of one camera."""

    __tablename__ = "calibrations"
    # Versions count per camera and kind; the constraint makes two jobs finishing at once take different ones.
    __table_args__ = (
        UniqueConstraint("camera_id", "kind", "version", name="uq_calibrations_camera_kind_version"),
        {"sqlite_autoincrement": True},  # ids never reused (migration 0006)
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(String(32))  # camera | projector
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    recording_id: Mapped[int | None] = mapped_column(ForeignKey("recordings.id", ondelete="SET NULL"), nullable=True)
    job_id: Mapped[str | None] = mapped_column(ForeignKey("jobs.id", ondelete="SET NULL"), nullable=True)
    version: Mapped[int] = mapped_column(Integer, default=1)
    path: Mapped[str] = mapped_column(String(500))  # relative to the data directory
    summary: Mapped[dict[str, Any]] = mapped_column(default=dict)
    # The image size it was made for: a topography job refuses a calibration of another size.
    image_width_px: Mapped[int] = mapped_column(Integer, default=0)
    image_height_px: Mapped[int] = mapped_column(Integer, default=0)
    sha256: Mapped[str] = mapped_column(String(64), default="")  # of the file at `path`, for provenance
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class User(Base):
    __tablename__ = "users"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(String(64), unique=True)
    password_hash: Mapped[str] = mapped_column(String(200))
    role: Mapped[str] = mapped_column(String(16), default="member")  # admin | member
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class Group(Base):
    __tablename__ = "groups"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)


class GroupMember(Base):
    __tablename__ = "group_members"

    group_id: Mapped[int] = mapped_column(ForeignKey("groups.id", ondelete="CASCADE"), primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), primary_key=True)


class ApiToken(Base):
    """A bearer token (API token for scripts, or a browser session); only its SHA-256 is stored."""

    __tablename__ = "api_tokens"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(100), default="")
    kind: Mapped[str] = mapped_column(String(16), default="api")  # api | session
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    prefix: Mapped[str] = mapped_column(String(16), default="")  # shown in lists to tell tokens apart
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    expires_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    last_used_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)


class AuditEvent(Base):
    """Who uploaded, started, cancelled or deleted what, and when."""

    __tablename__ = "audit_events"
    __table_args__ = {"sqlite_autoincrement": True}  # ids never reused (migration 0006)

    id: Mapped[int] = mapped_column(primary_key=True)
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow, index=True)
    user_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    username: Mapped[str] = mapped_column(String(64), default="")
    action: Mapped[str] = mapped_column(String(32))  # create | update | delete | upload | start | cancel | retry ...
    object_type: Mapped[str] = mapped_column(String(32))
    object_id: Mapped[str] = mapped_column(String(64))
    detail: Mapped[dict[str, Any]] = mapped_column(default=dict)
