"""The check job of an uploaded simulation: read it in a process of its own, within a memory and a time limit, and
store what it holds.

Task "fringelab.simulation_check" takes a job id whose spec is {"simulation_id": N}. A ZIP stored as received is
unpacked first, here (`fringelab.core.simulations.unpack_model`, the rule of every ZIP). The model is read by a child
of this worker process (`fringelab.core.simulation_check.checked_summary`: its address space and CPU time limited,
the readers refusing declared sizes beyond FRINGELAB_SIMULATION_MAX_BYTES before allocating them), so a hostile file
costs that child its limit and nothing else. What it read is stored beside the upload (`checked.h5`,
`fringelab.formats.simulation_store`): the web server's preview reads that, never the upload. The simulation ends
`ready` with its kind, node and state counts and
facts, or `failed` with the reason (and the job fails with it); the job's result holds the checking process's
peak memory. A simulation deleted meanwhile ends the job quietly. Running it twice (acks-late redelivery) writes
the same result.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fringelab.core.errors import DomainError
from fringelab.core.simulation_check import Refused, checked_summary
from fringelab.core.simulations import unpack_model
from fringelab.core.specs import SimulationCheckSpec
from fringelab.core.storage import simulation_dir
from fringelab.core.upload_checks import SIMULATION_CHECK, claim, store
from fringelab.formats.simulation_store import CHECKED_FILE
from worker.context import JobContext

MIB = 2**20


def check_simulation(context: JobContext[SimulationCheckSpec]) -> dict[str, Any]:
    simulation_id = context.spec.simulation_id
    with context.sessions() as session:
        simulation = claim(session, SIMULATION_CHECK, simulation_id, job_id=context.job_id)
        folder, filename = context.settings.data_path / simulation.path, simulation.filename
        session.commit()
    context.progress(0, 1, "reading the model")
    try:
        unpack_model(context.settings, folder, filename=filename)  # a ZIP as received: here, never in a request
        store = simulation_dir(context.settings.data_path, simulation_id) / CHECKED_FILE
        checked = checked_summary(folder, filename=filename, settings=context.settings, store=store)
    except DomainError as error:
        peak = error.peak_rss_bytes if isinstance(error, Refused) else 0
        _store(context, simulation_id, state="failed", error=error.detail)
        context.log(f"refused; the checking process's peak memory: {peak / MIB:.0f} MiB")
        raise ValueError(error.detail) from None
    except BaseException as error:
        _store(context, simulation_id, state="failed", error=f"the check stopped: {type(error).__name__}: {error}")
        raise
    summary = checked.summary
    _store(context, simulation_id, state="ready", error="", kind=summary["kind"], n_states=summary["n_states"],
           n_nodes=summary["n_nodes"], info=summary["info"], checked_bytes=_size(store))  # fmt: skip
    context.log(f"read; the checking process's peak memory: {checked.peak_rss_bytes / MIB:.0f} MiB")
    return {"simulation_id": simulation_id, "state": "ready", "kind": summary["kind"],
            "n_states": summary["n_states"], "n_nodes": summary["n_nodes"],
            "peak_rss_bytes": checked.peak_rss_bytes}  # fmt: skip


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:  # no store written (nothing to keep): nothing counted
        return 0


def _store(context: JobContext, simulation_id: int, **fields: Any) -> None:
    with context.sessions() as session:
        store(session, SIMULATION_CHECK, simulation_id, **fields)
