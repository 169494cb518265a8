"""The registry of job kinds (`fringelab.core.job_kinds`): every layer reads the same entries."""

from __future__ import annotations

import importlib
import typing

import pytest
from pydantic import TypeAdapter

from fringelab.core.job_kinds import JOB_KINDS, JobSpec, job_kind, kind_of, named_by, spec_of
from fringelab.core.specs import ExportSpec, IngestSpec, TopographySpec


def test_each_kind_has_its_orchestration_module_with_the_bodies_it_names() -> None:
    for entry in JOB_KINDS.values():
        module = importlib.import_module(entry.module)
        for name in (entry.body, *(p.chunk for p in entry.phases), *(p.merge for p in entry.phases)):
            assert callable(getattr(module, name, None)), f"{entry.module} has no {name}"


def test_the_worker_registers_each_kinds_task_under_its_name() -> None:
    from worker.tasks import ENTRY_TASKS, PHASES

    assert {kind: task.name for kind, task in ENTRY_TASKS.items()} == {k: e.task for k, e in JOB_KINDS.items()}
    assert set(PHASES) == {kind for kind, entry in JOB_KINDS.items() if entry.phases}
    assert len({entry.task for entry in JOB_KINDS.values()}) == len(JOB_KINDS)


def test_the_api_takes_the_startable_kinds_in_the_registrys_order() -> None:
    union = typing.get_args(typing.get_args(JobSpec)[0])
    assert union == tuple(entry.spec for entry in JOB_KINDS.values() if entry.startable)
    for model in union:
        assert typing.get_args(model.model_fields["kind"].annotation) == (kind_of(model.model_construct()).kind,)
    assert not JOB_KINDS["ingest"].startable


def test_a_spec_as_old_jobs_stored_it_still_reads() -> None:
    # an export spec stored before `lines` and `frames` existed, a topography spec before `chunk_frames` was
    # bounded, an ingest spec (never had a kind): as the JSON column holds them
    old_export = {
        "kind": "export",
        "job_id": "6f1c2b8e-2d4a-4f6e-9a51-3c7d0e9b2f10",
        "format": "grid-npz",
        "line": None,
    }
    export = spec_of("export", old_export)
    assert isinstance(export, ExportSpec) and export.lines is None and export.frames is None
    old_topography = {"kind": "topography", "recording_id": 3, "camera_calibration_id": 1,
                      "projector_calibration_id": 2, "frames": {"first": 0, "last": 99}, "grid_step_mm": 2.0,
                      "temporal_smoothing_frames": 0, "chunk_frames": None}  # fmt: skip
    topography = spec_of("topography", old_topography)
    assert isinstance(topography, TopographySpec) and topography.frames.last == 99
    # stored again (a retry) with what it said unchanged, and the fields added since at their defaults
    assert topography.model_dump(mode="json").items() >= old_topography.items()
    ingest = spec_of("ingest", {"recording_id": 7})
    assert isinstance(ingest, IngestSpec) and ingest.model_dump(mode="json") == {"recording_id": 7}


def test_the_inputs_a_stored_spec_names_by_their_kind() -> None:
    stored = TypeAdapter(JobSpec).validate_python(
        {"kind": "topography", "recording_id": 3, "camera_calibration_id": 1, "projector_calibration_id": 2}
    )
    as_stored = stored.model_dump(mode="json")
    assert named_by("topography", as_stored, "recording") == {3}
    assert named_by("topography", as_stored, "calibration") == {1, 2}
    assert named_by("topography", as_stored, "job") == set()
    comparison = {"kind": "comparison", "job_id": "abc", "simulation_id": 4}
    assert named_by("comparison", comparison, "job") == {"abc"}
    assert named_by("comparison", comparison, "simulation") == {4}
    assert named_by("ingest", {"recording_id": 5}, "recording") == {5}
    assert named_by("no-such-kind", {"recording_id": 5}, "recording") == set()


def test_an_unknown_kind_is_named_with_the_known_ones() -> None:
    with pytest.raises(ValueError, match="unknown job kind 'levitate'; expected one of"):
        job_kind("levitate")


def test_the_developer_guide_lists_every_kind_as_the_registry_has_it() -> None:
    from pathlib import Path

    guide = (Path(__file__).parents[2] / "docs" / "developer-guide.md").read_text()
    rows = {line.split("|")[1].strip().strip("`"): line for line in guide.splitlines() if line.startswith("| `")}
    assert set(rows) == set(JOB_KINDS)
    for kind, entry in JOB_KINDS.items():
        row = rows[kind]
        assert f"`{entry.spec.__name__}`" in row and f"`{entry.task}`" in row, kind
        for item in entry.inputs:
            assert f"`{item.field}`" in row, (kind, item.field)
        for phase in entry.phases:
            assert f"`{phase.chunk}` → `{phase.merge}`" in row, kind
