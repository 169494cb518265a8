"""A simulation upload is read outside the web server's process: in a child process with a memory and a time
limit (FRINGELAB_SIMULATION_CHECK_BYTES, FRINGELAB_SIMULATION_CHECK_S), which answers its summary as JSON.

A 16 KB Exodus file declaring 60 M nodes took the web process to 2176 MiB before its 422, and a 361 MB nodal CSV
held 1576 MiB of it for 26 s (issue 26): a reader allocates what a file declares. In a child, such a file costs
that child at most its limit, then a 422 naming it; the web process's memory does not move.

`python -m fringelab.core.simulation_check FOLDER FILENAME` is the child: it prints `{"summary": {...}}` or
`{"error": "..."}` and exits 0 or 2.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.core.errors import Invalid
from fringelab.core.settings import Settings


def _finite_range(values: np.ndarray | None) -> list[float] | None:
    if values is None or len(values) == 0 or not np.any(np.isfinite(values)):
        return None
    return [float(np.nanmin(values)), float(np.nanmax(values))]


def read_simulation_summary(folder: Path, *, filename: str) -> dict[str, Any]:
    """Open the simulation in `folder` (`open_simulation`): its kind, size and what it holds; Invalid with the
    reader's message when it is no simulation fringelab reads."""
    from fringelab.formats.simulations import open_simulation

    try:
        results = open_simulation(folder, punch_needed=False)  # a nodout of several nodes: chosen when compared
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


def checked_summary(folder: Path, *, filename: str, settings: Settings) -> dict[str, Any]:
    """The summary of the simulation in `folder` (`read_simulation_summary`), read by a child process
    within the limits; Invalid (422) with the reader's message, or naming the limit that stopped it."""
    limit_bytes = settings.simulation_check_bytes

    def limited() -> None:  # in the child, before it starts Python: its address space and CPU time
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
        seconds = int(settings.simulation_check_s) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (seconds, seconds))

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    try:
        done = subprocess.run(
            [sys.executable, "-m", "fringelab.core.simulation_check", str(folder), filename],
            capture_output=True, text=True, timeout=settings.simulation_check_s, preexec_fn=limited, env=env,
        )  # fmt: skip
    except subprocess.TimeoutExpired:
        raise Invalid(
            f"{filename}: reading it took longer than {settings.simulation_check_s:g} s "
            "(FRINGELAB_SIMULATION_CHECK_S); refused",
            code="simulation_too_large",
        ) from None
    try:
        answer = json.loads(done.stdout.strip().splitlines()[-1]) if done.stdout.strip() else {}
    except ValueError:
        answer = {}
    if "summary" in answer:
        return dict(answer["summary"])
    if answer.get("error"):
        raise Invalid(str(answer["error"]), code=str(answer.get("code") or "invalid_simulation"))
    # killed by its limits (out of memory, CPU time) without a word
    raise Invalid(
        f"{filename}: reading it needs more than {limit_bytes} bytes of memory or {settings.simulation_check_s:g} s "
        "(FRINGELAB_SIMULATION_CHECK_BYTES, FRINGELAB_SIMULATION_CHECK_S); refused",
        code="simulation_too_large",
    )


def main(argv: list[str]) -> int:
    folder, filename = Path(argv[0]), argv[1]
    try:
        summary = read_simulation_summary(folder, filename=filename)
    except Invalid as error:
        print(json.dumps({"error": error.detail, "code": error.code}))
        return 2
    except MemoryError:
        detail = f"{filename}: reading it needs more memory than FRINGELAB_SIMULATION_CHECK_BYTES allows; refused"
        print(json.dumps({"error": detail, "code": "simulation_too_large"}))
        return 2
    print(json.dumps({"summary": summary}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
