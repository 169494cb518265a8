"""Reading an uploaded simulation in a process of its own, with a memory and a time limit: what the check job
(`worker.jobs.simulation_check`) runs, in a worker, never the web server.

A 16 KB Exodus file declaring 60 M nodes took the web process to 2176 MiB before its 422, and a 361 MB nodal CSV
held 1576 MiB of it for 26 s (issue 26). Now the readers refuse what a file declares beyond
FRINGELAB_SIMULATION_MAX_BYTES before they allocate it (`fringelab.formats.simulation_budget`), and whatever a reader
still allocates is bounded by the child process's address space (FRINGELAB_SIMULATION_CHECK_BYTES) and CPU time
(FRINGELAB_SIMULATION_CHECK_S): such a file costs that child at most its limit, then a failed check naming it.

What the child read is stored (`fringelab.formats.simulation_store`, the simulation's `checked.h5`, every state
read once, within the disk's reserve), so that the web server never opens the uploaded files: the mapping form's
preview reads that store.

`python -m fringelab.core.simulation_check FOLDER FILENAME MAX_BYTES STORE RESERVE_BYTES` is the child: it prints
`{"summary": {...}, "peak_rss_bytes": N}` or `{"error": "...", "code": "...", "peak_rss_bytes": N}` and exits 0 or 2.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.core.errors import Invalid
from fringelab.core.settings import Settings
from fringelab.core.storage import InsufficientStorage, check_room


def _finite_range(values: np.ndarray | None) -> list[float] | None:
    if values is None or len(values) == 0 or not np.any(np.isfinite(values)):
        return None
    return [float(np.nanmin(values)), float(np.nanmax(values))]


def read_simulation_summary(
    folder: Path, *, filename: str, max_bytes: int, store: Path | None = None, reserve_bytes: int = 0
) -> dict[str, Any]:
    """Read the simulation in `folder` (`read_parts`, within `max_bytes` of declared arrays) and, given a `store`,
    keep what was read there (`write_checked`, with `reserve_bytes` left on its volume): its kind, size and what
    it holds; Invalid with the reader's message when it is no simulation fringelab reads."""
    from fringelab.formats.simulation_store import stored_bytes, write_checked
    from fringelab.formats.simulations import assemble, read_parts

    try:
        parts = read_parts(folder, max_bytes=max_bytes)
        results = assemble(parts, punch_needed=False)  # a nodout of several nodes: its node is chosen when compared
        if store is not None:
            try:
                check_room(store.parent, stored_bytes(parts), reserve_bytes=reserve_bytes)
            except InsufficientStorage as error:
                raise Invalid(f"{filename}: its checked copy cannot be stored: {error}",
                              code="insufficient_storage") from None  # fmt: skip
            write_checked(store, parts)
    except (ValueError, KeyError, IndexError, OSError, EOFError) as error:
        message = str(error).replace(str(folder) + "/", "").replace(str(folder), filename)
        raise Invalid(f"{filename}: not a simulation fringelab reads: {message}", code="invalid_simulation") from None
    return {
        "kind": results.kind,
        "n_states": results.n_states,
        "n_nodes": results.n_nodes,
        "info": {
            "time": _finite_range(results.time),
            "length_unit": results.length_unit,
            "time_unit_s": results.time_unit_s,
            "has_punch_displacement": results.punch_displacement is not None,
            "has_force": results.force is not None,
            "n_shells": int(len(results.shells)),
            "n_solids": int(len(results.solids)),
        },
    }


@dataclass(frozen=True)
class Checked:
    """What the checking process found: the summary (`read_simulation_summary`), and its peak resident memory."""

    summary: dict[str, Any]
    peak_rss_bytes: int


class Refused(Invalid):
    """The simulation was refused (Invalid, with its message and code), and the checking process's peak resident
    memory when it said so (0: it was killed before it could)."""

    def __init__(self, detail: str, *, code: str, peak_rss_bytes: int = 0) -> None:
        super().__init__(detail, code=code)
        self.peak_rss_bytes = peak_rss_bytes


def _peak_rss_bytes() -> int:
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024  # Linux: KiB


def checked_summary(folder: Path, *, filename: str, settings: Settings, store: Path) -> Checked:
    """The summary of the simulation in `folder`, read by a child process within the limits, which stores what it
    read in `store` (`read_simulation_summary`); Invalid with the reader's message, or naming the limit that
    stopped it (`Refused`)."""
    limit_bytes = settings.simulation_check_bytes

    def limited() -> None:  # in the child, before it starts Python: its address space and CPU time
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
        seconds = int(settings.simulation_check_s) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (seconds, seconds))

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "fringelab.core.simulation_check", str(folder), filename,
               str(settings.simulation_max_bytes), str(store), str(settings.min_free_disk_bytes)]  # fmt: skip
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=settings.simulation_check_s,
                              preexec_fn=limited, env=env)  # fmt: skip
    except subprocess.TimeoutExpired:
        raise Refused(
            f"{filename}: reading it took longer than {settings.simulation_check_s:g} s "
            "(FRINGELAB_SIMULATION_CHECK_S); refused",
            code="simulation_too_large",
        ) from None
    try:
        answer = json.loads(done.stdout.strip().splitlines()[-1]) if done.stdout.strip() else {}
    except ValueError:
        answer = {}
    if "summary" in answer:
        return Checked(dict(answer["summary"]), int(answer.get("peak_rss_bytes", 0)))
    if answer.get("error"):
        raise Refused(str(answer["error"]), code=str(answer.get("code") or "invalid_simulation"),
                      peak_rss_bytes=int(answer.get("peak_rss_bytes", 0)))  # fmt: skip
    if done.returncode < 0 and done.returncode not in (-9, -24):  # killed, but not by its limits (SIGKILL, SIGXCPU)
        raise Refused(f"{filename}: the process reading it was stopped (signal {-done.returncode}); check it again",
                      code="check_interrupted")  # fmt: skip
    # killed by its limits (out of memory, CPU time) without a word
    raise Refused(
        f"{filename}: reading it needs more than {limit_bytes} bytes of memory or {settings.simulation_check_s:g} s "
        "(FRINGELAB_SIMULATION_CHECK_BYTES, FRINGELAB_SIMULATION_CHECK_S); refused",
        code="simulation_too_large",
    )


def main(argv: list[str]) -> int:
    folder, filename, max_bytes, store, reserve = Path(argv[0]), argv[1], int(argv[2]), Path(argv[3]), int(argv[4])
    try:
        summary = read_simulation_summary(folder, filename=filename, max_bytes=max_bytes, store=store,
                                          reserve_bytes=reserve)  # fmt: skip
    except Invalid as error:
        print(json.dumps({"error": error.detail, "code": error.code, "peak_rss_bytes": _peak_rss_bytes()}))
        return 2
    except MemoryError:
        detail = f"{filename}: reading it needs more memory than FRINGELAB_SIMULATION_CHECK_BYTES allows; refused"
        print(json.dumps({"error": detail, "code": "simulation_too_large", "peak_rss_bytes": _peak_rss_bytes()}))
        return 2
    print(json.dumps({"summary": summary, "peak_rss_bytes": _peak_rss_bytes()}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
