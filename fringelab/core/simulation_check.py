"""Reading an uploaded simulation in a process of its own, with a memory and a time limit: what the check job
(`worker.jobs.simulation_check`) runs, in a worker, never the web server.

A 16 KB Exodus file declaring 60 M nodes took the web process to 2176 MiB before its 422, and a 361 MB nodal CSV
held 1576 MiB of it for 26 s (issue 26). Now the readers refuse what a file declares beyond
FRINGELAB_SIMULATION_MAX_BYTES before they allocate it (`fringelab.formats.simulation_budget`), and whatever a reader
still allocates is bounded by the child process's address space (FRINGELAB_SIMULATION_CHECK_BYTES) and CPU time
(FRINGELAB_SIMULATION_CHECK_S): such a file costs that child at most its limit, then a failed check naming it.

`python -m fringelab.core.simulation_check FOLDER FILENAME MAX_BYTES` is the child: it prints
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


def _finite_range(values: np.ndarray | None) -> list[float] | None:
    if values is None or len(values) == 0 or not np.any(np.isfinite(values)):
        return None
    return [float(np.nanmin(values)), float(np.nanmax(values))]


def read_simulation_summary(folder: Path, *, filename: str, max_bytes: int) -> dict[str, Any]:
    """Open the simulation in `folder` (`open_simulation`, within `max_bytes` of declared arrays): its kind, size
    and what it holds; Invalid with the reader's message when it is no simulation fringelab reads."""
    from fringelab.formats.simulations import open_simulation

    try:
        # a nodout of several nodes: its punch node is chosen when it is compared
        results = open_simulation(folder, punch_needed=False, max_bytes=max_bytes)
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


def checked_summary(folder: Path, *, filename: str, settings: Settings) -> Checked:
    """The summary of the simulation in `folder`, read by a child process within the limits; Invalid with the
    reader's message, or naming the limit that stopped it (`Refused`)."""
    limit_bytes = settings.simulation_check_bytes

    def limited() -> None:  # in the child, before it starts Python: its address space and CPU time
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
        seconds = int(settings.simulation_check_s) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (seconds, seconds))

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "fringelab.core.simulation_check", str(folder), filename,
               str(settings.simulation_max_bytes)]  # fmt: skip
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
    folder, filename, max_bytes = Path(argv[0]), argv[1], int(argv[2])
    try:
        summary = read_simulation_summary(folder, filename=filename, max_bytes=max_bytes)
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
