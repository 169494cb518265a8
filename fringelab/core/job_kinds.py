"""The job kinds: one entry per kind, which every layer reads.

An entry says everything the layers need to know of a kind: its spec model (`fringelab.core.specs`: what the API
takes, and what the form is built from), the name its Celery task is registered under, the inputs its spec names
with their roles (`fringelab.core.preparation` checks them before the job is queued; deletion and "in use" find a
job's inputs through them), the orchestration module in the worker that runs it (`worker.jobs.<kind>`: the entry
body, and per chunked phase its chunk and merge bodies, by name), and the result files it publishes.

Adding a kind is one entry here (and its spec model in `fringelab.core.specs`) and one orchestration module in
`worker/jobs/` (docs/developer-guide.md, "Adding a job kind"). What does not belong here: the checks themselves
(`fringelab.core.preparation`) and anything that runs a job (the worker).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Union

from pydantic import BaseModel, Field, TypeAdapter

from fringelab.core.preparation import (
    CalibrationInput,
    Input,
    JobInput,
    RecordingInput,
    ReferenceCodeInput,
    SimulationInput,
    check_export_source,
)
from fringelab.core.specs import (
    CameraCalibrationSpec,
    ComparisonSpec,
    ExportSpec,
    IngestSpec,
    ProcamCalibrationSpec,
    ProjectorCalibrationSpec,
    ScanSpec,
    SelftestSpec,
    SimulationCheckSpec,
    TopographySpec,
)

TOPOGRAPHY_FILE = "topography.h5"
COMPARISON_FILE = "comparison.h5"


@dataclass(frozen=True)
class Phase:
    """A chunked phase of a kind: the names of its chunk body (`(context, first, stop)`, run on any worker per
    frame range) and merge body (`(context, turns)`, in frame order) in the kind's orchestration module.
    hold_steals: the later chunks the merge measures itself stay in its process (`worker.runner.run_merge`)."""

    chunk: str
    merge: str
    hold_steals: bool = False


@dataclass(frozen=True)
class ResultSize:
    """What a kind's result files are expected to take, for the per-user quota (`fringelab.core.quota`): reserved
    against the experiment's owner while a job is queued or running, replaced by its files' real sizes once it
    ends. `flat_bytes`, plus `bytes_per_pixel_frame` × the pixels of every frame of the recordings its spec names,
    plus `times_source` × the size of the files of the job it reads. An estimate on the high side, not a limit."""

    flat_bytes: int = 0
    bytes_per_pixel_frame: float = 0.0
    times_source: float = 0.0


MIB = 2**20


@dataclass(frozen=True, kw_only=True)
class JobKind:
    """One kind of job (see the module's docstring)."""

    kind: str
    spec: type[BaseModel]
    task: str  # the Celery task's name; the API sends it by name
    inputs: tuple[Input, ...]
    body: str  # the entry body's name in `module`: `(context) -> result | Chunked`
    phases: tuple[Phase, ...] = ()
    result_files: tuple[str, ...] = ()  # the files it publishes (the download names; an export's depend on its format)
    result_size: ResultSize = ResultSize()  # what they are expected to take (the quota reserves it while it runs)
    startable: bool = True  # through POST /api/v1/jobs (an ingest is started by its upload)

    @property
    def module(self) -> str:
        """The worker's orchestration module of the kind."""
        return f"worker.jobs.{self.kind}"

    def parse(self, stored: Mapping[str, Any]) -> BaseModel:
        """The spec model from a spec as stored with the job (JSON), validated: the one door from stored JSON to
        a typed spec (old jobs' specs read the same: fields added since take their defaults)."""
        return self.spec.model_validate(stored)

    def named(self, stored: Mapping[str, Any], names: str) -> set[Any]:
        """The ids of the `names` ("recording", "calibration", "job", "simulation", "camera") a stored spec names.
        Reads the stored JSON by the inputs' fields, not through `parse`: deleting what a job used must work
        even for a spec that no longer validates."""
        found: set[Any] = set()
        for item in self.inputs:
            if item.names == names:
                value = stored.get(item.field)
                found.update(value if isinstance(value, list) else [] if value is None else [value])
        return found


_RECORDING = RecordingInput(field="recording_id", recording_kind="test", role="the test recording to measure")
_CAMERA = CalibrationInput(field="camera_calibration_id", calibration_kind="camera",
                           role="the camera's calibration (same camera, same image size)")  # fmt: skip

# In the order the API's schema lists the spec models (a kind added goes at the end).
JOB_KINDS: dict[str, JobKind] = {
    entry.kind: entry
    for entry in (
        JobKind(
            kind="ingest",
            spec=IngestSpec,
            task="fringelab.ingest",
            startable=False,
            body="ingest_recording",
            inputs=(
                RecordingInput(
                    field="recording_id", recording_kind="any", checked=False, role="the uploaded recording to check"
                ),
            ),
        ),
        JobKind(
            kind="selftest",
            spec=SelftestSpec,
            task="fringelab.selftest",
            inputs=(),
            body="selftest_entry",
            phases=(Phase("selftest_compute", "selftest_chain"), Phase("selftest_verify", "selftest_write")),
            result_files=("selftest.h5",),
            result_size=ResultSize(flat_bytes=MIB),
        ),
        JobKind(
            kind="camera_calibration",
            spec=CameraCalibrationSpec,
            task="fringelab.camera_calibration",
            inputs=(
                RecordingInput(
                    field="recording_id", recording_kind="camera_calibration", role="the chessboard recording"
                ),
            ),
            body="camera_calibration_body",
            result_files=("camera.json",),
            result_size=ResultSize(flat_bytes=MIB),
        ),
        JobKind(
            kind="projector_calibration",
            spec=ProjectorCalibrationSpec,
            task="fringelab.projector_calibration",
            inputs=(
                RecordingInput(
                    field="recording_id", recording_kind="projector_calibration", role="the flat plate moved along Z"
                ),
                _CAMERA,
            ),
            body="projector_calibration_body",
            result_files=("projector.h5",),
            # the look-up table: edges × scan lines × Z positions, float32 (~1 byte per pixel of each Z frame)
            result_size=ResultSize(flat_bytes=MIB, bytes_per_pixel_frame=1.0),
        ),
        JobKind(
            kind="topography",
            spec=TopographySpec,
            task="fringelab.topography",
            inputs=(
                _RECORDING,
                _CAMERA,
                CalibrationInput(
                    field="projector_calibration_id",
                    calibration_kind="projector",
                    role="the projector's look-up table (same camera, same image size)",
                ),
                ReferenceCodeInput(
                    field="reference_code_recording_id",
                    role="a Gray code recorded with the plate at rest by the test's camera (optional)",
                ),
            ),
            body="topography_entry",
            phases=(Phase("topography_measure", "topography_write", hold_steals=True),),
            result_files=(TOPOGRAPHY_FILE, "topography.xdmf"),
            # points (one per stripe edge and scan line, ~24 bytes each, compressed) and the grids of every frame
            result_size=ResultSize(flat_bytes=MIB, bytes_per_pixel_frame=4.0),
        ),
        JobKind(
            kind="export",
            spec=ExportSpec,
            task="fringelab.export",
            inputs=(
                JobInput(
                    field="job_id",
                    job_kinds=("topography", "comparison"),
                    advice="export a succeeded one",
                    check=check_export_source,
                    role="the result to export",
                ),
            ),
            body="export_body",
            result_files=("the format's file (fringelab.formats.exports)",),
            result_size=ResultSize(flat_bytes=MIB, times_source=3.0),  # a CSV of points: ~3 × the compressed result
        ),
        JobKind(
            kind="comparison",
            spec=ComparisonSpec,
            task="fringelab.comparison",
            inputs=(
                JobInput(
                    field="job_id",
                    job_kinds=("topography",),
                    needs_file=TOPOGRAPHY_FILE,
                    advice="compare a succeeded one (wait for it, or run it again)",
                    role="the measured deflection",
                ),
                SimulationInput(field="simulation_id", role="the finite-element model to compare it with"),
            ),
            body="comparison_body",
            result_files=(COMPARISON_FILE, "the `format`'s export, if one is named"),
            result_size=ResultSize(flat_bytes=MIB, times_source=2.0),
        ),
        JobKind(
            kind="procam_calibration",
            spec=ProcamCalibrationSpec,
            task="fringelab.procam_calibration",
            inputs=(
                RecordingInput(
                    field="recording_ids",
                    recording_kind="coded",
                    many=True,
                    role="the chessboard poses under Gray code, one recording each",
                ),
            ),
            body="procam_calibration_body",
            result_files=("procam.json",),
            result_size=ResultSize(flat_bytes=MIB),
        ),
        JobKind(
            kind="scan",
            spec=ScanSpec,
            task="fringelab.scan",
            inputs=(
                RecordingInput(field="recording_id", recording_kind="coded", role="the coded sequence to scan"),
                CalibrationInput(
                    field="procam_calibration_id",
                    calibration_kind="procam",
                    role="the camera–projector calibration (same camera, same image size)",
                ),
            ),
            body="scan_body",
            result_files=("scan.h5",),
            result_size=ResultSize(flat_bytes=MIB, bytes_per_pixel_frame=1.0),
        ),
        JobKind(
            kind="simulation_check",
            spec=SimulationCheckSpec,
            task="fringelab.simulation_check",
            startable=False,
            body="check_simulation",
            inputs=(SimulationInput(field="simulation_id", checked=False, role="the uploaded simulation to check"),),
        ),
    )  # fmt: skip
}


def job_kind(kind: str) -> JobKind:
    """The entry of `kind`; ValueError naming the kinds there are."""
    try:
        return JOB_KINDS[kind]
    except KeyError:
        raise ValueError(f"unknown job kind {kind!r}; expected one of {sorted(JOB_KINDS)}") from None


def spec_of(kind: str, stored: Mapping[str, Any]) -> BaseModel:
    """The typed spec of a job of `kind` from its stored JSON (`JobKind.parse`)."""
    return job_kind(kind).parse(stored)


def kind_of(spec: BaseModel) -> JobKind:
    """The entry of the kind a spec model is of (by its model: an ingest's spec has no `kind` field)."""
    for entry in JOB_KINDS.values():
        if type(spec) is entry.spec:
            return entry
    raise ValueError(f"{type(spec).__name__} is the spec of no job kind")


def named_by(kind: str, stored: Mapping[str, Any], names: str) -> set[Any]:
    """The ids of the `names` a job of `kind` names in its stored spec (`JobKind.named`); none for a kind that
    is no longer known."""
    entry = JOB_KINDS.get(kind)
    return entry.named(stored, names) if entry is not None else set()


# The spec POST /api/v1/jobs takes: one of the startable kinds' models, told apart by `kind` (the schema-driven
# form finds each kind's model in the API's schema by it).
if TYPE_CHECKING:
    JobSpec = BaseModel
else:
    JobSpec = Annotated[
        Union[tuple(entry.spec for entry in JOB_KINDS.values() if entry.startable)],  # noqa: UP007
        Field(discriminator="kind"),
    ]


@functools.cache
def spec_schemas() -> dict[str, Any]:
    """The JSON Schema of every startable kind's spec model and of the models they use, by model name, with
    references as `#/schemas/NAME`: what the dashboard builds its job forms from (GET /api/v1/jobs/specs). Made
    once per process from `JobSpec` (milliseconds), where the whole OpenAPI document takes seconds to build on a
    loaded machine and weighs ten times more."""
    document = TypeAdapter(JobSpec).json_schema(ref_template="#/schemas/{model}")
    return {"schemas": document.get("$defs", {})}
