"""Which calibrations go together, and which may be used: the one owner of the pairing and consent rules.

What belongs here: a calibration's name for people (id, camera, date), its verdict and whether it is "bad" (its
own verdict, or a projector calibration built on a bad camera calibration), which camera calibration a projector
calibration was built on, the consistent pairs of a camera, and the check a job's preparation calls for every
calibration it names (`check_calibration_use`): a projector calibration must be built on the camera calibration
the spec names, and a bad one needs the spec's explicit consent (`accept_bad_calibration`). Not here: whether a
calibration exists, is of the recording's camera and size (`fringelab.core.preparation`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from fringelab.core.errors import Invalid
from fringelab.core.models import Calibration, Camera, Job

BAD = "bad"


def _error(code: str, detail: str, field: str) -> Invalid:
    error = Invalid(detail, code=code, field=field)
    error.names_field = True
    return error


def calibration_label(session: Session, calibration: Calibration) -> str:
    """ "camera calibration #3 (camera 'left', 2026-11-27 07:40)": how every message and list names it."""
    camera = session.get(Camera, calibration.camera_id)
    name = f"camera '{camera.name}'" if camera is not None else f"camera {calibration.camera_id}"
    when = calibration.created_at.strftime("%Y-%m-%d %H:%M") if calibration.created_at else "date unknown"
    return f"{calibration.kind} calibration #{calibration.id} ({name}, {when})"


def built_on(session: Session, calibration: Calibration) -> int | None:
    """The camera calibration a projector calibration was built on (its summary's, else its job's spec); None for
    a camera calibration or when nothing says."""
    if calibration.kind != "projector":
        return None
    stored = (calibration.summary or {}).get("camera_calibration_id")
    if isinstance(stored, int):
        return stored
    job = session.get(Job, calibration.job_id) if calibration.job_id else None
    # A stored-JSON read: the projector calibration job's spec names the camera calibration it was built on (this
    # module is below the registry, fringelab.core.preparation imports it, so job_kinds.named_by is not reachable).
    value = (job.spec or {}).get("camera_calibration_id") if job is not None else None
    return int(value) if isinstance(value, int) else None


def own_verdict(calibration: Calibration) -> str | None:
    """The verdict the calibration's job gave it ("good", "acceptable", "bad"), None when it has none stored."""
    value = (calibration.summary or {}).get("verdict")
    return str(value) if value else None


@dataclass(frozen=True)
class Standing:
    """What the lists show of a calibration: its label, verdict, whether it is bad and why, and its base."""

    label: str
    verdict: str | None
    bad: bool
    bad_reason: str | None
    camera_calibration_id: int | None


def standing(session: Session, calibration: Calibration) -> Standing:
    verdict = own_verdict(calibration)
    base_id = built_on(session, calibration)
    reason = None
    if verdict == BAD:
        reason = 'its verdict is "bad" (see its report)'
    elif base_id is not None:
        base = session.get(Calibration, base_id)
        if base is not None and own_verdict(base) == BAD:
            reason = f'built on camera calibration #{base_id}, whose verdict is "bad"'
    return Standing(calibration_label(session, calibration), verdict, reason is not None, reason, base_id)


def consistent_pairs(session: Session, camera_id: int) -> list[tuple[Calibration, Calibration]]:
    """(camera calibration, projector calibration built on it) of one camera, newest projector first."""
    rows = session.scalars(
        select(Calibration).where(Calibration.camera_id == camera_id).order_by(Calibration.id.desc())
    ).all()
    cameras = {row.id: row for row in rows if row.kind == "camera"}
    pairs = []
    for row in rows:
        base = built_on(session, row)
        if row.kind == "projector" and base in cameras:
            pairs.append((cameras[base], row))
    return pairs


def check_calibration_use(session: Session, calibration: Calibration, spec: Any, *, field: str) -> dict[str, Any]:
    """Refuse (422, naming the field) a projector calibration not built on the spec's camera calibration, and a
    bad calibration without the spec's `accept_bad_calibration`; what the job's provenance records of it."""
    wanted = getattr(spec, "camera_calibration_id", None)
    base_id = built_on(session, calibration)
    label = calibration_label(session, calibration)
    if calibration.kind == "projector" and wanted is not None and base_id is not None and base_id != wanted:
        chosen = session.get(Calibration, wanted)
        chosen_label = calibration_label(session, chosen) if chosen is not None else f"camera calibration #{wanted}"
        raise _error(
            "calibration_mismatch",
            f"{label} was built on camera calibration #{base_id}, not on {chosen_label}: choose a projector "
            f"calibration built on #{wanted} (GET /api/v1/calibrations/pairs?camera_id={calibration.camera_id}), "
            f"or camera calibration #{base_id}",
            field,
        )
    state = standing(session, calibration)
    if state.bad and not getattr(spec, "accept_bad_calibration", False):
        raise _error(
            "bad_calibration",
            f"{label}: {state.bad_reason}; calibrate again, or set accept_bad_calibration to use it anyway (the "
            "results will carry the warning)",
            field,
        )
    recorded: dict[str, Any] = {"verdict": state.verdict, "bad": state.bad, "label": label}
    if state.bad:
        recorded["warning"] = f"{label}: {state.bad_reason}; used with the user's consent"
    return recorded


def warnings_of(provenance: dict[str, Any] | None) -> list[str]:
    """The warnings a job's results carry: each bad calibration it was allowed to use."""
    return [str(c["warning"]) for c in (provenance or {}).get("calibrations", []) if c.get("warning")]
