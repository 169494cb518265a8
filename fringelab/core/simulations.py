"""Finite-element simulations uploaded into an experiment, as the API changes them.

What belongs here: who may see or change a simulation (it follows its experiment, `fringelab.core.accounts`), how a
received file is stored as one (a single model file, or a ZIP of a folder format such as a d3plot family or a
.pvd/.vtu series, its directory checked under the rule of every ZIP) and its check job queued, when a delete is
refused (a comparison job still uses it), and the comparison's preview. Routes call these and stay thin.

No model is read in the web server's process: an upload is stored `checking`, and its check job
(`worker.jobs.simulation_check`) reads it in a worker, in a process of its own with a memory and a time limit
(`fringelab.core.simulation_check`), then makes it `ready` (with what it holds) or `failed` (with the reason).
A check whose job ended without saying (a worker lost too often, a cancel) is failed by
`fringelab.core.upload_checks.settle_checks`, which the reconciliation runs, so none stays `checking` for ever.

Storage: `DATA_DIR/simulations/<id>/model/` holds the file as received; a ZIP is unpacked in its place by the check
job (`unpack_model`), so no request spends its time unpacking. A refused upload (its name, size, archive or the
disk) leaves neither a row nor files.
"""

from __future__ import annotations

import os
import shutil
import threading
import uuid
import zipfile
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from fringelab.core import upload_checks
from fringelab.core.accounts import Principal, audit, require_access
from fringelab.core.app_state import AppState
from fringelab.core.errors import Conflict, Invalid, NotFound, TooLarge
from fringelab.core.job_kinds import TOPOGRAPHY_FILE, named_by
from fringelab.core.jobs import ACTIVE_STATES
from fringelab.core.models import Experiment, Job, Simulation
from fringelab.core.preparation import check_simulation_ready
from fringelab.core.quota import check_quota
from fringelab.core.recordings import check_upload_size, zip_limits
from fringelab.core.settings import Settings
from fringelab.core.specs import ComparisonSpec
from fringelab.core.storage import (
    InsufficientStorage,
    check_room,
    place_file,
    put_dir,
    remove_tree,
    simulation_dir,
)
from fringelab.core.text import check_file_name
from fringelab.core.upload_checks import SIMULATION_CHECK
from fringelab.formats.container_zip import check_archive, is_junk_entry
from fringelab.formats.simulation_store import CHECKED_FILE

MODEL_DIR = "model"


def simulation_for(session: Session, principal: Principal, simulation_id: int, *, write: bool = False) -> Simulation:
    """The simulation if `principal` may read (or write) its experiment; otherwise a 404 (403: read-only)."""
    simulation = session.get(Simulation, simulation_id)
    if simulation is None:
        raise NotFound(f"simulation {simulation_id} not found", code="simulation_not_found")
    require_access(session, principal, simulation.experiment, write=write, what=f"simulation {simulation_id}")
    return simulation


def check_simulation_request(
    state: AppState, principal: Principal, *, experiment_id: int, filename: str, length: int | None
) -> None:
    """Refuse an upload before any byte is sent: unknown experiment, a name that is no plain file name, size or disk."""
    check_file_name(filename)
    with state.sessions() as session:
        experiment = session.get(Experiment, experiment_id)
        if experiment is None:
            raise NotFound(f"experiment {experiment_id} not found")
        require_access(session, principal, experiment, write=True, what=f"experiment {experiment_id}")
        if length is not None:
            check_quota(session, state.settings, principal, incoming_bytes=length)
    if length is not None:
        # a ZIP unpacks beside itself: room for twice the bytes
        check_upload_size(state.settings, length, reserved_bytes=length)


def _check_zip(archive_path: Path, *, filename: str, settings: Settings) -> list[zipfile.ZipInfo]:
    """The rule of every ZIP on a simulation's archive, from its directory alone (not a byte unpacked: cheap enough
    for the request): unsafe entries, entry count, per-entry and whole-archive size and ratio
    (`container_zip.check_archive`), at least one file, and room on the disk for what it expands to (Invalid or
    TooLarge naming it). Returns its entries."""
    try:
        with zipfile.ZipFile(archive_path) as archive:
            infos = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError) as error:
        raise Invalid(f"{filename}: not a readable ZIP archive ({error})", code="corrupt_archive") from None
    try:
        total = check_archive(filename, infos, limits=zip_limits(settings), size=archive_path.stat().st_size)
    except ValueError as error:
        raise Invalid(f"{error}", code="unsafe_archive") from None
    if not any(not info.is_dir() and not is_junk_entry(info.filename) for info in infos):
        raise Invalid(f"{filename}: the ZIP holds no file", code="invalid_simulation")
    _room(settings, total, filename=filename)
    return infos


def _unpack(archive_path: Path, target: Path, *, filename: str, settings: Settings) -> None:
    """Unpack a ZIP of a simulation folder into `target` under `_check_zip`'s rule, with the room checked again
    before each entry is written (others write too)."""
    infos = _check_zip(archive_path, filename=filename, settings=settings)
    try:
        with zipfile.ZipFile(archive_path) as archive:
            for info in infos:
                if info.is_dir() or is_junk_entry(info.filename):
                    continue
                _room(settings, info.file_size, filename=filename)
                out = target.joinpath(*PurePosixPath(info.filename.replace("\\", "/")).parts)
                out.parent.mkdir(parents=True, exist_ok=True)
                with archive.open(info) as source, out.open("wb") as sink:
                    shutil.copyfileobj(source, sink, 2**20)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError) as error:
        raise Invalid(f"{filename}: not a readable ZIP archive ({error})", code="corrupt_archive") from None


def unpack_model(settings: Settings, folder: Path, *, filename: str) -> None:
    """Run by the simulation's check job (a worker, never the web server): a ZIP stored as received (the only
    file of its model folder `folder`) is unpacked under `_check_zip`'s rule and takes the folder's place (the one
    folder it wraps everything in, if so). Anything else is left as it is. Running it again after it finished does
    nothing; after a crash between its steps it starts over from the archive."""
    parent = folder.parent
    packed = parent / "packed"
    if not folder.exists() and packed.exists():
        os.replace(packed, folder)  # stopped between the two renames below: the archive is whole in `packed`
    remove_tree(settings.data_path, packed)  # stopped after them: the model is in place
    archive = folder / filename
    if not (archive.is_file() and [archive] == list(folder.iterdir()) and zipfile.is_zipfile(archive)):
        return
    work = parent / "unpacking"
    remove_tree(settings.data_path, work)
    work.mkdir()
    try:
        _unpack(archive, work, filename=filename, settings=settings)
        model = _model_folder(work)
        os.replace(folder, packed)
        os.replace(model, folder)
    finally:
        remove_tree(settings.data_path, work)
    remove_tree(settings.data_path, packed)


def _room(settings: Settings, size_bytes: int, *, filename: str) -> None:
    try:
        check_room(settings.data_path, size_bytes, reserve_bytes=settings.min_free_disk_bytes)
    except InsufficientStorage as error:
        raise TooLarge(f"{filename}: {error}", code="insufficient_storage") from None


def _model_folder(root: Path) -> Path:
    """The folder holding the model: `root`, or the one folder a ZIP wrapped everything in."""
    entries = list(root.iterdir())
    while len(entries) == 1 and entries[0].is_dir():
        root = entries[0]
        entries = list(root.iterdir())
    return root


def register_simulation(
    state: AppState,
    principal: Principal,
    *,
    staged: Path,
    experiment_id: int,
    filename: str,
    sha256: str,
    size_bytes: int,
) -> int:
    """Store a fully received file as a simulation of the experiment, `checking`, and queue its check job; returns
    its id. Nothing of the model is read here (the web server's process): the check job reads it in a worker.

    The file is kept as received in `simulations/<id>/model/`. A ZIP's directory is checked here under the rule of
    every ZIP (`_check_zip`: an unsafe archive gets its 4xx at once, before a byte is unpacked); its check job
    unpacks it (`unpack_model`). On a refusal the staging folder is removed; the staged upload stays for the
    caller to remove.
    """
    settings = state.settings
    work = put_dir(settings.data_path) / f"{uuid.uuid4().hex}.simulation"
    try:
        if zipfile.is_zipfile(staged):
            _check_zip(staged, filename=filename, settings=settings)
        (work / "upload").mkdir(parents=True)
        shutil.copyfile(staged, work / "upload" / filename)
        folder = _model_folder(work)
        with state.sessions() as session:
            experiment = session.get(Experiment, experiment_id)
            if experiment is None:
                raise NotFound(f"experiment {experiment_id} not found")
            require_access(session, principal, experiment, write=True, what=f"experiment {experiment_id}")
            simulation = Simulation(experiment_id=experiment_id, filename=filename, size_bytes=size_bytes,
                                    sha256=sha256, state="checking", info={})  # fmt: skip
            session.add(simulation)
            session.flush()
            target = simulation_dir(settings.data_path, simulation.id) / MODEL_DIR
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                place_file(folder, target)
                simulation.path = str(target.relative_to(settings.data_path))
                audit(session, principal, "upload", "simulation", simulation.id, filename=filename,
                      size_bytes=size_bytes, sha256=sha256, experiment_id=experiment_id)  # fmt: skip
                session.commit()
            except BaseException:
                session.rollback()
                remove_tree(settings.data_path, target.parent)
                raise
            submit_check(session, state, simulation)
            return simulation.id
    except OSError as error:
        raise TooLarge(
            f"{filename}: the simulation could not be stored ({error})", code="insufficient_storage"
        ) from None
    finally:
        remove_tree(settings.data_path, work)


def submit_check(session: Session, state: AppState, simulation: Simulation) -> None:
    """Queue the check job of a stored simulation (state `checking`); without a queue it turns `failed`."""
    upload_checks.submit_check(session, state.celery, SIMULATION_CHECK, simulation,
                               experiment_id=simulation.experiment_id)  # fmt: skip


def jobs_using_simulation(session: Session, simulation_id: int) -> list[Job]:
    """Queued or running jobs that read the simulation (that name it among their inputs), but its check: a
    simulation being checked can be deleted (its check then ends without a word)."""
    return [
        job
        for job in session.scalars(select(Job).where(Job.state.in_(ACTIVE_STATES)))
        if job.kind != "simulation_check" and simulation_id in named_by(job.kind, job.spec or {}, "simulation")
    ]


def delete_simulation(session: Session, settings: Settings, principal: Principal, simulation: Simulation) -> None:
    """The simulation's row and files; 409 `in_use` naming the comparison jobs still reading it."""
    jobs = jobs_using_simulation(session, simulation.id)
    if jobs:
        listed = ", ".join(f"{job.kind} job {job.id} ({job.state})" for job in jobs[:5])
        raise Conflict(
            f"simulation {simulation.id} is in use by {listed}; cancel the job or wait until it ends", code="in_use"
        )
    directory = simulation_dir(settings.data_path, simulation.id)
    audit(session, principal, "delete", "simulation", simulation.id, filename=simulation.filename)
    session.delete(simulation)
    session.commit()
    remove_tree(settings.data_path, directory)


# ---- the live preview of a mapping ---------------------------------------------------------------------------------

# The mapping options of a comparison spec (`ComparisonSpec`) and the `MappingSettings` field each sets.
MAPPING_OPTIONS = {
    "units": "length_unit", "symmetry": "symmetry", "normal_axis": "normal_axis", "w_sign": "w_sign",
    "origin_xy_mm": "origin_xy_mm", "rotation_deg": "rotation_deg", "surface": "surface",
    "shell_thickness_mm": "shell_thickness_mm", "time_unit_s": "time_unit_s", "time_offset_s": "time_offset_s",
}  # fmt: skip


def mapping_settings(spec: ComparisonSpec) -> Any:
    """A comparison spec's mapping options as `science.compare.MappingSettings` (None: detect): the one reading of
    them, for the comparison job and the preview."""
    from fringelab.science.compare import MappingSettings

    chosen = {f: getattr(spec, o) for o, f in MAPPING_OPTIONS.items()}
    values: dict[str, Any] = {f: value for f, value in chosen.items() if value is not None}
    if "origin_xy_mm" in values:
        values["origin_xy_mm"] = (float(values["origin_xy_mm"][0]), float(values["origin_xy_mm"][1]))
    return MappingSettings(**values)


def _preview_inputs(
    session: Session, settings: Settings, principal: Principal, spec: ComparisonSpec
) -> tuple[Path, Path]:
    """The topography result file and the simulation's checked copy (what its check job read and stored: the web
    server never opens the uploaded files) a preview reads; 404/409/422 naming the field."""
    from fringelab.core.jobs import job_error, job_for

    job = job_for(session, principal, spec.job_id)
    if job.kind != "topography":
        raise job_error(Invalid, "job_not_found", f"job {job.id} is a {job.kind} job; choose a topography job",
                        field="job_id")  # fmt: skip
    if job.state != "succeeded":
        raise job_error(
            Conflict, "job_not_succeeded", f"topography job {job.id} is {job.state}; wait until it succeeds"
        )
    entry = next((f for f in job.files or [] if f.get("name") == TOPOGRAPHY_FILE), None)
    result = settings.data_path / entry["path"] if entry else None
    if result is None or not result.is_file():
        raise job_error(
            Conflict, "result_missing", f"topography job {job.id} has no result file any more; run it again"
        )
    simulation = session.get(Simulation, spec.simulation_id)
    if simulation is None or simulation.experiment_id != job.experiment_id or not simulation.path:
        raise job_error(
            Invalid, "simulation_not_found",
            f"there is no simulation {spec.simulation_id} in the experiment of topography job {job.id}",
            field="simulation_id",
        )  # fmt: skip
    check_simulation_ready(simulation)
    store = simulation_dir(settings.data_path, simulation.id) / CHECKED_FILE
    if not store.is_file():  # checked before its check stored what it read (an upload of an older version)
        raise job_error(
            Conflict, "simulation_not_checked",
            f"simulation {simulation.id} ({simulation.filename}) has no checked copy to preview; upload it again",
            field="simulation_id",
        )  # fmt: skip
    return result, store


class _RecentPairings:
    """The last few pairings the preview made, by what they were made from: a preview that only changes the frame
    shown is answered at once, not paired again (pairing a model whose origin is fitted takes seconds). Few, as a
    pairing holds its simulation's states in memory. One pairing is made at a time: previews run in the API's
    threads, and the other requests must keep their cores."""

    def __init__(self, size: int = 2) -> None:
        self.size = size
        self._items: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
        self._lock = threading.Lock()
        self._making = threading.Lock()

    def _known(self, key: tuple[Any, ...]) -> Any:
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        return None

    def get(self, key: tuple[Any, ...], make: Callable[[], Any]) -> Any:
        known = self._known(key)
        if known is not None:
            return known
        with self._making:
            known = self._known(key)  # made while this one waited
            if known is not None:
                return known
            made = make()
        with self._lock:
            self._items[key] = made
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return made


_PAIRINGS = _RecentPairings()


def preview_comparison(
    session: Session, settings: Settings, principal: Principal, spec: ComparisonSpec, *, frame: int | None = None
) -> dict[str, Any]:
    """What a comparison with these mapping choices would pair, for the mapping form's live preview: the mapping
    resolved (every detected choice and note), each frame's partner state or why it has none, and the measured and
    simulated profiles through the punch axis along X and Y of one frame (`frame`, else the most deflected one
    paired). The pairing is the comparison's own (`formats.comparison.pair_result`), of the simulation as its check
    job stored it (`formats.simulation_store`): no uploaded file is opened here. A choice that cannot work is an
    Invalid (422) naming the form's setting to change."""
    from fringelab.formats.comparison import pair_result, plate_frame_of
    from fringelab.formats.simulation_store import read_checked
    from fringelab.formats.simulations import assemble
    from fringelab.formats.topography import TopographyResult
    from fringelab.science.compare import ComparisonError, in_form_terms
    from fringelab.science.fields import line_profile

    result_path, simulation_path = _preview_inputs(session, settings, principal, spec)
    mapping_choices = mapping_settings(spec)
    align = spec.align
    punch = (spec.punch_node, spec.contact_interface)
    try:
        with TopographyResult(result_path) as result:

            def pair() -> Any:
                simulation = assemble(read_checked(simulation_path), punch_node=punch[0], contact_interface=punch[1])
                return pair_result(result, simulation, mapping=mapping_choices, align=align)

            key = (
                str(result_path),
                result_path.stat().st_mtime_ns,
                str(simulation_path),
                punch,
                mapping_choices,
                align,
            )
            pairing = _PAIRINGS.get(key, pair)
            simulation = pairing.model.results
            alignment = pairing.alignment
            aligned = np.flatnonzero(alignment.aligned)
            if frame is None:
                peaks = result.measured_peaks()
                i = int(aligned[np.argmax(np.nan_to_num(peaks[aligned], nan=-np.inf))])
            else:
                hits = np.flatnonzero(result.frames == frame)
                if len(hits) == 0:
                    raise Invalid(f"frame {frame} is not in the result (its frames are {int(result.frames[0])}…"
                                  f"{int(result.frames[-1])})", code="frame_not_in_result", field="frame")  # fmt: skip
                i = int(hits[0])
            grid = result.grid
            w_meas = result.w_grid(i)
            w_sim = pairing.simulated_w(i)
            sigma = result.sigma_grid(i)
            stack = np.stack([w_meas, np.full(grid.shape, np.nan) if w_sim is None else w_sim,
                              np.full(grid.shape, np.nan) if sigma is None else sigma])  # fmt: skip
            axis_x, axis_y = plate_frame_of(result).axis_xy_mm
            mapping = pairing.model.mapping.as_dict()
            lines = {"x": ((float(grid.x_mm[0]), axis_y), (float(grid.x_mm[-1]), axis_y)),
                     "y": ((axis_x, float(grid.y_mm[0])), (axis_x, float(grid.y_mm[-1])))}  # fmt: skip
            profiles = {}
            for name, (start, end) in lines.items():
                cut = line_profile(stack, grid, start, end)
                profiles[name] = {"s_mm": cut.s_mm, "x_mm": cut.x_mm, "y_mm": cut.y_mm, "measured_mm": cut.values[0],
                                  "simulated_mm": cut.values[1], "sigma_mm": cut.values[2]}  # fmt: skip
            return {
                "frame": int(result.frames[i]),
                "alignment": align,
                "mapping": {**mapping, "notes": [in_form_terms(str(note)) for note in pairing.model.mapping.notes]},
                "overlap_fraction": float(pairing.overlap),
                "axis_xy_mm": [axis_x, axis_y],
                "frames": {
                    "frame": result.frames.astype(int).tolist(),
                    "state_lo": alignment.state_lo.astype(int).tolist(),
                    "state_fraction": alignment.fraction,
                    "reason": list(alignment.reason),
                    "peak_w_mm": result.measured_peaks(),
                },
                "simulation": {"n_states": simulation.n_states, "peak_w_mm": pairing.state_peak_mm},
                "profiles": profiles,
            }
    except ComparisonError as error:
        raise Invalid(in_form_terms(str(error)), code="mapping_not_possible") from None
    except (ValueError, KeyError, OSError) as error:
        raise Invalid(
            in_form_terms(str(error)).replace(str(simulation_path) + "/", ""), code="invalid_simulation"
        ) from None
