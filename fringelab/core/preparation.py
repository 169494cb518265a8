"""Preparing a job: its spec checked against the database before anything is queued.

What belongs here: the kinds of input a job spec names (a recording, a calibration, another job, a simulation),
each with its checks (does it exist, may the caller see it, is it ready, does it fit the others) and what it
records of itself in the job's provenance; and `prepare_inputs`, which walks a kind's inputs in order
(`fringelab.core.job_kinds` says which inputs each kind names). Shapes and ranges are not checked here (the spec
model did that); creating, cancelling and retrying jobs is `fringelab.core.jobs`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from pydantic import BaseModel
from sqlalchemy.orm import Session

from fringelab.core.calibration_pairs import check_calibration_use
from fringelab.core.errors import Conflict, DomainError, Invalid
from fringelab.core.models import Calibration, Camera, Job, Recording, Simulation
from fringelab.formats import COMPARISON_EXPORTS, EXPORT_FORMATS


def job_error(kind: type[DomainError], code: str, detail: str, *, field: str | None = None) -> DomainError:
    """A job request refused: a `kind` error whose answer always names the field at fault (null for none)."""
    error = kind(detail, code=code, field=field)
    error.names_field = True
    return error


@dataclass
class Prepared:
    """What the database says about a spec's inputs: the experiment they belong to and their provenance."""

    experiment_id: int | None = None
    inputs: list[dict[str, Any]] = field(default_factory=list)
    calibrations: list[dict[str, Any]] = field(default_factory=list)


Authorize = Callable[[int | None], None]  # raises a job error when the caller may not start jobs of that experiment


class NotVisible(Exception):
    """What an Authorize raises when the caller may not even read the experiment: its objects are then refused
    exactly as ids that do not exist, so that guessing ids teaches nothing about other users' experiments."""


def nobody_checks(_experiment_id: int | None) -> None:
    return None


@dataclass
class _Found:
    """The inputs found so far, for the checks of the inputs after them (a calibration needs its recording)."""

    recording: Recording | None = None
    job: Job | None = None


@dataclass(frozen=True, kw_only=True)
class Input:
    """An input a job kind's spec names: the spec's `field` holding its id (or a list of ids: `many`), what it
    names (`names`: a table) and the `role` it plays, for people (the docs, the developer guide)."""

    names: ClassVar[str]
    field: str
    role: str
    many: bool = False

    def ids(self, spec: BaseModel) -> list[Any]:
        value = getattr(spec, self.field)
        return [] if value is None else list(value) if self.many else [value]

    def prepare(self, session: Session, spec: Any, prepared: Prepared, found: _Found, authorize: Authorize) -> None:
        """Check the input against the database (raise a `job_error` naming the field) and record it."""
        raise NotImplementedError


@dataclass(frozen=True, kw_only=True)
class RecordingInput(Input):
    """A ready recording of `recording_kind`, in an experiment the caller may start jobs in. The spec's `frames`,
    when it has them, must lie inside it. `checked=False`: only named (the ingest job checks its recording)."""

    names = "recording"
    recording_kind: str
    checked: bool = True

    def prepare(self, session: Session, spec: Any, prepared: Prepared, found: _Found, authorize: Authorize) -> None:
        if not self.checked:
            return
        for recording_id in self.ids(spec):
            recording = _recording(session, recording_id, kind=self.recording_kind, field_name=self.field,
                                   authorize=authorize)  # fmt: skip
            _check_frames(getattr(spec, "frames", None), recording)
            prepared.experiment_id = recording.camera.experiment_id
            prepared.inputs.append({"recording_id": recording.id, "sha256": recording.sha256,
                                    "frames": recording.frame_count})  # fmt: skip
            found.recording = recording


@dataclass(frozen=True, kw_only=True)
class ReferenceCodeInput(Input):
    """A ready recording of kind coded by the camera of the recording named before it, at its image size: the
    Gray code recorded with the plate at rest before a test (docs/procam.md §5). Its frames are not the test's, so
    the spec's frame range is not checked against it."""

    names = "recording"

    def prepare(self, session: Session, spec: Any, prepared: Prepared, found: _Found, authorize: Authorize) -> None:
        test = found.recording
        if test is None:
            raise TypeError(f"{self.field}: a reference code follows the recording it is recorded for")
        for recording_id in self.ids(spec):
            code = _recording(session, recording_id, kind="coded", field_name=self.field, authorize=authorize)
            if code.camera_id != test.camera_id or (code.width_px, code.height_px) != (test.width_px, test.height_px):
                raise job_error(
                    Invalid,
                    "reference_code_of_another_camera",
                    f"recording {recording_id} ({code.width_px} × {code.height_px} px, camera {code.camera_id}) is not "
                    f"of the test recording's camera {test.camera_id} at {test.width_px} × {test.height_px} px: the "
                    "code at rest must be recorded by the test's camera, unmoved",
                    field=self.field,
                )
            prepared.inputs.append({"recording_id": code.id, "sha256": code.sha256, "frames": code.frame_count,
                                    "role": "reference code"})  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class CalibrationInput(Input):
    """A `calibration_kind` calibration of the camera and image size of the recording named before it."""

    names = "calibration"
    calibration_kind: str

    def prepare(self, session: Session, spec: Any, prepared: Prepared, found: _Found, authorize: Authorize) -> None:
        if found.recording is None:
            raise TypeError(f"{self.field}: a calibration input follows the recording it is checked against")
        for calibration_id in self.ids(spec):
            calibration = _calibration(session, calibration_id, kind=self.calibration_kind, recording=found.recording,
                                       field_name=self.field)  # fmt: skip
            use = check_calibration_use(session, calibration, spec, field=self.field)  # pairing and consent
            prepared.calibrations.append({"id": calibration.id, "kind": calibration.kind,
                                          "version": calibration.version, "sha256": calibration.sha256,
                                          **use})  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class JobInput(Input):
    """A succeeded job of one of `job_kinds`, in an experiment the caller may start jobs in; `advice` ends the
    sentence that refuses one not succeeded. needs_file: a result file it must still have. check(spec, job): the
    kind's own further checks of the job (an export's format must be one of that job's)."""

    names = "job"
    job_kinds: tuple[str, ...]
    advice: str
    needs_file: str | None = None
    check: Callable[[Any, Job], None] | None = None

    def prepare(self, session: Session, spec: Any, prepared: Prepared, found: _Found, authorize: Authorize) -> None:
        for job_id in self.ids(spec):
            source = session.get(Job, job_id)
            missing = job_error(Invalid, "job_not_found", f"there is no {' or '.join(self.job_kinds)} job {job_id}",
                                field=self.field)  # fmt: skip
            if source is None or source.kind not in self.job_kinds:
                raise missing
            try:
                authorize(source.experiment_id)
            except NotVisible:
                raise missing from None
            if source.state != "succeeded":
                raise job_error(Conflict, "job_not_succeeded",
                                f"{source.kind} job {source.id} is {source.state}; {self.advice}")  # fmt: skip
            if self.needs_file and not any(entry.get("name") == self.needs_file for entry in source.files or []):
                raise job_error(Conflict, "result_missing",
                                f"{source.kind} job {source.id} has no result file any more; run it again")  # fmt: skip
            if self.check is not None:
                self.check(spec, source)
            prepared.experiment_id = source.experiment_id
            prepared.inputs.append({"job_id": source.id})
            found.job = source


@dataclass(frozen=True, kw_only=True)
class SimulationInput(Input):
    """A ready simulation (its check job read it) in the experiment of the job named before it. `checked=False`:
    only named (the check job of an upload)."""

    names = "simulation"
    checked: bool = True

    def prepare(self, session: Session, spec: Any, prepared: Prepared, found: _Found, authorize: Authorize) -> None:
        if not self.checked:
            return
        source = found.job
        if source is None:
            raise TypeError(f"{self.field}: a simulation input follows the job it is compared with")
        for simulation_id in self.ids(spec):
            simulation = session.get(Simulation, simulation_id)
            if simulation is None or simulation.experiment_id != source.experiment_id:
                raise job_error(
                    Invalid,
                    "simulation_not_found",
                    f"there is no simulation {simulation_id} in the experiment of {source.kind} job {source.id}; "
                    f"see GET /api/v1/experiments/{source.experiment_id}/simulations",
                    field=self.field,
                )
            check_simulation_ready(simulation, field_name=self.field)
            prepared.inputs.append({"simulation_id": simulation.id, "sha256": simulation.sha256})


def check_simulation_ready(simulation: Simulation, *, field_name: str | None = "simulation_id") -> None:
    """A simulation is compared only once its check job has read it: 409 while it is checked, 422 when it failed
    (the one rule, for comparison jobs and the mapping form's preview)."""
    if simulation.state == "checking":
        raise job_error(
            Conflict,
            "simulation_not_ready",
            f"simulation {simulation.id} ({simulation.filename}) is still being checked; wait until it is ready",
            field=field_name,
        )
    if simulation.state != "ready":
        raise job_error(
            Invalid,
            "simulation_failed",
            f"simulation {simulation.id} ({simulation.filename}) failed its check: {simulation.error or 'unreadable'}; "
            "upload a readable model",
            field=field_name,
        )


def prepare_inputs(
    session: Session, spec: BaseModel, inputs: Sequence[Input], *, authorize: Authorize = nobody_checks
) -> Prepared:
    """Check a (shape-valid) spec's inputs against the database, in order; raise a `job_error` naming the field,
    or say what the job uses. `authorize` is asked as soon as the experiment is known, before anything about its
    inputs is revealed; a kind whose inputs are all unchecked (or that has none) runs outside any experiment."""
    prepared, found = Prepared(), _Found()
    if not any(getattr(item, "checked", True) for item in inputs):
        authorize(None)
        return prepared
    for item in inputs:
        item.prepare(session, spec, prepared, found, authorize)
    return prepared


# ------------------------------------------------------------------------------------------- the checks


def _recording(session: Session, recording_id: int, *, kind: str, field_name: str, authorize: Authorize) -> Recording:
    recording = session.get(Recording, recording_id)
    missing = job_error(Invalid, "recording_not_found", f"there is no recording {recording_id}", field=field_name)
    if recording is None:
        raise missing
    try:
        authorize(recording.camera.experiment_id)
    except NotVisible:
        raise missing from None
    if recording.kind != kind:
        raise job_error(
            Invalid,
            "wrong_recording_kind",
            f"recording {recording_id} is a {recording.kind} recording; this job needs a {kind} recording",
            field=field_name,
        )
    if recording.state != "ready":
        advice = {
            "uploading": "finish its upload",
            "ingesting": "wait for its ingest job to finish",
            "invalid": f"it was rejected ({recording.error or 'see the recording'}); upload it again",
        }.get(recording.state, "wait until it is ready")
        raise job_error(
            Conflict, "recording_not_ready", f"recording {recording_id} is {recording.state}, not ready: {advice}"
        )
    return recording


def _calibration(
    session: Session, calibration_id: int, *, kind: str, recording: Recording, field_name: str
) -> Calibration:
    calibration = session.get(Calibration, calibration_id)
    # A calibration of another experiment, perhaps someone else's, gets the very answer of an id that does not
    # exist (a different one told which ids exist).
    missing = job_error(
        Invalid,
        "calibration_not_found",
        f"there is no {kind} calibration {calibration_id} of camera {recording.camera_id} (the recording's); "
        f"see GET /api/v1/calibrations?camera_id={recording.camera_id}",
        field=field_name,
    )
    if calibration is None or calibration.kind != kind:
        raise missing
    if calibration.camera_id != recording.camera_id:
        other = session.get(Camera, calibration.camera_id)
        if other is None or other.experiment_id != recording.camera.experiment_id:
            raise missing
        raise job_error(
            Invalid,
            "calibration_mismatch",
            f"{kind} calibration {calibration_id} belongs to camera {calibration.camera_id}"
            f"{f' ({other.name})' if other else ''}, but recording {recording.id} was filmed by camera "
            f"{recording.camera_id}; use a calibration of that camera",
            field=field_name,
        )
    size = (calibration.image_width_px, calibration.image_height_px)
    if size != (recording.width_px, recording.height_px):
        raise job_error(
            Invalid,
            "calibration_mismatch",
            f"{kind} calibration {calibration_id} was made for {size[0]}x{size[1]} px images, but recording "
            f"{recording.id} has {recording.width_px}x{recording.height_px} px frames; calibrate at this size",
            field=field_name,
        )
    return calibration


def _check_frames(frames: Any, recording: Recording) -> None:
    """A spec's frame range (a `FrameRange`, or None) must lie inside the recording."""
    count = recording.frame_count
    for key in ("first", "last"):
        value = getattr(frames, key, None)
        if value is not None and value >= count:
            raise job_error(
                Invalid,
                "frame_out_of_range",
                f"frames.{key} = {value} is outside recording {recording.id}, whose frames are 0..{count - 1}",
                field=f"frames.{key}",
            )


def check_export_source(spec: Any, source: Job) -> None:
    """Each kind of result has its export formats; a comparison's take no frame range and no labelled lines. An
    export's frame range must hold frames of its result (the result says its first and last frame)."""
    formats = COMPARISON_EXPORTS if source.kind == "comparison" else EXPORT_FORMATS
    if spec.format not in formats:
        raise job_error(
            Invalid,
            "format_not_for_source",
            f"format {spec.format} is not an export of a {source.kind} result; choose one of {', '.join(formats)}",
            field="format",
        )
    if source.kind == "comparison":
        for name in ("frames", "lines"):
            if getattr(spec, name):
                raise job_error(Invalid, "invalid_spec", f"a comparison export takes no {name}", field=name)
    wanted = spec.frames
    held = (source.result or {}).get("frames")
    if not wanted or not held:
        return
    first, last = wanted.first, wanted.last if wanted.last is not None else held[1]
    if last < held[0] or first > held[1]:
        raise job_error(
            Invalid,
            "frames_outside_result",
            f"frames {first}…{last} hold no frame of topography job {source.id} (its frames are {held[0]}…{held[1]})",
            field="frames",
        )
